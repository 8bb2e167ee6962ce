/* Board time (µs since boot, from Timer1 at 2 MHz), a 500 µs tick (CLOCK_TICK_US) and one scheduled
   sample instant (Timer1 compare A latches the sensors at exactly that time). */
#ifndef CLOCK_H
#define CLOCK_H
#include <stdint.h>

void clock_init(void);
uint32_t clock_us(void);
#define CLOCK_TICK_US 500u
/* 1 once per elapsed tick since the last call. */
uint8_t clock_take_tick(void);
/* Call clock_sample_fired(at_us) from the compare interrupt at board time at_us. */
void clock_schedule(uint32_t at_us);
void clock_cancel(void);
extern void clock_sample_fired(uint32_t at_us);  /* provided by the hardware layer */

#endif
