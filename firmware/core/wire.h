/* Little-endian field access, byte by byte: the protocol's fields are unaligned (docs/protocol.md §3). */
#ifndef WIRE_H
#define WIRE_H
#include <stdint.h>

static inline void wire_put_u8(uint8_t *p, uint8_t v) { p[0] = v; }
static inline void wire_put_i8(uint8_t *p, int8_t v) { p[0] = (uint8_t)v; }
static inline void wire_put_u16(uint8_t *p, uint16_t v) { p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); }
static inline void wire_put_i16(uint8_t *p, int16_t v) { wire_put_u16(p, (uint16_t)v); }
static inline void wire_put_u32(uint8_t *p, uint32_t v) {
    p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); p[2] = (uint8_t)(v >> 16); p[3] = (uint8_t)(v >> 24);
}
static inline void wire_put_i32(uint8_t *p, int32_t v) { wire_put_u32(p, (uint32_t)v); }

static inline uint8_t wire_get_u8(const uint8_t *p) { return p[0]; }
static inline int8_t wire_get_i8(const uint8_t *p) { return (int8_t)p[0]; }
static inline uint16_t wire_get_u16(const uint8_t *p) { return (uint16_t)(p[0] | ((uint16_t)p[1] << 8)); }
static inline int16_t wire_get_i16(const uint8_t *p) { return (int16_t)wire_get_u16(p); }
static inline uint32_t wire_get_u32(const uint8_t *p) {
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}
static inline int32_t wire_get_i32(const uint8_t *p) { return (int32_t)wire_get_u32(p); }

#endif
