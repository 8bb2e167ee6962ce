/* Firmware-in-the-loop harness: the board firmware (.elf) on a simulated ATmega2560 (simavr),
   with the robot's electronics around it. Built as a shared library and stepped in lockstep
   by omnibench/sim/firmware/fil.py, which supplies the physics (omnibench's plant):

   - UART0 (host link): bytes from the host are queued and fed at the line rate (simavr's
     UART paces them, XON/XOFF); bytes the firmware sends are collected with their cycle.
   - USART1 (Sabertooth packet serial): decoded into packets (address, command, value)
     stamped with the cycle of their last byte; bad checksums are counted.
   - SPI + PORTL bits 3..0 (pins 46..49): four LS7366R counters. Each counts
     floor(c0 + rate * (cycle - cycle0) / F_CPU) from the counts and rates the plant gave at
     cycle0, so a latch between two lockstep updates reads an extrapolated count.
   - ADC: millivolts per channel, set by the caller.
   - Pin 7 (PH4): the drivers' enable line, read by the caller.
   - CPU load: cycles spent asleep are counted by our sleep callback (which never sleeps). */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "avr_adc.h"
#include "avr_ioport.h"
#include "avr_spi.h"
#include "avr_uart.h"
#include "sim_avr.h"
#include "sim_elf.h"

#define F_CPU 16000000.0
#define RING 65536
#define PACKETS 8192

typedef struct {
    uint8_t state;       /* 0 idle (deselected), 1 expects instruction, 2 reading OTR/CNTR, 3 writing */
    uint8_t instr, index;
    int32_t otr;
    double c0, rate;     /* plant count at cycle0, counts per second */
    uint64_t cycle0;
    int64_t zero;        /* count at the last CLR_CNTR */
    uint8_t mdr0, mdr1;
} ls7366r_t;

typedef struct {
    uint64_t cycle;
    uint8_t address, command, value;
} packet_t;

typedef struct {
    avr_t *avr;
    elf_firmware_t fw;
    /* host -> board */
    uint8_t in[RING];
    uint32_t in_head, in_tail;
    int feeding;
    /* board -> host */
    uint8_t out[RING];
    uint64_t out_cycle[RING];
    uint32_t out_head, out_tail, out_lost;
    /* Sabertooth */
    uint8_t pk[4], pk_n;
    packet_t packets[PACKETS];
    uint32_t pkt_head, pkt_tail, pkt_bad, pkt_lost;
    /* LS7366R */
    ls7366r_t enc[4];
    uint8_t cs_low;      /* bit i: chip i (pin 46 + i) selected */
    uint64_t sleep_cycles;
} fil_t;

static fil_t *current;  /* the sleep callback has no user pointer: one harness per process */

static void sleep_count(avr_t *avr, avr_cycle_count_t how_long) {
    (void)avr;
    if (current)
        current->sleep_cycles += how_long + 1;
}

static void quiet_logger(avr_t *avr, const int level, const char *fmt, va_list ap) {
    (void)avr;
    if (level <= LOG_ERROR) {
        fprintf(stderr, "simavr: ");
        vfprintf(stderr, fmt, ap);
    }
}

/* ------------------------------------------------------------------ UART0: host link */
/* Host bytes enter the chip one per character time (10 bits at 115200 baud), as on the
   wire; simavr's receive FIFO then never holds more than one, so no flow control is needed. */
#define HOST_BYTE_CYCLES ((avr_cycle_count_t)(F_CPU * 10 / 115200))

static avr_cycle_count_t feed_host_byte(avr_t *avr, avr_cycle_count_t when, void *param) {
    fil_t *f = param;
    if (f->in_tail == f->in_head) {
        f->feeding = 0;
        return 0;
    }
    avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT), f->in[f->in_tail % RING]);
    f->in_tail++;
    return when + HOST_BYTE_CYCLES;
}

static void push_host_bytes(fil_t *f) {
    if (!f->feeding && f->in_tail != f->in_head) {
        f->feeding = 1;
        avr_cycle_timer_register(f->avr, 1, feed_host_byte, f);
    }
}

