/* libFuzzer harness of the protocol core (docs/firmware.md, "Fuzzing the protocol core").

   An input is a 4-byte seed (little-endian) and then the bytes the host link delivers. The
   seed drives a small generator that cuts the stream into the pieces core_rx receives (as
   the UART RX ring hands them over), advances board time between pieces (core_poll runs:
   watchdog, telemetry) and now and then raises a fault input. The harness decodes every
   frame itself (COBS, CRC-32/ISO-HDLC computed bit by bit, the layouts of
   protocols/omnibot-board-v2.toml) and aborts, naming the broken rule, when:
   - a duty reaches the drivers that no valid SET_DUTIES asked for (only a valid SET_DUTIES
     sets duties, only a valid STOP, a fault input or the watchdog zero them);
   - the board acknowledges a frame that is not valid, or does not acknowledge a valid one,
     or acknowledges another id or seq;
   - a frame the board sends does not decode or carries a wrong CRC;
   - the motors still run a watchdog timeout after the last valid frame.
   Sanitizer findings (AddressSanitizer, UndefinedBehaviorSanitizer) abort too. */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "board_core.h"
#include "hal.h"

_Static_assert(PROTO_CRC_WIDTH == 32 && PROTO_CRC_LITTLE_ENDIAN, "the reference decoder knows CRC-32 little-endian");
_Static_assert(MSG_SET_DUTIES_SIZE == 8 && MSG_CONFIGURE_SIZE == 4, "the reference decoder knows these layouts");

#define FAIL(...) do { fprintf(stderr, "fuzz_core: invariant broken: " __VA_ARGS__); fputc('\n', stderr); abort(); } while (0)

/* ---------------------------------------------------------------- reference decoder */

static uint32_t ref_crc32(const uint8_t *p, size_t n) {
    uint32_t c = 0xFFFFFFFFu;
    for (size_t i = 0; i < n; i++) {
        c ^= p[i];
        for (int k = 0; k < 8; k++)
            c = (c >> 1) ^ (0xEDB88320u & (uint32_t)-(int32_t)(c & 1));
    }
    return c ^ 0xFFFFFFFFu;
}

/* COBS decode of one chunk (no delimiter); -1 if malformed. */
static int ref_cobs(const uint8_t *in, size_t n, uint8_t *out, size_t cap) {
    size_t i = 0, o = 0;
    while (i < n) {
        uint8_t code = in[i++];
        if (code == 0 || i + code - 1 > n)
            return -1;
        for (uint8_t k = 1; k < code; k++) {
            if (o >= cap) return -1;
            out[o++] = in[i++];
        }
        if (code != 0xFF && i < n) {
            if (o >= cap) return -1;
            out[o++] = 0;
        }
    }
    return (int)o;
}

typedef struct {
    int valid;          /* decodes, length within the frame limits, CRC right */
    uint8_t id;
    uint16_t seq;
    int payload_n;
    uint8_t payload[PROTO_MAX_FRAME];
} frame_t;

static frame_t ref_frame(const uint8_t *chunk, size_t n) {
    frame_t f;
    uint8_t body[1024];
    memset(&f, 0, sizeof f);
    int m = ref_cobs(chunk, n, body, sizeof body);
    if (m < 3 + 4 || m > PROTO_MAX_FRAME)
        return f;
    uint32_t crc = (uint32_t)body[m - 4] | (uint32_t)body[m - 3] << 8 | (uint32_t)body[m - 2] << 16
                   | (uint32_t)body[m - 1] << 24;
    if (crc != ref_crc32(body, (size_t)m - 4))
        return f;
    f.valid = 1;
    f.id = body[0];
    f.seq = (uint16_t)(body[1] | body[2] << 8);
    f.payload_n = m - 4 - 3;
    memcpy(f.payload, body + 3, (size_t)f.payload_n);
    return f;
}

static int16_t le16(const uint8_t *p) { return (int16_t)(uint16_t)(p[0] | p[1] << 8); }

/* ---------------------------------------------------------------- the board as the harness sees it */

static core_t core;
static uint32_t now_us;
static uint8_t fault_inputs;
static int sample_armed;
static uint32_t sample_at;

static int16_t out_duty[4];       /* what the drivers were last told */
static enum { IN_BOOT, IN_RX, IN_POLL } phase;
static const frame_t *current;    /* the frame whose delimiter core_rx is handling, or NULL */
static int acks, acks_expected;
static int ref_faulted;           /* faults latched, as the protocol says */
static uint32_t ref_watchdog_us, ref_last_valid_us;

#ifdef FUZZ_TRACE
#define TRACE(...) fprintf(stderr, __VA_ARGS__)
#else
#define TRACE(...) do { } while (0)
#endif

