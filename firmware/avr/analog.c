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

static int32_t pin_mv(uint8_t i) {
    uint16_t r;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { r = raw[i]; }
    /* code r means V_in in [r, r + 1) * AVCC / 1024 (the conversion truncates): its centre, so
       that a reading carries no bias of half a code (37 mA on a 66 mV/A Hall sensor) */
    return ((2 * (int32_t)r + 1) * AVCC_MV + 1024) / 2048;
}

int32_t analog_battery_mv(void) { return (pin_mv(0) * BATTERY_DIVIDER_X1000 + 500) / 1000; }

__attribute__((unused)) static int32_t hall_ma(uint8_t i) { return (pin_mv(i) - HALL_ZERO_MV) * 1000L / HALL_MV_PER_A; }

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