static void uart0_out(struct avr_irq_t *irq, uint32_t v, void *p) {
    (void)irq;
    fil_t *f = p;
    if (f->out_head - f->out_tail >= RING) {
        f->out_lost++;
        return;
    }
    f->out[f->out_head % RING] = (uint8_t)v;
    f->out_cycle[f->out_head % RING] = f->avr->cycle;
    f->out_head++;
}

/* ------------------------------------------------------------------ USART1: Sabertooth */
static void uart1_out(struct avr_irq_t *irq, uint32_t v, void *p) {
    (void)irq;
    fil_t *f = p;
    uint8_t b = (uint8_t)v;
    if (b & 0x80) {  /* an address byte starts a packet (command, value, checksum are < 128) */
        f->pk[0] = b;
        f->pk_n = 1;
        return;
    }
    if (f->pk_n == 0 || f->pk_n >= 4)
        return;
    f->pk[f->pk_n++] = b;
    if (f->pk_n < 4)
        return;
    if (((f->pk[0] + f->pk[1] + f->pk[2]) & 0x7F) != f->pk[3]) {
        f->pkt_bad++;
        return;
    }
    if (f->pkt_head - f->pkt_tail >= PACKETS) {
        f->pkt_lost++;
        return;
    }
    packet_t *k = &f->packets[f->pkt_head++ % PACKETS];
    k->cycle = f->avr->cycle;
    k->address = f->pk[0];
    k->command = f->pk[1];
    k->value = f->pk[2];
}

/* ------------------------------------------------------------------ SPI: LS7366R x4 */
static int64_t count_now(fil_t *f, int i) {
    ls7366r_t *e = &f->enc[i];
    double c = e->c0 + e->rate * (double)(f->avr->cycle - e->cycle0) / F_CPU;
    return (int64_t)floor(c) - e->zero;
}

static void cs_pin(fil_t *f, int chip, int low) {
    ls7366r_t *e = &f->enc[chip];
    if (low && !(f->cs_low & (1 << chip))) {
        e->state = 1;
        e->index = 0;
    }
    if (!low)
        e->state = 0;
    f->cs_low = (uint8_t)(low ? (f->cs_low | (1 << chip)) : (f->cs_low & ~(1 << chip)));
}

static void cs_pin0(struct avr_irq_t *irq, uint32_t v, void *p) { (void)irq; cs_pin(p, 0, !v); }
static void cs_pin1(struct avr_irq_t *irq, uint32_t v, void *p) { (void)irq; cs_pin(p, 1, !v); }
static void cs_pin2(struct avr_irq_t *irq, uint32_t v, void *p) { (void)irq; cs_pin(p, 2, !v); }
static void cs_pin3(struct avr_irq_t *irq, uint32_t v, void *p) { (void)irq; cs_pin(p, 3, !v); }

static uint8_t chip_byte(fil_t *f, int i, uint8_t b) {
    ls7366r_t *e = &f->enc[i];
    if (e->state == 1) {
        e->instr = b;
        e->index = 0;
        switch (b & 0xF8) {
        case 0x20: e->zero += count_now(f, i); e->state = 3; break;      /* CLR_CNTR */
        case 0xE8: e->otr = (int32_t)count_now(f, i); e->state = 3; break; /* LOAD_OTR */
        case 0x60: e->otr = (int32_t)count_now(f, i); e->state = 2; break; /* RD_CNTR */
        case 0x68: e->state = 2; break;                                  /* RD_OTR */
        default: e->state = 3; break;                                    /* WR_MDR0/1 etc. */
        }
        return 0;
    }
    if (e->state == 2) {
        uint8_t r = (uint8_t)((uint32_t)e->otr >> (8 * (3 - (e->index & 3))));
        e->index++;
        return r;
    }
    if (e->state == 3) {
        if (e->instr == 0x88) e->mdr0 = b;
        if (e->instr == 0x90) e->mdr1 = b;
    }
    return 0;
}

