/* The protocol core (docs/protocol.md §4): hardware-free, see board_core.h. */
#include <string.h>
#include "board_core.h"
#include "cobs.h"
#include "hal.h"

_Static_assert(MSG_SET_DUTIES_DUTY_PER_UNIT == MSG_TELEMETRY_DUTY_PER_UNIT,
               "SET_DUTIES and TELEMETRY duties must share one scale");
_Static_assert(PROTO_HEADER_SIZE + PROTO_CRC_BYTES + MSG_TELEMETRY_SIZE <= PROTO_MAX_FRAME,
               "TELEMETRY does not fit the largest frame");

/* A milli-unit value (mA, mV) as the raw integer of a field of `scale` (constant-folded). */
#define MILLI_TO_RAW(x, scale) \
    ((scale) == 0.001 ? (int32_t)(x) : (int32_t)((float)(x) * (float)(0.001 / (scale)) + ((x) >= 0 ? 0.5f : -0.5f)))

static int16_t clip_i16(int32_t v) { return v > 32767 ? 32767 : v < -32768 ? -32768 : (int16_t)v; }
static uint16_t clip_u16(int32_t v) { return v > 65535 ? 65535 : v < 0 ? 0 : (uint16_t)v; }

uint8_t core_running(const core_t *c) {
    return (c->duty[0] | c->duty[1] | c->duty[2] | c->duty[3]) != 0;
}

void core_send(core_t *c, uint8_t msg_id, const uint8_t *payload, uint8_t n) {
    uint8_t body[PROTO_MAX_FRAME];
    uint8_t wire[CORE_RX_CHUNK + 1];
    body[0] = msg_id;
    wire_put_u16(body + 1, c->tx_seq);
    c->tx_seq++;  /* every frame the board sends, whether or not it fits the link */
    memcpy(body + PROTO_HEADER_SIZE, payload, n);
    uint8_t len = (uint8_t)(PROTO_HEADER_SIZE + n);
    crc_t crc = crc_compute(body, len);
    for (uint8_t i = 0; i < PROTO_CRC_BYTES; i++) {
        uint8_t shift = PROTO_CRC_LITTLE_ENDIAN ? 8 * i : 8 * (PROTO_CRC_BYTES - 1 - i);
        body[len + i] = (uint8_t)(crc >> shift);
    }
    len += PROTO_CRC_BYTES;
    uint8_t m = cobs_encode(body, len, wire);
    wire[m++] = 0x00;
    if (!hal_host_send(wire, m))
        c->frames_lost_tx++;
}

/* The board time a frame sent now carries: `now`, but never earlier than a frame already
   sent (a sample latched after the caller read the clock may have gone out first). */
static uint32_t stamp(core_t *c, uint32_t now) {
    if ((int32_t)(now - c->last_stamp_us) < 0)
        now = c->last_stamp_us;
    c->last_stamp_us = now;
    return now;
}

static void send_ack(core_t *c, uint8_t cmd_id, uint16_t cmd_seq, uint8_t status, uint32_t now) {
    msg_ack_t a = {.cmd_id = cmd_id, .cmd_seq = cmd_seq, .status = status, .time = now};
    uint8_t p[MSG_ACK_SIZE];
    msg_ack_pack(p, &a);
    core_send(c, MSG_ACK, p, sizeof p);
}

static void send_event(core_t *c, uint8_t code, uint32_t arg, uint32_t now) {
    msg_event_t e = {.code = code, .arg = arg, .time = now};
    uint8_t p[MSG_EVENT_SIZE];
    msg_event_pack(p, &e);
    core_send(c, MSG_EVENT, p, sizeof p);
}

static void send_hello(core_t *c) {
    msg_hello_t h;
    memset(&h, 0, sizeof h);
    h.protocol_version = PROTO_VERSION;
    memcpy(h.firmware_version, c->id.firmware_version, 3);
    h.board_id = c->id.board_id;
    h.boot_id = c->boot_id;
    h.counts_per_rev = c->id.counts_per_rev;
    h.max_telemetry_rate = c->id.max_telemetry_hz;
    h.capabilities = c->id.capabilities;
    uint8_t p[MSG_HELLO_SIZE];
    msg_hello_pack(p, &h);
    core_send(c, MSG_HELLO, p, sizeof p);
}

