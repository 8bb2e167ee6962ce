/* Four LS7366R quadrature counters on SPI, chip selects on pins 46..49 (PL3..PL0 = FL FR RL RR;
   build setting ENCODER_CS). */
#ifndef LS7366R_H
#define LS7366R_H
#include <stdint.h>

void ls7366r_init(void);
/* Copy the four counters to their output registers, one chip after the other (~3 µs apart). */
void ls7366r_latch_all(void);
/* The output register of counter i (as latched). */
int32_t ls7366r_read_latched(uint8_t i);
/* Clear the four counters (one chip after the other). */
void ls7366r_clear_all(void);

#endif
