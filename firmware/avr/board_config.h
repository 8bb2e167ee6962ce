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

/* Sabertooth drivers (packet serial on USART1, TX1 = pin 18). Wheel -> {address, channel,
   sign}: sign -1 means the wheel turns forward for a "backward" driver command. */
#ifndef MOTOR_MAP
#define MOTOR_MAP {{128, 2, -1}, {128, 1, -1}, {129, 1, 1}, {129, 2, 1}}
#endif
#ifndef SABERTOOTH_BAUD
#define SABERTOOTH_BAUD 38400UL      /* fastest packet-serial rate of the Sabertooth 2x5/2x12/2x25/2x60 */
#endif
#ifndef SABERTOOTH_TIMEOUT_MS
#define SABERTOOTH_TIMEOUT_MS 300    /* driver stops by itself after this silence (0 = not set) */
#endif
#ifndef SABERTOOTH_REFRESH_MS
#define SABERTOOTH_REFRESH_MS 100    /* resend every channel this often (feeds the driver timeout) */
#endif
#ifndef SABERTOOTH_REBAUD_MS
#define SABERTOOTH_REBAUD_MS 2000    /* second 0xAA for drivers that powered up with the board */
#endif

/* LS7366R counters: counter sign per wheel (FR and RR count backwards on the robot). */
#ifndef ENCODER_SIGNS
#define ENCODER_SIGNS {1, -1, 1, -1}
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
