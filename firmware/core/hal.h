/* What the protocol core needs from the board: the hardware layer implements these
   (avr/hal_avr.c on the ATmega2560, test/host_hal.c on the host). The core never touches
   a register, so it compiles and is tested on the host. Times are board µs since boot. */
#ifndef HAL_H
#define HAL_H
#include <stdint.h>

/* One sample of every sensor, taken at one instant (SI in milli-units). */
typedef struct {
    uint32_t time_us;             /* when the counters were latched */
    int32_t encoder[4];           /* FL, FR, RL, RR, forward positive */
    int32_t motor_current_ma[4];  /* signed with the duty; 0 without sensors */
    int32_t battery_mv;
    int32_t battery_current_ma;   /* 0 without a sensor */
} hal_sample_t;

/* Queue a whole frame for the host link; returns 0 if it does not fit (the frame is lost). */
uint8_t hal_host_send(const uint8_t *bytes, uint8_t n);
/* Apply four duties (raw, ±32767 = full scale, FL FR RL RR) to the motor drivers. */
void hal_set_duties(const int16_t duty[4]);
/* Enable (1) or disable (0) the motor drivers' enable / e-stop line. */
void hal_set_drivers_enabled(uint8_t on);
/* Set the four encoder counters to zero. */
void hal_reset_encoders(void);
/* Latch a sample at board time at_us (or as soon as possible if that has passed). */
void hal_schedule_sample(uint32_t at_us);
/* Cancel a scheduled sample (telemetry off). */
void hal_cancel_sample(void);
/* 1 and the sample if the scheduled one has been latched since the last call. */
uint8_t hal_take_sample(hal_sample_t *s);
/* Fault flags (FAULTS_*) the board's sensors report now: e-stop input, undervoltage, overcurrent. */
uint8_t hal_fault_inputs(void);

#endif
