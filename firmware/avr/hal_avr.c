/* hal.h on the ATmega2560: the thin layer between the protocol core and the drivers. */
#include <avr/io.h>
#include <string.h>
#include "analog.h"
#include "board_config.h"
#include "clock.h"
#include "hal.h"
#include "hal_avr.h"
#include "host_uart.h"
#include "ls7366r.h"
#include "protocol_gen.h"
#include "sabertooth.h"

static const int8_t encoder_sign[4] = ENCODER_SIGNS;
static hal_sample_t sample;
static volatile uint8_t sample_ready;

uint8_t hal_host_send(const uint8_t *bytes, uint8_t n) { return host_uart_write(bytes, n); }

void hal_set_duties(const int16_t duty[4]) {
    for (uint8_t w = 0; w < 4; w++)
        sabertooth_set(w, duty[w]);
}

/* Pin 7 (PH4): high = drivers enabled (wired to the Sabertooths' S2 e-stop input). */
void hal_set_drivers_enabled(uint8_t on) {
    if (on)
        PORTH |= _BV(PH4);
    else
        PORTH &= (uint8_t)~_BV(PH4);
}

void hal_reset_encoders(void) { ls7366r_clear_all(); }

void hal_schedule_sample(uint32_t at_us) {
    sample_ready = 0;
    clock_schedule(at_us);
}

void hal_cancel_sample(void) {
    clock_cancel();
    sample_ready = 0;
}

/* From the Timer1 compare interrupt, at board time at_us: latch the four counters at one
   instant (LOAD_OTR to each chip, about 3 µs apart), read them and the latest analog values. */
void clock_sample_fired(uint32_t at_us) {
    ls7366r_latch_all();
    sample.time_us = at_us;
    for (uint8_t w = 0; w < 4; w++) {
        sample.encoder[w] = encoder_sign[w] * ls7366r_read_latched(w);
        sample.motor_current_ma[w] = analog_motor_current_ma(w);
    }
    sample.battery_mv = analog_battery_mv();
    sample.battery_current_ma = analog_battery_current_ma();
    sample_ready = 1;
}

uint8_t hal_avr_sample_ready(void) { return sample_ready; }

uint8_t hal_take_sample(hal_sample_t *s) {
    if (!sample_ready)
        return 0;
    memcpy(s, &sample, sizeof *s);  /* the next sample is at least 1 ms away */
    sample_ready = 0;
    return 1;
}

uint8_t hal_fault_inputs(void) {
    uint8_t f = 0;
#if ESTOP_INPUT
    if (!(PINE & _BV(PE4)))
        f |= FAULTS_ESTOP;
#endif
#if UNDERVOLTAGE_MV > 0
    if (analog_battery_mv() < UNDERVOLTAGE_MV)
        f |= FAULTS_UNDERVOLTAGE;
#endif
#if OVERCURRENT_MA > 0 && MOTOR_CURRENT_HALL
    for (uint8_t w = 0; w < 4; w++) {
        int32_t i = analog_motor_current_ma(w);
        if (i > OVERCURRENT_MA || i < -OVERCURRENT_MA)
            f |= FAULTS_OVERCURRENT;
    }
#endif
    return f;
}
