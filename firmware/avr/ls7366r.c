#include <avr/io.h>
#include <util/atomic.h>
#include "board_config.h"
#include "ls7366r.h"

#define CLR_CNTR 0x20
#define RD_OTR 0x68
#define WR_MDR0 0x88
#define WR_MDR1 0x90
#define LOAD_OTR 0xE8
#define MDR0_X4_FREE 0x03   /* x4 quadrature, free-running, index off, filter /1 */
#define MDR1_4BYTE 0x00     /* 4-byte counter, counting enabled, no flags */

/* Chip select per wheel (build setting ENCODER_CS, pins 42..49 = PL7..PL0; default 46, 47, 48,
   49 = PL3, PL2, PL1, PL0 as in square.ino). One chip at a time, as the 2019 sketches: the
   LS7366R's MISO is high-impedance only while its SS is high, so two selected chips would
   drive the same MISO line. */
static const uint8_t cs_bit[4] = ENCODER_CS_BITS;
#define CS_ALL (cs_bit[0] | cs_bit[1] | cs_bit[2] | cs_bit[3])

static uint8_t spi(uint8_t b) {
    SPDR = b;
    while (!(SPSR & _BV(SPIF)))
        ;
    return SPDR;
}

static void select(uint8_t mask) { PORTL &= (uint8_t)~mask; }
static void deselect(void) { PORTL |= CS_ALL; }

/* A one-byte instruction (and an optional data byte) to each chip in turn. */
static void each(uint8_t instruction, int16_t data) {
    for (uint8_t i = 0; i < 4; i++) {
        select(cs_bit[i]);
        spi(instruction);
        if (data >= 0)
            spi((uint8_t)data);
        deselect();
    }
}

void ls7366r_init(void) {
    PORTL |= CS_ALL;
    DDRL |= CS_ALL;
    DDRB |= _BV(PB0) | _BV(PB1) | _BV(PB2);  /* SS (pin 53, must be an output), SCK, MOSI */
    SPCR = _BV(SPE) | _BV(MSTR);              /* mode 0, F_CPU/4 = 4 MHz */
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        each(WR_MDR0, MDR0_X4_FREE);
        each(WR_MDR1, MDR1_4BYTE);
    }
    ls7366r_clear_all();
}

/* About 3 µs apart (one SPI byte at 4 MHz plus the pin writes): FL first. */
void ls7366r_latch_all(void) { each(LOAD_OTR, -1); }

int32_t ls7366r_read_latched(uint8_t i) {
    uint32_t v = 0;
    select(cs_bit[i]);
    spi(RD_OTR);
    for (uint8_t k = 0; k < 4; k++)
        v = (v << 8) | spi(0);
    deselect();
    return (int32_t)v;
}

void ls7366r_clear_all(void) {
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { each(CLR_CNTR, -1); }
}
