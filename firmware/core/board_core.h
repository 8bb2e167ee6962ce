/* The protocol core of the Omnibot board (docs/protocol.md): framing, seq, handshake,
   commands and their ACK statuses, telemetry schedule, watchdog, latched faults.
   Hardware-free: it talks to the board through hal.h only. No dynamic memory. */
#ifndef BOARD_CORE_H
#define BOARD_CORE_H
#include <stdint.h>
#include "protocol_gen.h"
#include "crc.h"

/* Largest COBS chunk of a valid frame: decoded bytes plus one overhead byte per 254. */
#define CORE_RX_CHUNK (PROTO_MAX_FRAME + PROTO_MAX_FRAME / 254 + 1)

typedef struct {
    uint8_t firmware_version[3];
    uint32_t board_id;
    uint16_t counts_per_rev;
    uint16_t max_telemetry_hz;
    uint8_t capabilities;         /* CAPABILITIES_* of what is fitted */
} core_identity_t;

typedef struct {
    core_identity_t id;
    uint32_t boot_id;
    uint16_t tx_seq;
    int16_t duty[4];
    uint8_t faults;
    uint32_t watchdog_us;
    uint32_t last_rx_us;
    uint32_t telemetry_period_us; /* 0 = telemetry off */
    uint32_t next_telemetry_us;
    uint32_t last_stamp_us;       /* time of the last frame sent: no frame goes out stamped earlier */
    uint8_t rx[CORE_RX_CHUNK];
    uint8_t rx_n;
    uint8_t rx_overflow;
    /* counters for diagnostics */
    uint16_t frames_ok, frames_bad, frames_lost_tx;
} core_t;

/* Power-on state, then HELLO and EVENT BOOT (docs/protocol.md, Boot and handshake). */
void core_boot(core_t *c, const core_identity_t *id, uint32_t boot_id, uint32_t now_us);
/* Bytes from the host link, received at now_us. */
void core_rx(core_t *c, const uint8_t *bytes, uint8_t n, uint32_t now_us);
/* Everything the board does on its own: fault inputs, watchdog, telemetry. Call often. */
void core_poll(core_t *c, uint32_t now_us);
/* Encode and send one frame (used by the core; exposed for the host test). */
void core_send(core_t *c, uint8_t msg_id, const uint8_t *payload, uint8_t n);
/* 1 if any duty is non-zero. */
uint8_t core_running(const core_t *c);

#endif
