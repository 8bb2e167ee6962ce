/* Omnibot board firmware for the Arduino Mega 2560: boot, then a sleep-driven main loop
   that hands host bytes and time to the protocol core (core/board_core.c). */
#include <avr/eeprom.h>
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>
#include <avr/wdt.h>
#include "analog.h"
#include "board_config.h"
#include "board_core.h"
#include "clock.h"
#include "hal_avr.h"
#include "host_uart.h"
#include "ls7366r.h"
#include "sabertooth.h"

static core_t core;
static uint8_t noise[32] __attribute__((section(".noinit")));  /* uninitialised RAM: differs per power-up */
static uint32_t EEMEM boot_counter;

/* A watchdog reset keeps the watchdog on: turn it off before anything else. */
void early_wdt_off(void) __attribute__((naked, used, section(".init3")));
void early_wdt_off(void) {
    MCUSR = 0;
    wdt_disable();
}

static uint32_t fnv1a(uint32_t h, const uint8_t *p, uint8_t n) {
    while (n--) {
        h ^= *p++;
        h *= 16777619UL;
    }
    return h;
}

/* Random non-zero boot id: uninitialised RAM, a boot counter in EEPROM (so it differs between
   boots even when RAM powers up the same), ADC noise and timer jitter, hashed with the board id. */
static uint32_t draw_boot_id(void) {
    uint32_t n = eeprom_read_dword(&boot_counter) + 1;
    eeprom_update_dword(&boot_counter, n);
    uint32_t h = fnv1a(2166136261UL, noise, sizeof noise);
    uint32_t extra[3] = {n, BOARD_ID, clock_us()};
    h = fnv1a(h, (const uint8_t *)extra, sizeof extra);
    for (uint8_t i = 0; i < 8; i++) {
        int32_t mv = analog_battery_mv();
        h = fnv1a(h, (const uint8_t *)&mv, 1);
        while (clock_us() < 200UL * (i + 1) + 2000UL)
            ;  /* let the ADC convert again */
    }
    return h ? h : 1;
}

int main(void) {
    static const core_identity_t id = {
        FIRMWARE_VERSION, BOARD_ID, COUNTS_PER_REV, MAX_TELEMETRY_HZ,
        (BATTERY_CURRENT_HALL ? CAPABILITIES_BATTERY_CURRENT : 0) | (MOTOR_CURRENT_HALL ? CAPABILITIES_MOTOR_CURRENT : 0) |
            CAPABILITIES_PACKET_SERIAL_DRIVERS,
    };
    DDRH |= _BV(PH4);       /* pin 7: drivers' enable, low until the core says otherwise */
    PORTH &= (uint8_t)~_BV(PH4);
#if ESTOP_INPUT
    PORTE |= _BV(PE4);      /* pin 2 with pull-up: button to ground */
#endif
    clock_init();
    host_uart_init(PROTO_BAUDRATE);
    sabertooth_init();
    ls7366r_init();
    analog_init();
    sei();
    uint32_t boot_id = draw_boot_id();
    core_boot(&core, &id, boot_id, clock_us());
    wdt_enable(WDTO_120MS);  /* a hung firmware resets (and the drivers' timeout stops them) */
    uint8_t odd = 0;
    for (;;) {
        wdt_reset();
        uint8_t buf[32];
        uint8_t n = host_uart_read(buf, sizeof buf);
        uint8_t tick = 0;
        if (n)
            core_rx(&core, buf, n, clock_us());
        while (clock_take_tick()) {
            tick = 1;
            if ((odd ^= 1))
                analog_start_round();  /* every millisecond */
            sabertooth_tick();         /* start-up wait (1.5 s, 0xAA, 0.5 s), refresh, setup resends */
        }
        /* the core's own work (faults, watchdog, telemetry) at each 500 µs tick (the watchdog's
           resolution: its stop packets then leave within timeout + 0.5 ms + 4 packets), sample and host
           frame; other wake-ups (a byte sent, a conversion done) go straight back to sleep */
        if (n || tick || hal_avr_sample_ready())
            core_poll(&core, clock_us());
        cli();
        if (!host_uart_available() && !hal_avr_sample_ready()) {
            sleep_enable();  /* idle: every interrupt (byte, tick, sample) wakes the loop */
            sei();
            sleep_cpu();
            sleep_disable();
        }
        sei();
    }
}