static int running(void) { return (out_duty[0] | out_duty[1] | out_duty[2] | out_duty[3]) != 0; }

void hal_set_duties(const int16_t d[4]) {
    int zero = (d[0] | d[1] | d[2] | d[3]) == 0;
    if (memcmp(d, out_duty, sizeof out_duty) == 0)
        return;
    if (phase == IN_BOOT) {
        if (!zero) FAIL("boot set non-zero duties");
    } else if (phase == IN_RX) {
        const frame_t *f = current;
        if (!f || !f->valid)
            FAIL("duties %d %d %d %d applied without a valid frame", d[0], d[1], d[2], d[3]);
        if (f->id == MSG_STOP && f->payload_n == 0) {
            if (!zero) FAIL("STOP applied non-zero duties");
        } else if (f->id == MSG_SET_DUTIES && f->payload_n == 8) {
            for (int i = 0; i < 4; i++) {
                int16_t want = le16(f->payload + 2 * i);
                if (want < MSG_SET_DUTIES_DUTY_MIN)
                    FAIL("SET_DUTIES with duty %d (out of range) moved the wheels", want);
                if (d[i] != want)
                    FAIL("wheel %d got %d, SET_DUTIES said %d", i, d[i], want);
            }
            if (ref_faulted)
                FAIL("SET_DUTIES moved the wheels with a fault latched");
        } else {
            FAIL("duties %d %d %d %d applied on message 0x%02x (length %d), not SET_DUTIES",
                 d[0], d[1], d[2], d[3], f->id, f->payload_n);
        }
    } else {
        if (!zero) FAIL("core_poll applied non-zero duties");
        int expired = (int32_t)(now_us - ref_last_valid_us) >= (int32_t)ref_watchdog_us;
        if (!fault_inputs && !expired)
            FAIL("duties zeroed without a fault input or watchdog timeout (%u us of silence, timeout %u us)",
                 now_us - ref_last_valid_us, ref_watchdog_us);
    }
    TRACE("t=%u duties %d %d %d %d (phase %d)\n", now_us, d[0], d[1], d[2], d[3], (int)phase);
    memcpy(out_duty, d, sizeof out_duty);
}

uint8_t hal_host_send(const uint8_t *b, uint8_t n) {
    if (n < 2 || b[n - 1] != 0)
        FAIL("board frame without its delimiter");
    for (uint8_t i = 0; i + 1 < n; i++)
        if (b[i] == 0) FAIL("board frame with a 0x00 inside");
    frame_t f = ref_frame(b, (size_t)n - 1);
    if (!f.valid)
        FAIL("board sent a frame that does not decode or has a wrong CRC");
    if (f.id == MSG_ACK) {
        acks++;
        if (phase != IN_RX || !current || !current->valid)
            FAIL("ACK without a valid host frame");
        if (f.payload[0] != current->id || (uint16_t)(f.payload[1] | f.payload[2] << 8) != current->seq)
            FAIL("ACK of id 0x%02x seq %u for a frame of id 0x%02x seq %u", f.payload[0],
                 f.payload[1] | f.payload[2] << 8, current->id, current->seq);
    }
    return 1;
}
void hal_set_drivers_enabled(uint8_t on) { (void)on; }
void hal_reset_encoders(void) {}
void hal_schedule_sample(uint32_t at) { sample_armed = 1; sample_at = at; }
void hal_cancel_sample(void) { sample_armed = 0; }
uint8_t hal_take_sample(hal_sample_t *s) {
    if (!sample_armed || (int32_t)(now_us - sample_at) < 0) return 0;
    memset(s, 0, sizeof *s);
    s->time_us = sample_at;
    s->battery_mv = 24700;
    sample_armed = 0;
    return 1;
}
uint8_t hal_fault_inputs(void) { return fault_inputs; }

#ifdef FUZZ_INJECT_BUG
/* A deliberate bug, to prove the harness catches one (make fuzz FUZZ_INJECT_BUG=1, which links
   with --wrap=crc_compute): the core's check of an incoming SET_DUTIES expects the CRC with its
   top byte flipped, so it takes frames with that wrong CRC and refuses the right ones. */
crc_t __real_crc_compute(const uint8_t *data, uint8_t n);
crc_t __wrap_crc_compute(const uint8_t *data, uint8_t n);
crc_t __wrap_crc_compute(const uint8_t *data, uint8_t n) {
    crc_t c = __real_crc_compute(data, n);
    return phase == IN_RX && n >= 1 && data[0] == MSG_SET_DUTIES ? c ^ 0xFF000000u : c;
}
#endif

/* ---------------------------------------------------------------- driving the core */

static uint32_t rng;
static uint32_t next(void) { rng ^= rng << 13; rng ^= rng >> 17; rng ^= rng << 5; return rng; }

