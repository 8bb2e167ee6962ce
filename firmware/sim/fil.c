/* Firmware-in-the-loop harness: the board firmware (.elf) on a simulated ATmega2560 (simavr),
   with the robot's electronics around it. Built as a shared library and stepped in lockstep
   by omnibench/sim/firmware/fil.py, which supplies the physics (omnibench's plant) and the
   robot's wiring (a file in omnibench/sim/firmware/robots/, never the firmware build's settings).

   - UART0 (host link): bytes from the host are queued and fed at the line rate (simavr's
     UART paces them, XON/XOFF); bytes the firmware sends are collected with their cycle.
   - The Sabertooth S1 line, as the drivers hear it: either a pin (e.g. pin 6, PH3), whose
     levels are sampled mid-bit at the drivers' rate from each falling edge (start bit,
     8 data bits, stop bit: a byte at another rate is garbage or a framing error, as for the
     driver), or TX1 (pin 18), where simavr's USART1 gives whole bytes: they count only if the
     USART's programmed rate is within 3 % of the drivers'. An autobauding driver hears
     nothing until an 0xAA, whose bit time then sets its rate. The bytes go to the caller,
     which models the drivers (packets, checksum, serial timeout).
   - Activity the robot does not listen to is counted too (edges on pin 6, bytes on USART1),
     so a test can say where the firmware talks when the drivers hear nothing.
   - SPI + port L (pins 42..49): LS7366R counters at the chip-select pins the robot has
     them on. Each counts floor(c0 + rate * (cycle - cycle0) / F_CPU) from the counts and
     rates the plant gave at cycle0, so a latch between two lockstep updates reads an
     extrapolated count. Every selected chip takes the instruction (MOSI is shared); a byte
     clocked with several chips selected is counted as MISO contention (each selected chip
     drives MISO then: the datasheet gives MISO high impedance only while SS is high) and
     reads as the AND of their outputs.
   - ADC: millivolts per channel, set by the caller.
   - Output pins (e.g. pin 7, PH4, the drivers' enable), read by the caller.
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

typedef struct {
    uint8_t state;       /* 0 idle (deselected), 1 expects instruction, 2 reading OTR/CNTR, 3 writing */
    uint8_t instr, index;
    int32_t otr;
    double c0, rate;     /* plant count at cycle0, counts per second */
    uint64_t cycle0;
    int64_t zero;        /* count at the last CLR_CNTR */
    uint8_t mdr0, mdr1;
    uint8_t pin_bit;     /* port L bit of its chip select (0xFF: no chip) */
} ls7366r_t;

#define LINE_BYTES 8192
typedef struct {
    int mode;            /* 0 off, 1 a pin sampled bit by bit, 2 USART1's bytes (TX1) */
    char port;
    int bit;
    double bit_cycles;   /* the drivers' bit time (0: autobaud, not yet set) */
    int autobaud;
    int watching;        /* the pin's notify is registered */
    int level;           /* the pin's level now (idle high) */
    int busy;            /* a byte is being sampled */
    uint64_t start;      /* cycle of its start bit's falling edge */
    int sampled;         /* bits sampled so far */
    uint16_t shift;
    uint64_t ab_edges[10];  /* autobaud: edges of the candidate 0xAA */
    int ab_n;
    uint8_t bytes[LINE_BYTES];
    uint64_t cycles[LINE_BYTES];
    uint32_t head, tail, lost;
    uint32_t framing_errors, wrong_rate_bytes;
} line_t;

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
    /* Sabertooth S1 */
    line_t line;
    uint32_t pin6_edges, usart1_bytes;
    /* LS7366R */
    ls7366r_t enc[4];
    uint8_t cs_low;      /* port L bits now low */
    uint32_t contention; /* SPI bytes clocked with several chips selected */
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

/* ------------------------------------------------------------------ the Sabertooth S1 line */
static void line_put(fil_t *f, uint8_t b) {
    line_t *l = &f->line;
    if (l->head - l->tail >= LINE_BYTES) {
        l->lost++;
        return;
    }
    l->bytes[l->head % LINE_BYTES] = b;
    l->cycles[l->head % LINE_BYTES] = f->avr->cycle;
    l->head++;
}

