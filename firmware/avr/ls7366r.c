#include <avr/io.h>
#include <util/atomic.h>
#include "ls7366r.h"

#define CLR_CNTR 0x20
#define RD_OTR 0x68
#define WR_MDR0 0x88
#define WR_MDR1 0x90
#define LOAD_OTR 0xE8
#define MDR0_X4_FREE 0x03   /* x4 quadrature, free-running, index off, filter /1 */
#define MDR1_4BYTE 0x00     /* 4-byte counter, counting enabled, no flags */

/* pins 46, 47, 48, 49 = PL3, PL2, PL1, PL0 */
static const uint8_t cs_bit[4] = {_BV(PL3), _BV(PL2), _BV(PL1), _BV(PL0)};
#define CS_ALL (_BV(PL3) | _BV(PL2) | _BV(PL1) | _BV(PL0))

static uint8_t spi(uint8_t b) {
    SPDR = b;
    while (!(SPSR & _BV(SPIF)))
        ;
    return SPDR;
}

static void select(uint8_t mask) { PORTL &= (uint8_t)~mask; }
static void deselect(void) { PORTL |= CS_ALL; }

void ls7366r_init(void) {
    PORTL |= CS_ALL;
    DDRL |= CS_ALL;
    DDRB |= _BV(PB0) | _BV(PB1) | _BV(PB2);  /* SS (pin 53, must be an output), SCK, MOSI */
    SPCR = _BV(SPE) | _BV(MSTR);              /* mode 0, F_CPU/4 = 4 MHz */
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        select(CS_ALL);
        spi(WR_MDR0);
        spi(MDR0_X4_FREE);
        deselect();
        select(CS_ALL);
        spi(WR_MDR1);
        spi(MDR1_4BYTE);
        deselect();
    }
    ls7366r_clear_all();
}

void ls7366r_latch_all(void) {
    select(CS_ALL);
    spi(LOAD_OTR);
    deselect();
}

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
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        select(CS_ALL);
        spi(CLR_CNTR);
        deselect();
    }
}
