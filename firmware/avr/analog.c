#include <avr/interrupt.h>
#include <avr/io.h>
#include <util/atomic.h>
#include "analog.h"
#include "board_config.h"

static const uint8_t channels[] = {
    0,
#if BATTERY_CURRENT_HALL
    5,
#endif
#if MOTOR_CURRENT_HALL
    1, 2, 3, 4,
#endif
};
#define N_CH (sizeof channels)
static volatile uint16_t raw[N_CH];
static volatile uint8_t idx;

static void start(uint8_t i) {
    ADMUX = (uint8_t)(_BV(REFS0) | channels[i]);  /* AVCC reference */
    ADCSRA |= _BV(ADSC);
}

void analog_init(void) {
    ADCSRA = _BV(ADEN) | _BV(ADIE) | _BV(ADPS2) | _BV(ADPS1) | _BV(ADPS0);  /* 125 kHz: 104 µs per conversion */
    ADCSRB = 0;
    start(0);
}

/* One round of conversions per call (every millisecond): 104 µs per channel. */
void analog_start_round(void) {
    if (!(ADCSRA & _BV(ADSC)) && idx == 0)
        start(0);
}

ISR(ADC_vect) {
    raw[idx] = ADC;
    idx = (uint8_t)(idx + 1 == N_CH ? 0 : idx + 1);
    if (idx)
        start(idx);
}

/* Code r means V_in in [r, r + 1) * AVCC / 1024 (the conversion truncates): each reading is
   taken at its centre, (2r + 1) * AVCC / 2048, so that it carries no bias of half a code (37 mA
   on a 66 mV/A Hall sensor), and converted to mV or mA with a single rounding at the end. A
   centre first rounded to whole mV at the pin is off by up to 0.5 mV, a different amount for each
   code: 7.6 mA on the Hall sensor, a bias of about 1 % in a motor current of 0.5 A that noise does
   not average away (it dithers over neighbouring codes with their own errors). */
static uint16_t half_code(uint8_t i) {
    uint16_t r;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { r = raw[i]; }
    return (uint16_t)(2 * r + 1);
}

/* battery mV per half code (AVCC / 2048 at the pin, times the divider) in units of 2^-12 mV:
   exact for the default 5 V and 6.000 (60000); at most 2047 * Q < 2^32 for dividers up to 210 */
#define BATTERY_Q12 ((uint32_t)((AVCC_MV * BATTERY_DIVIDER_X1000 + 250) / 500))
_Static_assert((uint64_t)BATTERY_Q12 * 2047 < 4294967296ULL, "BATTERY_DIVIDER too large for analog.c");

int32_t analog_battery_mv(void) { return (int32_t)(((uint32_t)half_code(0) * BATTERY_Q12 + 2048) >> 12); }

/* Hall current, mA, rounded to nearest: ((2r + 1) AVCC / 2048 - ZERO) / (mV per A), written as
   ((2r + 1) AVCC 125 - ZERO 256000) / (256 mV per A) so that it stays within 32 bits */
__attribute__((unused)) static int32_t hall_ma(uint8_t i) {
    int32_t num = (int32_t)half_code(i) * (AVCC_MV * 125L) - HALL_ZERO_MV * 256000L;
    int32_t den = 256L * HALL_MV_PER_A;
    return (num >= 0 ? num + den / 2 : num - den / 2) / den;
}

int32_t analog_battery_current_ma(void) {
#if BATTERY_CURRENT_HALL
    return hall_ma(1);
#else
    return 0;
#endif
}

int32_t analog_motor_current_ma(uint8_t w) {
#if MOTOR_CURRENT_HALL
    /* a sensor in the motor lead reads the driver channel's sense; the map's sign turns it to the wheel's */
    static const struct { uint8_t address, channel; int8_t sign; } map[4] = MOTOR_MAP;
    return map[w].sign * hall_ma((uint8_t)(1 + BATTERY_CURRENT_HALL + w));
#else
    (void)w;
    return 0;
#endif
}