/* One sample per bit time, mid-bit, from the start bit's falling edge (as a UART receiver). */
static avr_cycle_count_t line_sample(avr_t *avr, avr_cycle_count_t when, void *param) {
    (void)avr;
    (void)when;
    fil_t *f = param;
    line_t *l = &f->line;
    int k = l->sampled++;
    if (k == 0 && l->level) {           /* a glitch, not a start bit */
        l->busy = 0;
        return 0;
    }
    if (k >= 1 && k <= 8)
        l->shift |= (uint16_t)(l->level << (k - 1));
    if (k == 9) {
        l->busy = 0;
        if (!l->level)
            l->framing_errors++;         /* no stop bit: the driver drops the byte */
        else
            line_put(f, (uint8_t)l->shift);
        return 0;
    }
    return l->start + (avr_cycle_count_t)((k + 1.5) * l->bit_cycles + 0.5);
}

/* Autobaud: the edges of 0xAA framed 8N1 fall at 0, 2, 3, 4, 5, 6, 7, 8 bit times. */
static void autobaud_edge(fil_t *f) {
    line_t *l = &f->line;
    if (l->ab_n == 0 && l->level)
        return;
    if (l->ab_n > 0 && f->avr->cycle - l->ab_edges[0] > 16000000ULL / 1200 * 10) {
        l->ab_n = 0;                     /* too slow for any rate: start over */
        if (l->level)
            return;
    }
    l->ab_edges[l->ab_n++] = f->avr->cycle;
    if (l->ab_n < 8)
        return;
    double bit = (double)(l->ab_edges[7] - l->ab_edges[0]) / 8.0;
    static const double at[8] = {0, 2, 3, 4, 5, 6, 7, 8};
    int ok = 1;
    for (int i = 1; i < 8; i++)
        if (fabs((double)(l->ab_edges[i] - l->ab_edges[0]) / bit - at[i]) > 0.25)
            ok = 0;
    l->ab_n = 0;
    if (ok)
        l->bit_cycles = bit;             /* the rate is set; the 0xAA itself is not a packet byte */
}

static void line_pin(struct avr_irq_t *irq, uint32_t v, void *p) {
    (void)irq;
    fil_t *f = p;
    line_t *l = &f->line;
    int level = v ? 1 : 0;
    if (level == l->level)
        return;
    l->level = level;
    if (l->mode != 1)
        return;
    if (l->bit_cycles == 0) {
        autobaud_edge(f);
        return;
    }
    if (!level && !l->busy) {
        l->busy = 1;
        l->start = f->avr->cycle;
        l->sampled = 0;
        l->shift = 0;
        avr_cycle_timer_register(f->avr, (avr_cycle_count_t)(0.5 * l->bit_cycles + 0.5), line_sample, f);
    }
}

static void pin6_edge(struct avr_irq_t *irq, uint32_t v, void *p) {
    (void)irq;
    (void)v;
    ((fil_t *)p)->pin6_edges++;
}

/* USART1's programmed rate (UBRR1, U2X1). */
static double usart1_baud(fil_t *f) {
    uint16_t ubrr = (uint16_t)(f->avr->data[0xCC] | (f->avr->data[0xCD] << 8));  /* UBRR1L/H */
    int u2x = (f->avr->data[0xC8] >> 1) & 1;                                      /* UCSR1A.U2X1 */
    return F_CPU / ((u2x ? 8.0 : 16.0) * (ubrr + 1));
}

static void uart1_out(struct avr_irq_t *irq, uint32_t v, void *p) {
    (void)irq;
    fil_t *f = p;
    line_t *l = &f->line;
    f->usart1_bytes++;
    if (l->mode != 2)
        return;
    double rate = usart1_baud(f);
    if (l->bit_cycles == 0) {            /* autobaud: an 0xAA at any rate sets it */
        if ((uint8_t)v == 0xAA)
            l->bit_cycles = F_CPU / rate;
        return;
    }
    if (fabs(F_CPU / rate / l->bit_cycles - 1.0) > 0.03) {
        l->wrong_rate_bytes++;           /* at another rate the driver reads garbage */
        return;
    }
    line_put(f, (uint8_t)v);
}

/* ------------------------------------------------------------------ SPI: LS7366R x4 */
static int64_t count_now(fil_t *f, int i) {
    ls7366r_t *e = &f->enc[i];
    double c = e->c0 + e->rate * (double)(f->avr->cycle - e->cycle0) / F_CPU;
    return (int64_t)floor(c) - e->zero;
}

