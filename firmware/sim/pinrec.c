/* pinrec: run a firmware .elf on a bare simulated ATmega2560 (simavr, nothing attached: no
   host bytes, no SPI slave, no ADC input) and record the levels of chosen Arduino Mega pins
   with the cycle of every change. Independent of the project's rig (firmware/sim/fil.c):
   it is the "scope on the pins" the firmware tests check the motor line with.

   Usage: pinrec FIRMWARE.elf SECONDS PORTBIT...      e.g.  pinrec omnibot.elf 2.5 H3 H4
   Output, one line per event:
     F 16000000                      clock frequency
     I <port><bit> <level>           level at cycle 0 (PORT bit, as written)
     C <cycle> <port><bit> <level>   a change of the written level
     D <port><bit> <ddr> <port>      data-direction and output bits at the end
     E <cycle>                       end of the run */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "avr_ioport.h"
#include "avr_uart.h"
#include "sim_avr.h"
#include "sim_elf.h"

#define MAX_PINS 8

typedef struct {
    char port;
    int bit;
    int level;
} pin_t;

static avr_t *avr;
static pin_t pins[MAX_PINS];

static void changed(struct avr_irq_t *irq, uint32_t v, void *p) {
    (void)irq;
    pin_t *pin = p;
    int level = v ? 1 : 0;
    if (level == pin->level)
        return;
    pin->level = level;
    printf("C %llu %c%d %d\n", (unsigned long long)avr->cycle, pin->port, pin->bit, level);
}

static void quiet(avr_t *a, const int level, const char *fmt, va_list ap) {
    (void)a;
    if (level <= LOG_ERROR)
        vfprintf(stderr, fmt, ap);
}

int main(int argc, char **argv) {
    if (argc < 4) {
        fprintf(stderr, "usage: pinrec FIRMWARE.elf SECONDS PORTBIT...  (e.g. H3 H4)\n");
        return 2;
    }
    int n = argc - 3;
    if (n > MAX_PINS) {
        fprintf(stderr, "pinrec: at most %d pins\n", MAX_PINS);
        return 2;
    }
    elf_firmware_t fw;
    memset(&fw, 0, sizeof fw);
    avr_global_logger_set(quiet);
    if (elf_read_firmware(argv[1], &fw) != 0) {
        fprintf(stderr, "pinrec: cannot read %s\n", argv[1]);
        return 1;
    }
    avr = avr_make_mcu_by_name("atmega2560");
    if (!avr) {
        fprintf(stderr, "pinrec: simavr has no atmega2560\n");
        return 1;
    }
    avr_init(avr);
    fw.frequency = 16000000;
    avr_load_firmware(avr, &fw);
    avr->frequency = 16000000;
    avr->log = LOG_ERROR;
    uint32_t fl = 0;
    avr_ioctl(avr, AVR_IOCTL_UART_GET_FLAGS('0'), &fl);
    fl &= ~(uint32_t)AVR_UART_FLAG_STDIO;
    avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &fl);
    printf("F %u\n", (unsigned)avr->frequency);
    for (int i = 0; i < n; i++) {
        const char *a = argv[3 + i];
        if (strlen(a) != 2 || a[0] < 'A' || a[0] > 'L' || a[1] < '0' || a[1] > '7') {
            fprintf(stderr, "pinrec: pin %s: expected PORT letter and bit, e.g. H3\n", a);
            return 2;
        }
        pins[i].port = a[0];
        pins[i].bit = a[1] - '0';
        pins[i].level = 0;
        printf("I %c%d 0\n", pins[i].port, pins[i].bit);
        avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(a[0]), pins[i].bit), changed, &pins[i]);
    }
    unsigned long long end = (unsigned long long)(atof(argv[2]) * avr->frequency);
    int state = cpu_Running;
    while (avr->cycle < end && state != cpu_Done && state != cpu_Crashed)
        state = avr_run(avr);
    for (int i = 0; i < n; i++) {
        avr_ioport_state_t st;
        avr_ioctl(avr, AVR_IOCTL_IOPORT_GETSTATE(pins[i].port), &st);
        printf("D %c%d %d %d\n", pins[i].port, pins[i].bit, (st.ddr >> pins[i].bit) & 1, (st.port >> pins[i].bit) & 1);
    }
    printf("E %llu\n", (unsigned long long)avr->cycle);
    if (state == cpu_Crashed) {
        fprintf(stderr, "pinrec: the simulated chip crashed\n");
        return 1;
    }
    return 0;
}
