/* Consistent Overhead Byte Stuffing (Cheshire & Baker 1999): no 0x00 in the encoded bytes. */
#ifndef COBS_H
#define COBS_H
#include <stdint.h>

/* Encode n bytes into out (room for n + n/254 + 1); returns the encoded length (no delimiter). */
uint8_t cobs_encode(const uint8_t *in, uint8_t n, uint8_t *out);
/* Decode n bytes (no delimiter) into out (room for n); returns the decoded length, 0 if malformed. */
uint8_t cobs_decode(const uint8_t *in, uint8_t n, uint8_t *out);

#endif
