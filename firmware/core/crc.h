/* The frame check, generic over the catalogue parameters (width 8/16/32, poly, init, refin,
   refout, xorout). Parameters default to the generated PROTO_CRC_* of the protocol
   description; a protocol that changes its CRC is a regeneration, not a code change. */
#ifndef CRC_H
#define CRC_H
#include <stdint.h>
#include "protocol_gen.h"

#ifndef CRC_WIDTH
#define CRC_WIDTH PROTO_CRC_WIDTH
#define CRC_POLY PROTO_CRC_POLY
#define CRC_INIT PROTO_CRC_INIT
#define CRC_REFIN PROTO_CRC_REFIN
#define CRC_REFOUT PROTO_CRC_REFOUT
#define CRC_XOROUT PROTO_CRC_XOROUT
#endif

#if CRC_WIDTH <= 8
typedef uint8_t crc_t;
#elif CRC_WIDTH <= 16
typedef uint16_t crc_t;
#else
typedef uint32_t crc_t;
#endif

/* Build the lookup table (once, before the first crc_compute). */
void crc_init(void);
/* CRC of n bytes (init, update, final in one go). */
crc_t crc_compute(const uint8_t *data, uint8_t n);

#endif
