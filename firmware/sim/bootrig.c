/* bootrig: the Arduino Mega as a user meets it, in simavr. The chip starts in the stock
   stk500v2 bootloader (Debian arduino-core-avr's stk500boot_v2_mega2560.hex, placed where
   BOOTRST puts the reset vector: byte 0x3E000); UART0 is a pseudo-terminal (simavr's
   uart_pty), so `avrdude -c wiring -P <pty>` flashes the application into it as into a board.
   Flash is kept in a file between runs (as the chip keeps it across power cycles).

   Usage: bootrig BOOTLOADER.hex FLASH.bin SECONDS [HANG_S HANG_PC]
     FLASH.bin: the flash image (created erased if missing; written back at the end, also on
          SIGTERM / SIGINT).
     HANG_S HANG_PC: HANG_S seconds after the application first started, the firmware hangs:
          the program counter is set to HANG_PC (a byte address in the application: an
          endless loop such as avr-libc's __stop_program, "cli; rjmp ."), so the watchdog the
          firmware armed stops being fed and simavr's watchdog resets the chip.
   Events on stdout, one per line, with the board time (s):
     PTY <path>            the pseudo-terminal to open (also /tmp/simavr-uart0)
     RESET <t> <cause>     power-on or watchdog
     APP <t>               the program counter left the bootloader for the application
     BOOT <t> from <pc>    the program counter entered the bootloader (last application pc)
     HANG <t>              the firmware was made to hang (HANG_S)
     END <t>
   A signal (SIGUSR1) resets the chip as the Mega's DTR line does when a port is opened.

   BOOTRIG_REALTIME=1 in the environment runs the chip at a real Mega's pace, for a host that
   times its own silences: simulated time is held to the wall clock (never ahead of it; END then
   also prints the largest lag behind it), and UART polls do not sleep. simavr's default
   (AVR_UART_FLAG_POLL_SLEEP) sleeps on every poll of an empty receiver, which slows the
   bootloader's programming-mode byte wait (a poll every 10 cycles) about a hundredfold:
   its 5 s silence timeout would take minutes of wall time. */
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "avr_ioport.h"
#include "avr_uart.h"
#include "sim_avr.h"
#include "sim_hex.h"
#include "uart_pty.h"

#define BOOT_START 0x3E000u
#define FLASH_SIZE 0x40000u

static volatile sig_atomic_t dtr_reset, stop;
static void on_usr1(int sig) { (void)sig; dtr_reset = 1; }
static void on_term(int sig) { (void)sig; stop = 1; }

static int verbose;

static double wall_s(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec + ts.tv_nsec * 1e-9;
}

/* Cycles asleep are skipped, not slept on the host (simavr's default sleeps in real time). */
static void no_sleep(avr_t *a, avr_cycle_count_t how_long) { (void)a; (void)how_long; }
static void quiet(avr_t *a, const int level, const char *fmt, va_list ap) {
    (void)a;
    if (level <= LOG_ERROR || verbose)
        vfprintf(stderr, fmt, ap);
}

