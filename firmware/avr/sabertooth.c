#include <avr/interrupt.h>
#include <avr/io.h>
#include <util/atomic.h>
#include "board_config.h"
#include "sabertooth.h"

typedef struct { uint8_t address, channel; int8_t sign; } motor_t;
static const motor_t map[4] = MOTOR_MAP;

static volatile uint8_t cmd[4], val[4];   /* per wheel: the packet's command and value */
static volatile uint8_t dirty;            /* wheels whose packet is still to be sent */
static volatile uint8_t ctl[12], ctl_n, ctl_i;  /* control bytes (0xAA, timeout packets) first */
static volatile uint8_t pkt[4], pkt_i = 4;
static volatile uint8_t next_wheel;

void sabertooth_init(void) {
    UBRR1 = (uint16_t)((F_CPU / 8 / SABERTOOTH_BAUD - 1) / 2);  /* 25 at 38400 (+0.2 %) */
    UCSR1A = 0;
    UCSR1C = _BV(UCSZ11) | _BV(UCSZ10);
    UCSR1B = _BV(TXEN1);
    for (uint8_t w = 0; w < 4; w++) {
        cmd[w] = (uint8_t)(map[w].channel == 1 ? 0 : 4);
        val[w] = 0;
    }
}

static void put_packet(volatile uint8_t *p, uint8_t address, uint8_t command, uint8_t value) {
    p[0] = address;
    p[1] = command;
    p[2] = value;
    p[3] = (uint8_t)((address + command + value) & 0x7F);
}

void sabertooth_baud(void) {
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        ctl[0] = 0xAA;
        ctl_n = 1;
#if SABERTOOTH_TIMEOUT_MS > 0
        put_packet(ctl + 1, 128, 14, (uint8_t)((SABERTOOTH_TIMEOUT_MS + 99) / 100));
        put_packet(ctl + 5, 129, 14, (uint8_t)((SABERTOOTH_TIMEOUT_MS + 99) / 100));
        ctl_n = 9;
#endif
        ctl_i = 0;
        UCSR1B |= _BV(UDRIE1);
    }
}

void sabertooth_set(uint8_t w, int16_t d) {
    const motor_t *m = &map[w];
    int32_t x = (int32_t)d * m->sign;
    uint8_t back = x < 0;
    if (back)
        x = -x;
    uint8_t value = (uint8_t)((x * 127 + 16383) / 32767);  /* rounded to the driver's 0..127 */
    uint8_t command = (uint8_t)((m->channel == 1 ? 0 : 4) + back);
    if (value == 0)
        command = (uint8_t)(m->channel == 1 ? 0 : 4);  /* stop is "forward 0" */
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        if (cmd[w] != command || val[w] != value) {  /* only changes; the refresh resends all */
            cmd[w] = command;
            val[w] = value;
            dirty |= (uint8_t)(1 << w);
        }
        UCSR1B |= _BV(UDRIE1);
    }
}

void sabertooth_refresh(void) {
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        dirty = 0x0F;
        UCSR1B |= _BV(UDRIE1);
    }
}

ISR(USART1_UDRE_vect) {
    if (pkt_i < 4) {
        UDR1 = pkt[pkt_i++];
        return;
    }
    if (ctl_i < ctl_n) {
        UDR1 = ctl[ctl_i++];
        return;
    }
    if (dirty) {
        while (!(dirty & (1 << next_wheel)))
            next_wheel = (uint8_t)((next_wheel + 1) & 3);
        uint8_t w = next_wheel;
        dirty &= (uint8_t)~(1 << w);
        next_wheel = (uint8_t)((w + 1) & 3);
        put_packet(pkt, map[w].address, cmd[w], val[w]);
        UDR1 = pkt[0];
        pkt_i = 1;
        return;
    }
    UCSR1B &= (uint8_t)~_BV(UDRIE1);
}
