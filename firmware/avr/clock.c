#include <avr/interrupt.h>
#include <avr/io.h>
#include <util/atomic.h>
#include "clock.h"

#define TICK_COUNTS 1000u             /* Timer1 at F_CPU/8 = 2 MHz: a tick every 500 µs */
#define ARM_WITHIN_US 30000L          /* arm the compare less than one overflow (32768 µs) ahead */

static uint32_t wrap_us;              /* 32768 µs per counter wrap seen (interrupts off) */
static uint16_t last_count;           /* the counter as last read: a smaller one means a wrap */
static volatile uint8_t ticks;
static volatile uint8_t pending;      /* a sample is scheduled but not armed yet */
static volatile uint32_t sample_at;

void clock_init(void) {
    TCCR1A = 0;
    TCCR1B = _BV(CS11);
    OCR1B = TICK_COUNTS;
    TIFR1 = _BV(TOV1) | _BV(OCF1A) | _BV(OCF1B);
    TIMSK1 = _BV(OCIE1B);  /* no overflow interrupt: the 500 µs tick reads the counter often enough */
}

/* Interrupts off. The 16-bit counter is extended by counting its wraps as seen by the reads
   themselves: the tick interrupt reads it every 500 µs, far within one wrap (32768 µs), so no
   wrap is missed. (An overflow interrupt with a TOV1 check raced on simavr 1.6: reads around
   the wrap came out 32 ms early, and the floor below then held the clock for milliseconds,
   delaying the watchdog by up to 4 ms.) */
static uint32_t now_locked(void) {
    uint16_t t = TCNT1;
    if (t < last_count)
        wrap_us += 32768UL;               /* an add, not a 32-bit shift: interrupts stay off briefly */
    last_count = t;
    return wrap_us + (t >> 1);
}

/* Board time never steps back (the last value read is a floor; a safety net only). */
uint32_t clock_us(void) {
    static uint32_t last;
    uint32_t t;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        t = now_locked();
        if ((int32_t)(t - last) < 0)
            t = last;
        last = t;
    }
    return t;
}

uint8_t clock_take_tick(void) {
    uint8_t t;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        t = ticks;
        if (t) ticks--;
    }
    return t != 0;
}

/* Interrupts off (the compare must be armed before the counter can pass it). Arm compare A
   once the instant is within reach; 1 and *at = the sample time if it is due now (the caller
   then latches the sample with interrupts enabled). */
static uint8_t try_arm(uint32_t *at) {
    if (!pending)
        return 0;
    uint32_t now = now_locked();
    int32_t d = (int32_t)(sample_at - now);
    if (d <= 8) {
        pending = 0;
        *at = d < 0 ? now : sample_at;
        return 1;
    }
    if (d < ARM_WITHIN_US) {
        pending = 0;
        OCR1A = (uint16_t)(sample_at << 1);
        TIFR1 = _BV(OCF1A);
        TIMSK1 |= _BV(OCIE1A);
    }
    return 0;
}

void clock_schedule(uint32_t at_us) {
    uint32_t at = 0;
    uint8_t due;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        TIMSK1 &= (uint8_t)~_BV(OCIE1A);
        sample_at = at_us;
        pending = 1;
        due = try_arm(&at);
    }
    if (due)
        clock_sample_fired(at);
}

void clock_cancel(void) {
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        TIMSK1 &= (uint8_t)~_BV(OCIE1A);
        pending = 0;
    }
}

/* Both Timer1 interrupts run with interrupts enabled (they may read the four counters, about
   60 µs of SPI), so that the motor line's bit interrupt (sabertooth.c) is never late; only
   the arming of the compare is atomic. (Without that, the bit interrupt could fall between
   computing a compare value and writing it: a compare armed a few µs ahead was passed and
   fired one counter wrap, 32.8 ms, late: a gap in 220 Hz telemetry.) The bookkeeping here
   is safe with interrupts on: no other interrupt touches the clock. */
ISR(TIMER1_COMPB_vect, ISR_NOBLOCK) {
    OCR1B += TICK_COUNTS;
    uint32_t at = 0;
    uint8_t due;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        (void)now_locked();  /* keeps the wrap count current even when nobody asks the time */
        if (ticks < 255)
            ticks++;
        due = try_arm(&at);
    }
    if (due)
        clock_sample_fired(at);
}

ISR(TIMER1_COMPA_vect, ISR_NOBLOCK) {
    TIMSK1 &= (uint8_t)~_BV(OCIE1A);  /* its flag was cleared on entry: no second call */
    clock_sample_fired(sample_at);
}
