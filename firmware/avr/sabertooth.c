#include <avr/interrupt.h>
#include <avr/io.h>
#include <util/atomic.h>
#include "board_config.h"
#include "clock.h"
#include "sabertooth.h"

typedef struct { uint8_t address, channel; int8_t sign; } motor_t;
static const motor_t map[4] = MOTOR_MAP;

static volatile uint8_t cmd[4], val[4];   /* per wheel: the packet's command and value */
static volatile uint8_t dirty;            /* wheels whose packet is still to be sent */
static volatile uint8_t ctl[9], ctl_n, ctl_i;  /* control bytes (0xAA, timeout packets) first */
static volatile uint8_t pkt[4], pkt_i = 4;
static volatile uint8_t next_wheel;
static volatile uint8_t started;          /* start-up wait over: motor packets may go */
static uint8_t driver[2];                 /* the two drivers' addresses, from the map */

#define TICKS(ms) ((uint16_t)((ms) * 1000UL / CLOCK_TICK_US))
#define WAIT_BEFORE_AA_MS 1500u           /* Sabertooth::autobaud(): delay(1500), 0xAA, delay(500) */
#define WAIT_AFTER_AA_MS 500u

/* ------------------------------------------------------------------ the line */
#if SABERTOOTH_S1_PIN == 6
/* Timer2, CTC: one compare interrupt per bit. 9600 baud: F_CPU/8 = 2 MHz, 208 counts per bit
   (9615 baud, +0.16 %). Slow rates take the /32 prescaler. */
#define T2_DIV (F_CPU / 8 / SABERTOOTH_BAUD <= 256 ? 8UL : 32UL)
#define T2_TOP ((F_CPU / T2_DIV + SABERTOOTH_BAUD / 2) / SABERTOOTH_BAUD - 1)
#if F_CPU / 32 / SABERTOOTH_BAUD > 256 || F_CPU / 8 / SABERTOOTH_BAUD < 16
#error "SABERTOOTH_BAUD out of the software UART's range (about 2400..115200)"
#endif
static volatile uint16_t frame;           /* bits after next_level, LSB first, over an end marker */
static volatile uint8_t next_level = 1;   /* the level the next interrupt writes */

static void line_init(void) {
    PORTH |= _BV(PH3);                    /* idle high (mark) from the start */
    DDRH |= _BV(PH3);
    TCCR2A = _BV(WGM21);                  /* CTC, TOP = OCR2A */
    TCCR2B = T2_DIV == 8 ? _BV(CS21) : (_BV(CS21) | _BV(CS20));
    OCR2A = (uint8_t)T2_TOP;
}

static uint8_t next_byte(uint8_t *b);

/* Interrupts off. Start the timer if the line is idle (the first interrupt writes one more idle
   bit and fetches the byte: the start bit follows one bit time later). */
static void line_kick(void) {
    if (TIMSK2 & _BV(OCIE2A))
        return;
    TCNT2 = 0;
    TIFR2 = _BV(OCF2A);
    TIMSK2 |= _BV(OCIE2A);
}

/* The level computed at the previous interrupt is written first, so the bit edges carry only
   the interrupt latency, never the time spent fetching a byte (the sample interrupt, the only
   long one, lets this one in: clock.c). */
ISR(TIMER2_COMPA_vect) {
    if (next_level)
        PORTH |= _BV(PH3);
    else
        PORTH &= (uint8_t)~_BV(PH3);
    uint16_t f = frame;
    if (f <= 1) {                         /* the stop bit (or an idle bit) is going out */
        uint8_t b;
        if (!next_byte(&b)) {
            next_level = 1;
            frame = 0;
            if (f == 0)                   /* a whole idle bit written: stop the timer */
                TIMSK2 &= (uint8_t)~_BV(OCIE2A);
            return;
        }
        f = (uint16_t)(0x600 | ((uint16_t)b << 1));  /* start 0, 8 data, stop 1, end marker */
    }
    next_level = f & 1;
    frame = f >> 1;
}
#elif SABERTOOTH_S1_PIN == 18
static uint8_t next_byte(uint8_t *b);

static void line_init(void) {
    UBRR1 = (uint16_t)((F_CPU / 8 / SABERTOOTH_BAUD - 1) / 2);  /* 103 at 9600 (+0.2 %) */
    UCSR1A = 0;
    UCSR1C = _BV(UCSZ11) | _BV(UCSZ10);
    UCSR1B = _BV(TXEN1);
}