/* Duties to the drivers; the enable line follows the latched faults. */
static void apply(core_t *c) {
    hal_set_drivers_enabled(c->faults == 0);
    hal_set_duties(c->duty);
}

static void stop(core_t *c) {
    memset(c->duty, 0, sizeof c->duty);
    apply(c);
}

static void latch(core_t *c, uint8_t bits) {
    c->faults |= bits;
    stop(c);
}

void core_boot(core_t *c, const core_identity_t *id, uint32_t boot_id, uint32_t now_us) {
    crc_init();
    memset(c, 0, sizeof *c);
    c->id = *id;
    c->boot_id = boot_id ? boot_id : 1;
    c->watchdog_us = (uint32_t)PROTO_DEFAULT_WATCHDOG_MS * 1000UL;
    c->last_rx_us = now_us;
    c->last_stamp_us = now_us;
    stop(c);
    hal_reset_encoders();
    hal_cancel_sample();
    send_hello(c);
    send_event(c, EVENT_BOOT, c->boot_id, stamp(c, now_us));
}

static void send_telemetry(core_t *c, const hal_sample_t *s) {
    msg_telemetry_t t;
    memset(&t, 0, sizeof t);
    t.time = s->time_us;
    if ((int32_t)(s->time_us - c->last_stamp_us) > 0)
        c->last_stamp_us = s->time_us;
    for (uint8_t i = 0; i < 4; i++) {
        t.encoder[i] = s->encoder[i];
        t.motor_current[i] = clip_i16(MILLI_TO_RAW(s->motor_current_ma[i], MSG_TELEMETRY_MOTOR_CURRENT_SCALE));
        t.duty[i] = c->duty[i];
    }
    t.battery_voltage = clip_u16(MILLI_TO_RAW(s->battery_mv, MSG_TELEMETRY_BATTERY_VOLTAGE_SCALE));
    t.battery_current = clip_i16(MILLI_TO_RAW(s->battery_current_ma, MSG_TELEMETRY_BATTERY_CURRENT_SCALE));
    t.faults = c->faults;
    uint8_t p[MSG_TELEMETRY_SIZE];
    msg_telemetry_pack(p, &t);
    core_send(c, MSG_TELEMETRY, p, sizeof p);
}

/* Send a latched sample before anything stamped later (an ACK, an EVENT): board time in
   the frames the host receives never runs backwards (docs/protocol.md, Telemetry). */
static void flush_sample(core_t *c) {
    hal_sample_t s;
    if (c->telemetry_period_us && hal_take_sample(&s)) {
        send_telemetry(c, &s);
        c->next_telemetry_us += c->telemetry_period_us;
        hal_schedule_sample(c->next_telemetry_us);
    }
}

/* One command; returns its ACK status. */
static uint8_t dispatch(core_t *c, uint8_t id, const uint8_t *p, uint32_t now) {
    switch (id) {
    case MSG_HELLO_REQ:
        send_hello(c);
        return STATUS_OK;
    case MSG_PING:
        return STATUS_OK;
    case MSG_SET_DUTIES: {
        msg_set_duties_t m;
        msg_set_duties_unpack(p, &m);
        for (uint8_t i = 0; i < 4; i++)
            if (m.duty[i] < MSG_SET_DUTIES_DUTY_MIN || m.duty[i] > MSG_SET_DUTIES_DUTY_MAX)
                return STATUS_BAD_VALUE;
        if (c->faults) {
            stop(c);
            return STATUS_FAULT_ACTIVE;
        }
        memcpy(c->duty, m.duty, sizeof c->duty);
        apply(c);
        return STATUS_OK;
    }
    case MSG_STOP:
        stop(c);
        return STATUS_OK;
    case MSG_CONFIGURE: {
        msg_configure_t m;
        msg_configure_unpack(p, &m);
        if (m.watchdog < MSG_CONFIGURE_WATCHDOG_MIN || m.watchdog > MSG_CONFIGURE_WATCHDOG_MAX
            || m.telemetry_rate > c->id.max_telemetry_hz)
            return STATUS_BAD_VALUE;
        c->watchdog_us = (uint32_t)m.watchdog * 1000UL;
        if (m.telemetry_rate) {
            c->telemetry_period_us = (1000000UL + m.telemetry_rate / 2) / m.telemetry_rate;
            c->next_telemetry_us = now + c->telemetry_period_us;
            hal_schedule_sample(c->next_telemetry_us);
        } else {
            c->telemetry_period_us = 0;
            hal_cancel_sample();
        }
        return STATUS_OK;
    }
    case MSG_RESET_ENCODERS:
        hal_reset_encoders();
        return STATUS_OK;
    case MSG_CLEAR_FAULTS:
        c->faults = 0;
        apply(c);
        return STATUS_OK;
    default:
        return STATUS_UNSUPPORTED;
    }
}

