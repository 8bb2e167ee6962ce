/* Build settings of the Omnibot board (the Makefile passes them as -D; defaults here are
   the 2019 robot as wired for square.ino). See docs/firmware.md, Build options. */
#ifndef BOARD_CONFIG_H
#define BOARD_CONFIG_H

#ifndef F_CPU
#define F_CPU 16000000UL
#endif
#ifndef FIRMWARE_VERSION
#define FIRMWARE_VERSION {1, 0, 0}
#endif
#ifndef BOARD_ID
#define BOARD_ID 1UL                 /* HELLO board_id: give each robot its own */
#endif
#ifndef COUNTS_PER_REV
#define COUNTS_PER_REV 980           /* LS7366R x4 counts per wheel revolution (20 x 49) */
#endif
#ifndef MAX_TELEMETRY_HZ
#define MAX_TELEMETRY_HZ 500         /* HELLO max_telemetry_rate; CONFIGURE above it is BAD_VALUE */
#endif

/* Sabertooth drivers (packet serial on S1; sabertooth.h). Wheel -> {address, channel, sign}:
   sign -1 means the wheel turns forward for a "backward" driver command. */
#ifndef MOTOR_MAP
#define MOTOR_MAP {{128, 2, -1}, {128, 1, -1}, {129, 1, 1}, {129, 2, 1}}
#endif
#ifndef SABERTOOTH_S1_PIN
#define SABERTOOTH_S1_PIN 6          /* 6: software UART on PH3 (the 2019 wiring); 18: USART1 TX1 */
#endif
#ifndef SABERTOOTH_BAUD
#define SABERTOOTH_BAUD 9600UL       /* the drivers' factory rate, the only one known to work on the robot */
#endif
#ifndef SABERTOOTH_TIMEOUT_MS
#define SABERTOOTH_TIMEOUT_MS 300    /* driver stops by itself after this silence (0 = not set) */
#endif
#ifndef SABERTOOTH_REFRESH_MS
#define SABERTOOTH_REFRESH_MS 100    /* resend every channel this often (feeds the driver timeout) */
#endif
#ifndef SABERTOOTH_SETUP_MS
#define SABERTOOTH_SETUP_MS 1000     /* resend 0xAA + the timeout packets this often (survive a driver power cycle) */
#endif

/* LS7366R counters: counter sign per wheel (FR and RR count backwards on the robot). */
#ifndef ENCODER_SIGNS
#define ENCODER_SIGNS {1, -1, 1, -1}
#endif
#ifndef ENCODER_CS_BITS
#define ENCODER_CS_BITS {_BV(PL3), _BV(PL2), _BV(PL1), _BV(PL0)}  /* pins 46, 47, 48, 49 */
#endif

/* Analog inputs (AVCC reference). */
#ifndef AVCC_MV
#define AVCC_MV 5000L
#endif
#ifndef BATTERY_DIVIDER_X1000
#define BATTERY_DIVIDER_X1000 6000L  /* battery volts per volt on A0, x1000 (50k/10k: 6.000) */
#endif
#ifndef BATTERY_CURRENT_HALL
#define BATTERY_CURRENT_HALL 0       /* 1: Hall current sensor on A5 */
#endif
#ifndef MOTOR_CURRENT_HALL
#define MOTOR_CURRENT_HALL 0         /* 1: Hall current sensors on A1..A4 (FL FR RL RR) */
#endif
#ifndef HALL_MV_PER_A
#define HALL_MV_PER_A 66L            /* ACS712-30A: 66 mV/A */
#endif
#ifndef HALL_ZERO_MV
#define HALL_ZERO_MV 2500L           /* output at 0 A */
#endif
#ifndef UNDERVOLTAGE_MV
#define UNDERVOLTAGE_MV 0L           /* latch UNDERVOLTAGE below this battery voltage (0 = off) */
#endif
#ifndef OVERCURRENT_MA
#define OVERCURRENT_MA 0L            /* latch OVERCURRENT above this motor current (0 = off; needs MOTOR_CURRENT_HALL) */
#endif
#ifndef ESTOP_INPUT
#define ESTOP_INPUT 0                /* 1: e-stop button on pin 2 (PE4), pressed = low, latches ESTOP */
#endif

#endif