static void spi_out(struct avr_irq_t *irq, uint32_t v, void *p) {
    (void)irq;
    fil_t *f = p;
    uint8_t reply = 0;
    for (int i = 0; i < 4; i++)
        if (f->cs_low & (1 << i))
            reply |= chip_byte(f, i, (uint8_t)v);  /* several selected: MISO lines wired-or */
    avr_raise_irq(avr_io_getirq(f->avr, AVR_IOCTL_SPI_GETIRQ(0), SPI_IRQ_INPUT), reply);
}

/* simavr 1.6 completes every SPI byte 100 µs after SPDR is written, whatever the clock
   divider: 50 times the real ATmega2560 at F_CPU/4. That would make a counter read cost
   2 ms of simulated CPU. We replace SPDR's write handler with one that completes the byte
   after 8 SPI clocks, as the chip does (the rest of simavr's SPI model is kept). */
static avr_cycle_count_t spi_byte_done(avr_t *avr, avr_cycle_count_t when, void *param) {
    (void)when;
    avr_spi_t *p = param;
    if (avr_regbit_get(avr, p->spe) && avr_regbit_get(avr, p->mstr)) {
        avr_raise_interrupt(avr, &p->spi);
        avr_raise_irq(p->io.irq + SPI_IRQ_OUTPUT, avr->data[p->r_spdr]);
    }
    return 0;
}

static void spdr_write(avr_t *avr, avr_io_addr_t addr, uint8_t v, void *param) {
    static const uint8_t divider[4] = {4, 16, 64, 128};
    avr_spi_t *p = param;
    avr_regbit_clear(avr, p->spi.raised);
    avr_core_watch_write(avr, addr, v);
    uint16_t d = divider[avr->data[p->r_spcr] & 3];
    if (avr->data[p->r_spsr] & 1)  /* SPI2X */
        d >>= 1;
    avr_cycle_timer_register(avr, (avr_cycle_count_t)d * 8, spi_byte_done, p);
}

/* ------------------------------------------------------------------ API (ctypes) */
fil_t *fil_open(const char *elf, char *err, int errlen) {
    fil_t *f = calloc(1, sizeof *f);
    if (!f) return NULL;
    avr_global_logger_set(quiet_logger);
    if (elf_read_firmware(elf, &f->fw) != 0) {
        snprintf(err, errlen, "cannot read %s", elf);
        free(f);
        return NULL;
    }
    f->avr = avr_make_mcu_by_name("atmega2560");
    if (!f->avr) {
        snprintf(err, errlen, "simavr has no atmega2560");
        free(f);
        return NULL;
    }
    avr_init(f->avr);
    f->fw.frequency = 16000000;
    avr_load_firmware(f->avr, &f->fw);
    f->avr->frequency = 16000000;
    f->avr->vcc = f->avr->avcc = f->avr->aref = 5000;
    f->avr->sleep = sleep_count;
    f->avr->log = LOG_ERROR;
    current = f;
    for (int u = 0; u < 2; u++) {
        uint32_t fl = 0;
        avr_ioctl(f->avr, AVR_IOCTL_UART_GET_FLAGS('0' + u), &fl);
        fl &= ~(uint32_t)(AVR_UART_FLAG_STDIO | AVR_UART_FLAG_POLL_SLEEP);
        avr_ioctl(f->avr, AVR_IOCTL_UART_SET_FLAGS('0' + u), &fl);
    }
    avr_irq_register_notify(avr_io_getirq(f->avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT), uart0_out, f);
    avr_irq_register_notify(avr_io_getirq(f->avr, AVR_IOCTL_UART_GETIRQ('1'), UART_IRQ_OUTPUT), uart1_out, f);
    avr_irq_register_notify(avr_io_getirq(f->avr, AVR_IOCTL_SPI_GETIRQ(0), SPI_IRQ_OUTPUT), spi_out, f);
    {
        avr_io_addr_t spdr = 0x4E;  /* ATmega2560 SPDR (data address) */
        avr_spi_t *spi = f->avr->io[AVR_DATA_TO_IO(spdr)].w.param;
        if (spi && spi->r_spdr == spdr)
            f->avr->io[AVR_DATA_TO_IO(spdr)].w.c = spdr_write;
    }
    void (*cs[4])(struct avr_irq_t *, uint32_t, void *) = {cs_pin0, cs_pin1, cs_pin2, cs_pin3};
    for (int i = 0; i < 4; i++)  /* pins 46..49 = PL3..PL0 */
        avr_irq_register_notify(avr_io_getirq(f->avr, AVR_IOCTL_IOPORT_GETIRQ('L'), 3 - i), cs[i], f);
    return f;
}