/* A complete COBS chunk (no delimiter): decode, check, dispatch, ACK. */
static void handle_chunk(core_t *c, uint32_t now) {
    uint8_t body[CORE_RX_CHUNK];
    uint8_t n = cobs_decode(c->rx, c->rx_n, body);
    if (n < PROTO_HEADER_SIZE + PROTO_CRC_BYTES || n > PROTO_MAX_FRAME) {
        c->frames_bad++;
        return;
    }
    n -= PROTO_CRC_BYTES;
    crc_t got = 0;
    for (uint8_t i = 0; i < PROTO_CRC_BYTES; i++) {
        uint8_t shift = PROTO_CRC_LITTLE_ENDIAN ? 8 * i : 8 * (PROTO_CRC_BYTES - 1 - i);
        got |= (crc_t)((crc_t)body[n + i] << shift);
    }
    if (got != crc_compute(body, n)) {
        c->frames_bad++;
        return;  /* a bad CRC is not acknowledged: its seq cannot be trusted */
    }
    c->frames_ok++;
    flush_sample(c);
    now = stamp(c, now);
    c->last_rx_us = now;  /* every valid host frame restarts the watchdog */
    uint8_t id = body[0];
    uint16_t seq = wire_get_u16(body + 1);
    uint8_t status;
    int16_t size = proto_payload_size(id);
    if (size < 0 || proto_direction(id) != PROTO_DIR_HOST_TO_BOARD || proto_sim_only(id))
        status = STATUS_UNSUPPORTED;
    else if (n - PROTO_HEADER_SIZE != size)
        status = STATUS_BAD_LENGTH;
    else
        status = dispatch(c, id, body + PROTO_HEADER_SIZE, now);
    send_ack(c, id, seq, status, now);
}

void core_rx(core_t *c, const uint8_t *bytes, uint8_t n, uint32_t now_us) {
    for (uint8_t i = 0; i < n; i++) {
        uint8_t b = bytes[i];
        if (b != 0) {
            if (c->rx_n < sizeof c->rx)
                c->rx[c->rx_n++] = b;
            else
                c->rx_overflow = 1;
            continue;
        }
        if (c->rx_n && !c->rx_overflow)
            handle_chunk(c, now_us);
        else if (c->rx_n)
            c->frames_bad++;
        c->rx_n = 0;
        c->rx_overflow = 0;
    }
}

void core_poll(core_t *c, uint32_t now_us) {
    /* an idle board's last stamp follows the clock: half a wrap (35.8 min) behind, `stamp`
       would take every later time for an earlier one and the watchdog would never see silence */
    if ((int32_t)(now_us - c->last_stamp_us) > 0)
        c->last_stamp_us = now_us;
    /* motors first, words after: a fault or the watchdog stops them before anything is sent */
    uint8_t fresh = hal_fault_inputs() & (uint8_t)~c->faults;
    if (fresh)
        latch(c, fresh);
    uint32_t silence_ms = 0;
    uint8_t silent = core_running(c) && (int32_t)(now_us - c->last_rx_us) >= (int32_t)c->watchdog_us;
    if (silent) {
        silence_ms = (now_us - c->last_rx_us) / 1000UL;
        latch(c, FAULTS_WATCHDOG);
    }
    flush_sample(c);  /* a sample latched before now goes out before the events stamped now */
    if (fresh)
        send_event(c, EVENT_FAULT, fresh, stamp(c, now_us));
    if (silent)
        send_event(c, EVENT_WATCHDOG, silence_ms, stamp(c, now_us));
    flush_sample(c);  /* a sample latched while the events went out */
}