static void line_kick(void) { UCSR1B |= _BV(UDRIE1); }

ISR(USART1_UDRE_vect) {
    uint8_t b;
    if (next_byte(&b))
        UDR1 = b;
    else
        UCSR1B &= (uint8_t)~_BV(UDRIE1);
}
#else
#error "SABERTOOTH_S1_PIN must be 6 (software UART, the 2019 wiring) or 18 (USART1 TX1)"
#endif

static void put_packet(volatile uint8_t *p, uint8_t address, uint8_t command, uint8_t value) {
    p[0] = address;
    p[1] = command;
    p[2] = value;
    p[3] = (uint8_t)((address + command + value) & 0x7F);
}

/* From the line's interrupt: the next byte to send, if any (control bytes before motor packets). */
static uint8_t next_byte(uint8_t *b) {
    if (pkt_i < 4) {
        *b = pkt[pkt_i++];
        return 1;
    }
    if (ctl_i < ctl_n) {
        *b = ctl[ctl_i++];
        return 1;
    }
    if (dirty && started) {
        while (!(dirty & (1 << next_wheel)))
            next_wheel = (uint8_t)((next_wheel + 1) & 3);
        uint8_t w = next_wheel;
        dirty &= (uint8_t)~(1 << w);
        next_wheel = (uint8_t)((w + 1) & 3);
        put_packet(pkt, map[w].address, cmd[w], val[w]);
        *b = pkt[0];
        pkt_i = 1;
        return 1;
    }
    return 0;
}

/* ------------------------------------------------------------------ packets */
void sabertooth_init(void) {
    for (uint8_t w = 0; w < 4; w++) {
        cmd[w] = (uint8_t)(map[w].channel == 1 ? 0 : 4);
        val[w] = 0;
    }
    driver[0] = driver[1] = map[0].address;
    for (uint8_t w = 1; w < 4; w++)
        if (map[w].address != driver[0])
            driver[1] = map[w].address;
    line_init();
}

/* 0xAA, then (with a timeout set) the serial-timeout packet to both drivers. */
static void queue_setup(uint8_t with_timeout) {
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        if (ctl_i < ctl_n)
            return;                       /* the previous setup is still going out */
        ctl[0] = 0xAA;
        ctl_n = 1;
#if SABERTOOTH_TIMEOUT_MS > 0
        if (with_timeout) {
            put_packet(ctl + 1, driver[0], 14, (uint8_t)((SABERTOOTH_TIMEOUT_MS + 99) / 100));
            ctl_n = 5;
            if (driver[1] != driver[0]) {
                put_packet(ctl + 5, driver[1], 14, (uint8_t)((SABERTOOTH_TIMEOUT_MS + 99) / 100));
                ctl_n = 9;
            }
        }
#else
        (void)with_timeout;
#endif
        ctl_i = 0;
        line_kick();
    }
}

static void refresh_all(void) {
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        dirty = 0x0F;
        next_wheel = 0;
        line_kick();
    }
}

void sabertooth_tick(void) {
    static uint16_t wait = TICKS(WAIT_BEFORE_AA_MS), refresh_in, setup_in;
    static uint8_t phase;                 /* 0 before 0xAA, 1 after it, 2 running */
    if (phase < 2) {
        if (--wait)
            return;
        if (phase == 0) {
            queue_setup(0);               /* the library's 0xAA, alone */
            wait = TICKS(WAIT_AFTER_AA_MS);
            phase = 1;
            return;
        }
        phase = 2;
        started = 1;
        queue_setup(1);
        refresh_all();
        refresh_in = TICKS(SABERTOOTH_REFRESH_MS);
        setup_in = TICKS(SABERTOOTH_SETUP_MS);
        return;
    }
    if (--refresh_in == 0) {              /* countdowns: no division in the loop */
        refresh_in = TICKS(SABERTOOTH_REFRESH_MS);
        refresh_all();
    }
    if (--setup_in == 0) {
        setup_in = TICKS(SABERTOOTH_SETUP_MS);
        queue_setup(1);
    }
}

uint8_t sabertooth_started(void) { return started; }

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
        if (w == 0)
            next_wheel = 0;                /* a new command goes out FL, FR, RL, RR, as square.ino */
        if (started)
            line_kick();
    }
}
