/* Two Sabertooth dual drivers in packet serial mode on USART1 (TX1, pin 18).
   Packet: address, command, value 0..127, (address + command + value) & 0x7F.
   Commands 0/1 = motor 1 forward/backward, 4/5 = motor 2, 14 = serial timeout (x100 ms).
   Each channel holds its latest value; a changed value is sent next (latest wins, so a
   burst of commands never queues stale packets). */
#ifndef SABERTOOTH_H
#define SABERTOOTH_H
#include <stdint.h>

void sabertooth_init(void);
/* Send the autobaud byte 0xAA and the serial-timeout packets. */
void sabertooth_baud(void);
/* Set wheel w (0..3, FL FR RL RR) to raw duty d (±32767 full scale). */
void sabertooth_set(uint8_t w, int16_t d);
/* Resend every channel (feeds the drivers' serial timeout). */
void sabertooth_refresh(void);

#endif
