/* What main.c needs from the hardware layer beyond hal.h. */
#ifndef HAL_AVR_H
#define HAL_AVR_H
#include <stdint.h>
uint8_t hal_avr_sample_ready(void);  /* a latched sample waits for the core */
#endif