/* Port L changed: each chip follows its own chip-select bit. */
static void port_l(struct avr_irq_t *irq, uint32_t v, void *p) {
    (void)irq;
    fil_t *f = p;
    uint8_t low = (uint8_t)~v;
    for (int i = 0; i < 4; i++) {
        ls7366r_t *e = &f->enc[i];
        if (e->pin_bit > 7)
            continue;
        int was = (f->cs_low >> e->pin_bit) & 1, is = (low >> e->pin_bit) & 1;
        if (is && !was) {
            e->state = 1;
            e->index = 0;
        }
        if (!is)
            e->state = 0;
    }
    f->cs_low = low;
}

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
    uint8_t reply = 0xFF;                /* nobody drives MISO: the pull-up reads 1s */
    int selected = 0;
    for (int i = 0; i < 4; i++)
        if (f->enc[i].pin_bit <= 7 && (f->cs_low >> f->enc[i].pin_bit) & 1) {
            uint8_t r = chip_byte(f, i, (uint8_t)v);
            reply = selected ? (uint8_t)(reply & r) : r;
            selected++;
        }
    if (selected > 1)
        f->contention++;
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
    avr_irq_register_notify(avr_io_getirq(f->avr, AVR_IOCTL_IOPORT_GETIRQ('H'), 3), pin6_edge, f);
    f->line.level = 1;
    for (int i = 0; i < 4; i++)
        f->enc[i].pin_bit = 0xFF;
    avr_irq_register_notify(avr_io_getirq(f->avr, AVR_IOCTL_SPI_GETIRQ(0), SPI_IRQ_OUTPUT), spi_out, f);
    {
        avr_io_addr_t spdr = 0x4E;  /* ATmega2560 SPDR (data address) */
        avr_spi_t *spi = f->avr->io[AVR_DATA_TO_IO(spdr)].w.param;
        if (spi && spi->r_spdr == spdr)
            f->avr->io[AVR_DATA_TO_IO(spdr)].w.c = spdr_write;
    }
    avr_irq_register_notify(avr_io_getirq(f->avr, AVR_IOCTL_IOPORT_GETIRQ('L'), IOPORT_IRQ_PIN_ALL), port_l, f);
    f->cs_low = 0;
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

/* The S1 line as the robot wires it: mode 1 = pin (port letter, bit) sampled at `baud`,
   mode 2 = USART1 (TX1); autobaud: the rate comes from the first 0xAA. */
void fil_s1_config(fil_t *f, int mode, char port, int bit, double baud, int autobaud) {
    line_t *l = &f->line;
    l->mode = mode;
    l->port = port;
    l->bit = bit;
    l->autobaud = autobaud;
    l->bit_cycles = autobaud ? 0 : F_CPU / baud;
    l->ab_n = 0;
    if (mode == 1 && !l->watching++)
        avr_irq_register_notify(avr_io_getirq(f->avr, AVR_IOCTL_IOPORT_GETIRQ(port), bit), line_pin, f);
}

/* Bytes the drivers received on S1, with the cycle each was complete. */
int fil_s1_bytes(fil_t *f, uint8_t *bytes, uint64_t *cycles, int max) {
    line_t *l = &f->line;
    int n = 0;
    while (n < max && l->tail != l->head) {
        bytes[n] = l->bytes[l->tail % LINE_BYTES];
        cycles[n] = l->cycles[l->tail % LINE_BYTES];
        l->tail++;
        n++;
    }
    return n;
}

/* The rate the drivers listen at now (0: an autobauding driver still waits for 0xAA). */
double fil_s1_baud(fil_t *f) { return f->line.bit_cycles > 0 ? F_CPU / f->line.bit_cycles : 0; }

/* Counters for diagnosis: [0] S1 framing errors, [1] S1 bytes at a wrong USART rate, [2] level
   changes on pin 6 (PH3), [3] bytes the firmware wrote to USART1, [4] SPI bytes with several
   chips selected, [5] S1 bytes lost (caller too slow), [6] USART1's programmed rate (baud). */
void fil_counters(fil_t *f, double *out) {
    out[0] = f->line.framing_errors;
    out[1] = f->line.wrong_rate_bytes;
    out[2] = f->pin6_edges;
    out[3] = f->usart1_bytes;
    out[4] = f->contention;
    out[5] = f->line.lost;
    out[6] = usart1_baud(f);
}

/* LS7366R chip i sits on Arduino pin pins[i] (42..49, port L); another value: no chip. */
void fil_encoder_pins(fil_t *f, const int *pins) {
    for (int i = 0; i < 4; i++)
        f->enc[i].pin_bit = (uint8_t)(pins[i] >= 42 && pins[i] <= 49 ? 49 - pins[i] : 0xFF);
}

/* The four chips' plant counts (raw counter sense) and rates (counts/s) as of now. */
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

/* An output pin (port letter, bit): 1 if driven high. */
int fil_pin_high(fil_t *f, char port, int bit) {
    avr_ioport_state_t st;
    if (avr_ioctl(f->avr, AVR_IOCTL_IOPORT_GETSTATE(port), &st) != 0)
        return 0;
    return (st.port >> bit) & (st.ddr >> bit) & 1;
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