void fil_close(fil_t *f) {
    if (!f) return;
    if (current == f) current = NULL;
    avr_terminate(f->avr);
    free(f);
}

/* Run until the cycle count reaches `cycle`; returns simavr's cpu state (cpu_Done/cpu_Crashed end it). */
int fil_run_until(fil_t *f, uint64_t cycle) {
    int st = f->avr->state;
    while (f->avr->cycle < cycle) {
        st = avr_run(f->avr);
        if (st == cpu_Done || st == cpu_Crashed)
            break;
    }
    return st;
}

uint64_t fil_cycles(fil_t *f) { return f->avr->cycle; }
uint64_t fil_sleep_cycles(fil_t *f) { return f->sleep_cycles; }

int fil_host_write(fil_t *f, const uint8_t *b, int n) {
    int k = 0;
    while (k < n && f->in_head - f->in_tail < RING)
        f->in[f->in_head++ % RING] = b[k++];
    push_host_bytes(f);
    return k;
}

uint32_t fil_host_pending(fil_t *f) { return f->in_head - f->in_tail; }

/* Bytes the firmware sent, with the cycle each was written. */
int fil_host_read(fil_t *f, uint8_t *buf, uint64_t *cycles, int max) {
    int n = 0;
    while (n < max && f->out_tail != f->out_head) {
        buf[n] = f->out[f->out_tail % RING];
        if (cycles) cycles[n] = f->out_cycle[f->out_tail % RING];
        n++;
        f->out_tail++;
    }
    return n;
}

int fil_packets(fil_t *f, uint64_t *cycle, uint8_t *address, uint8_t *command, uint8_t *value, int max) {
    int n = 0;
    while (n < max && f->pkt_tail != f->pkt_head) {
        packet_t *k = &f->packets[f->pkt_tail++ % PACKETS];
        cycle[n] = k->cycle;
        address[n] = k->address;
        command[n] = k->command;
        value[n] = k->value;
        n++;
    }
    return n;
}

uint32_t fil_packets_bad(fil_t *f) { return f->pkt_bad; }

/* The four counters' plant counts (raw counter sense) and rates (counts/s) as of now. */
void fil_set_counters(fil_t *f, const double *counts, const double *rates) {
    for (int i = 0; i < 4; i++) {
        f->enc[i].c0 = counts[i];
        f->enc[i].rate = rates[i];
        f->enc[i].cycle0 = f->avr->cycle;
    }
}

void fil_set_adc_mv(fil_t *f, int channel, uint32_t mv) {
    avr_raise_irq(avr_io_getirq(f->avr, AVR_IOCTL_ADC_GETIRQ, ADC_IRQ_ADC0 + channel), mv);
}

/* Pin 7 (PH4): 1 if driven high (drivers enabled). */
int fil_pin7(fil_t *f) {
    avr_ioport_state_t st;
    if (avr_ioctl(f->avr, AVR_IOCTL_IOPORT_GETSTATE('H'), &st) != 0)
        return 0;
    return (st.port >> 4) & st.ddr >> 4 & 1;
}

/* Profiling aid: run until `cycle`, adding the cycles of each instruction to hist[pc / 2]
   (hist has 131072 entries, one per flash word). */
int fil_run_profiled(fil_t *f, uint64_t cycle, uint32_t *hist) {
    int st = f->avr->state;
    while (f->avr->cycle < cycle) {
        uint32_t pc = f->avr->pc;
        uint64_t c0 = f->avr->cycle;
        int running = f->avr->state == cpu_Running;
        st = avr_run(f->avr);
        if (running)
            hist[(pc / 2) & 131071] += (uint32_t)(f->avr->cycle - c0);
        if (st == cpu_Done || st == cpu_Crashed)
            break;
    }
    return st;
}
