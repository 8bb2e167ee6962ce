/* Two Sabertooth dual drivers in packet serial mode on one S1 line.
   Packet: address, command, value 0..127, (address + command + value) & 0x7F.
   Commands 0/1 = motor 1 forward/backward, 4/5 = motor 2, 14 = serial timeout (x100 ms).

   The line (build setting SABERTOOTH_S1_PIN):
     6   (default, the robot as wired in 2019): PH3, a transmit-only software UART. Timer2
         interrupts once per bit time and writes the next bit to the pin; nothing waits for it.
     18  TX1: USART1 (S1 wire moved to pin 18).
   Start-up as Dimension Engineering's Arduino library (Sabertooth::autobaud): nothing on the
   line for 1.5 s after reset, 0xAA, 0.5 s more; only then the serial-timeout packets and the
   motor packets. Each channel holds its latest value; a changed value is sent next (latest
   wins, so a burst of commands never queues stale packets); every channel is resent every
   SABERTOOTH_REFRESH_MS and 0xAA + the timeout packets every SABERTOOTH_SETUP_MS (a driver
   that was power-cycled forgets its timeout; an autobauding one needs a new 0xAA). */
#ifndef SABERTOOTH_H
#define SABERTOOTH_H
#include <stdint.h>

void sabertooth_init(void);
/* Call every CLOCK_TICK_US (500 µs): start-up sequence, refresh and setup resends. */
void sabertooth_tick(void);
/* Set wheel w (0..3, FL FR RL RR) to raw duty d (±32767 full scale). Before the start-up
   wait ends it is only remembered (the drivers hold their motors stopped until then). */
void sabertooth_set(uint8_t w, int16_t d);
/* 1 once the start-up wait is over and motor packets go out. */
uint8_t sabertooth_started(void);

#endif