int main(int argc, char **argv) {
    if (argc < 4) {
        fprintf(stderr, "usage: bootrig BOOTLOADER.hex FLASH.bin SECONDS [HANG_S HANG_PC]\n");
        return 2;
    }
    double hang_s = argc > 5 ? atof(argv[4]) : -1;
    unsigned long hang_pc = argc > 5 ? strtoul(argv[5], NULL, 0) : 0;
    avr_global_logger_set(quiet);
    avr_t *avr = avr_make_mcu_by_name("atmega2560");
    if (!avr) {
        fprintf(stderr, "bootrig: simavr has no atmega2560\n");
        return 1;
    }
    avr_init(avr);
    avr->frequency = 16000000;
    avr->vcc = avr->avcc = avr->aref = 5000;
    avr->sleep = no_sleep;
    verbose = getenv("BOOTRIG_TRACE") != NULL;
    avr->log = verbose ? LOG_TRACE : LOG_ERROR;
    memset(avr->flash, 0xFF, FLASH_SIZE);
    FILE *fl = fopen(argv[2], "rb");
    if (fl) {
        size_t n = fread(avr->flash, 1, BOOT_START, fl);
        (void)n;
        fclose(fl);
    }
    ihex_chunk_p chunks = NULL;
    int nc = read_ihex_chunks(argv[1], &chunks);
    if (nc <= 0) {
        fprintf(stderr, "bootrig: cannot read %s\n", argv[1]);
        return 1;
    }
    for (int i = 0; i < nc; i++) {
        if (chunks[i].baseaddr + chunks[i].size > FLASH_SIZE) {
            fprintf(stderr, "bootrig: %s: data beyond the flash\n", argv[1]);
            return 1;
        }
        memcpy(avr->flash + chunks[i].baseaddr, chunks[i].data, chunks[i].size);
    }
    avr->codeend = FLASH_SIZE - 1;
    avr->reset_pc = BOOT_START;  /* BOOTRST programmed: reset jumps to the boot section */
    avr->pc = BOOT_START;
    uint32_t uf = 0;
    avr_ioctl(avr, AVR_IOCTL_UART_GET_FLAGS('0'), &uf);
    uf &= ~(uint32_t)AVR_UART_FLAG_STDIO;
    const char *rt = getenv("BOOTRIG_REALTIME");
    int realtime = rt && *rt && strcmp(rt, "0") != 0;
    if (realtime)
        uf &= ~(uint32_t)AVR_UART_FLAG_POLL_SLEEP;
    avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &uf);
    uart_pty_t pty;
    memset(&pty, 0, sizeof pty);
    uart_pty_init(avr, &pty);
    uart_pty_connect(&pty, '0');
    printf("PTY %s\n", pty.pty.slavename);
    printf("RESET 0.000000 power-on\n");
    fflush(stdout);
    signal(SIGUSR1, on_usr1);
    signal(SIGTERM, on_term);
    signal(SIGINT, on_term);
    unsigned long long end = (unsigned long long)(atof(argv[3]) * avr->frequency);
    int in_app = 0, hung = 0;
    unsigned long long app_first = 0;
    int state = cpu_Running;
    uint32_t last_app_pc = 0;
    double wall0 = wall_s(), max_lag = 0;
    unsigned long long next_pace = 0;
    while (avr->cycle < end && state != cpu_Done && state != cpu_Crashed && !stop) {
        if (avr->pc < BOOT_START)
            last_app_pc = avr->pc;
        state = avr_run(avr);
        double t = avr->cycle / (double)avr->frequency;
        if (realtime && avr->cycle >= next_pace) {  /* every 1 ms of simulated time */
            next_pace = avr->cycle + avr->frequency / 1000;
            double ahead = t - (wall_s() - wall0);
            if (ahead > 0.001) {
                struct timespec ts = {(time_t)ahead, (long)((ahead - (time_t)ahead) * 1e9)};
                nanosleep(&ts, NULL);
            } else if (-ahead > max_lag) {
                max_lag = -ahead;
            }
        }
        int app = avr->pc < BOOT_START;
        if (app != in_app) {
            if (app)
                printf("APP %.6f\n", t);
            else
                printf("BOOT %.6f from 0x%05x\n", t, (unsigned)last_app_pc);
            fflush(stdout);
            in_app = app;
            if (app && !app_first)
                app_first = avr->cycle;
            if (!app && avr->pc == BOOT_START && app_first) {
                uint8_t mcusr = avr->data[0x54];
                printf("RESET %.6f %s\n", t, mcusr & (1 << 3) ? "watchdog" : "other");
                fflush(stdout);
            }
        }
        if (dtr_reset) {
            dtr_reset = 0;
            avr_reset(avr);
            avr->pc = BOOT_START;
            printf("RESET %.6f dtr\n", t);
            fflush(stdout);
        }
        if (hang_s >= 0 && !hung && in_app && avr->cycle - app_first > hang_s * avr->frequency) {
            hung = 1;
            avr->pc = (avr_flashaddr_t)hang_pc;
            printf("HANG %.6f\n", t);
            fflush(stdout);
        }
    }
    printf("END %.6f%s", avr->cycle / (double)avr->frequency, state == cpu_Crashed ? " crashed" : "");
    if (realtime)
        printf(" lag %.3f", max_lag);
    printf("\n");
    fl = fopen(argv[2], "wb");
    if (fl) {
        fwrite(avr->flash, 1, BOOT_START, fl);
        fclose(fl);
    }
    fflush(stdout);
    /* not uart_pty_stop(): in simavr 1.6 it joins a thread that never returns (it waits in
       select() on the pty). _exit, not return: exit handlers tearing the process down while that
       thread is still in select() aborted it once ("bit out of range 0 - FD_SETSIZE"), exit -6 */
    _exit(state == cpu_Crashed);
}
