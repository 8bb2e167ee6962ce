/* The protocol core on the host, with a scripted hardware layer, for tests/firmware.

   Reads commands on stdin, one per line, answers on stdout, each answer ending with ".":
     crc HEX                      -> crc VALUE               CRC of the bytes
     frame ID SEQ HEX             -> wire HEX                one frame as the board sends it
     pack ID V1 V2 ...            -> payload HEX             typed packer of message ID
     unpack ID HEX                -> values V1 V2 ...        typed unpacker
     boot BOOT_ID T | rx T HEX | poll T | enc A B C D | fault BITS
                                  -> what the core did: "tx HEX" per frame sent,
                                     "duty T A B C D", "enable X", "resetenc"
   Times T in µs of board time. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "board_core.h"
#include "hal.h"

static core_t core;
static uint32_t now_us;
static int32_t enc[4];
static uint8_t fault_bits;
static int sample_armed;
static uint32_t sample_at;

uint8_t hal_host_send(const uint8_t *b, uint8_t n) {
    printf("tx ");
    for (uint8_t i = 0; i < n; i++) printf("%02x", b[i]);
    printf("\n");
    return 1;
}
void hal_set_duties(const int16_t d[4]) { printf("duty %u %d %d %d %d\n", now_us, d[0], d[1], d[2], d[3]); }
void hal_set_drivers_enabled(uint8_t on) { printf("enable %u\n", on); }
void hal_reset_encoders(void) { memset(enc, 0, sizeof enc); printf("resetenc\n"); }
void hal_schedule_sample(uint32_t at) { sample_armed = 1; sample_at = at; }
void hal_cancel_sample(void) { sample_armed = 0; }
uint8_t hal_take_sample(hal_sample_t *s) {
    if (!sample_armed || (int32_t)(now_us - sample_at) < 0) return 0;
    memset(s, 0, sizeof *s);
    s->time_us = sample_at;
    memcpy(s->encoder, enc, sizeof enc);
    s->battery_mv = 24700;
    sample_armed = 0;
    return 1;
}
uint8_t hal_fault_inputs(void) { return fault_bits; }

static size_t unhex(const char *h, uint8_t *out, size_t cap) {
    size_t n = 0;
    while (h[0] && h[1] && n < cap) {
        unsigned v;
        if (sscanf(h, "%2x", &v) != 1) break;
        out[n++] = (uint8_t)v;
        h += 2;
    }
    return n;
}

int main(void) {
    static const core_identity_t id = {{0, 1, 0}, 0x2019, 980, 500, 0};
    char line[4096], arg[4096];
    uint8_t buf[2048];
    crc_init();
    while (fgets(line, sizeof line, stdin)) {
        unsigned long a = 0, b = 0;
        arg[0] = 0;
        if (sscanf(line, "crc %4095s", arg) == 1) {
            size_t n = unhex(arg, buf, sizeof buf);
            printf("crc %lx\n", (unsigned long)crc_compute(buf, (uint8_t)n));
        } else if (sscanf(line, "frame %lu %lu %4095s", &a, &b, arg) >= 2) {
            size_t n = unhex(arg, buf, sizeof buf);
            core.tx_seq = (uint16_t)b;
            printf("wire-");
            core_send(&core, (uint8_t)a, buf, (uint8_t)n);
        } else if (sscanf(line, "pack %lu", &a) == 1) {
            long long v[64];
            int k = 0;
            char *p = line + 5;
            strtoul(p, &p, 10);
            while (k < 64) {
                char *e;
                long long x = strtoll(p, &e, 10);
                if (e == p) break;
                v[k++] = x;
                p = e;
            }
            int n = proto_test_pack((uint8_t)a, v, buf);
            printf("payload ");
            for (int i = 0; i < n; i++) printf("%02x", buf[i]);
            printf("\n");
        } else if (sscanf(line, "unpack %lu %4095s", &a, arg) >= 1) {
            long long v[64];
            unhex(arg, buf, sizeof buf);
            int n = proto_test_unpack((uint8_t)a, buf, v);
            printf("values");
            for (int i = 0; i < n; i++) printf(" %lld", v[i]);
            printf("\n");
        } else if (sscanf(line, "boot %lu %lu", &a, &b) == 2) {
            now_us = (uint32_t)b;
            core_boot(&core, &id, (uint32_t)a, now_us);
        } else if (sscanf(line, "rx %lu %4095s", &a, arg) == 2) {
            now_us = (uint32_t)a;
            size_t n = unhex(arg, buf, sizeof buf);
            for (size_t i = 0; i < n; i += 200)
                core_rx(&core, buf + i, (uint8_t)(n - i < 200 ? n - i : 200), now_us);
        } else if (sscanf(line, "poll %lu", &a) == 1) {
            now_us = (uint32_t)a;
            core_poll(&core, now_us);
        } else if (sscanf(line, "enc %d %d %d %d", &enc[0], &enc[1], &enc[2], &enc[3]) == 4) {
        } else if (sscanf(line, "fault %lu", &a) == 1) {
            fault_bits = (uint8_t)a;
        } else {
            printf("error unknown command: %s", line);
        }
        printf(".\n");
        fflush(stdout);
    }
    return 0;
}