static void poll_at(uint32_t t) {
    int was_running = running();
    now_us = t;
    phase = IN_POLL;
    core_poll(&core, now_us);
    TRACE("t=%u poll inputs %u core faults %u last_rx %u wd %u ref %u\n", now_us, fault_inputs, core.faults, core.last_rx_us, core.watchdog_us, ref_last_valid_us);
    if (fault_inputs || (was_running && (int32_t)(now_us - ref_last_valid_us) >= (int32_t)ref_watchdog_us))
        ref_faulted = 1;
    if (ref_faulted && running())
        FAIL("wheels still driven with a fault latched");
}

/* The protocol's effect of one valid host frame on the state the harness tracks. */
static void ref_apply(const frame_t *f) {
    ref_last_valid_us = now_us;
    if (f->id == MSG_CONFIGURE && f->payload_n == 4) {
        uint16_t wd = (uint16_t)le16(f->payload), rate = (uint16_t)le16(f->payload + 2);
        if (wd >= MSG_CONFIGURE_WATCHDOG_MIN && wd <= MSG_CONFIGURE_WATCHDOG_MAX && rate <= 500)
            ref_watchdog_us = wd * 1000u;
    } else if (f->id == MSG_CLEAR_FAULTS && f->payload_n == 0) {
        ref_faulted = 0;
    }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
    static const core_identity_t id = {{1, 0, 0}, 0x2019, 980, 500, 0};
    static uint8_t chunk[4096];
    size_t chunk_n = 0;
    if (size < 4)
        return 0;
    rng = (uint32_t)data[0] | (uint32_t)data[1] << 8 | (uint32_t)data[2] << 16 | (uint32_t)data[3] << 24;
    if (!rng) rng = 0x2019;
    data += 4;
    size -= 4;
    memset(out_duty, 0, sizeof out_duty);
    fault_inputs = 0;
    sample_armed = 0;
    ref_faulted = 0;
    ref_watchdog_us = PROTO_DEFAULT_WATCHDOG_MS * 1000u;
    now_us = next();               /* any boot time: board time wraps */
    ref_last_valid_us = now_us;
    phase = IN_BOOT;
    core_boot(&core, &id, next(), now_us);

    size_t i = 0;
    while (i < size) {
        uint32_t r = next();
        if ((r & 3) == 0) {        /* time passes: up to 2 ms, or now and then up to 12 s */
            uint32_t dt = (r >> 8) & 0x3F ? (r >> 8) % 2000u : (r >> 8) % 12000000u;
            if (((r >> 2) & 0x3F) == 0)
                fault_inputs = ((r >> 16) & 1) ? (uint8_t)(FAULTS_ESTOP | FAULTS_OVERCURRENT) & (uint8_t)(r >> 24) : 0;
            poll_at(now_us + dt);
        }
        /* the next piece: up to 32 bytes, ending at a delimiter if one comes first */
        size_t len = 1 + (next() % 32), k = 0;
        while (k < len && i + k < size && data[i + k] != 0) k++;
        int delimited = i + k < size && data[i + k] == 0 && k < len;
        if (delimited) k++;
        size_t body = delimited ? k - 1 : k;
        if (chunk_n + body <= sizeof chunk) memcpy(chunk + chunk_n, data + i, body);
        chunk_n += body;
        frame_t f;
        memset(&f, 0, sizeof f);
        if (delimited && chunk_n <= sizeof chunk)
            f = ref_frame(chunk, chunk_n);
        current = delimited ? &f : NULL;
        acks = 0;
        acks_expected = f.valid;
        phase = IN_RX;
        core_rx(&core, data + i, (uint8_t)k, now_us);
        TRACE("t=%u rx %zu bytes (delim %d) last_rx %u duty %d ok %u bad %u\n", now_us, k, delimited, core.last_rx_us, core.duty[0], core.frames_ok, core.frames_bad);
        if (acks != acks_expected)
            FAIL("%d ACKs for a %s frame (%zu bytes on the wire)", acks, f.valid ? "valid" : "invalid", chunk_n);
        if (f.valid) {
            TRACE("t=%u frame 0x%02x len %d\n", now_us, f.id, f.payload_n);
            ref_apply(&f);
        }
        if (delimited)
            chunk_n = 0;
        current = NULL;
        i += k;
    }
    /* the host goes silent: the watchdog must stop the wheels */
    uint32_t silent_at = ref_last_valid_us + ref_watchdog_us;
    poll_at((int32_t)(silent_at - now_us) > 0 ? silent_at : now_us);
    if (running())
        FAIL("wheels still driven %u us after the last valid frame (watchdog %u us)",
             now_us - ref_last_valid_us, ref_watchdog_us);
    return 0;
}
