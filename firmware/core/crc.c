/* Bit-serial CRC over the catalogue parameters (Rocksoft model). No table: 64 bytes of frame
   at most, a few thousand cycles, and no flash spent per polynomial. */
#include "crc.h"

#define CRC_TOP ((crc_t)((crc_t)1 << (CRC_WIDTH - 1)))
#define CRC_MASK ((crc_t)(CRC_WIDTH == 32 ? 0xFFFFFFFFUL : ((1UL << (CRC_WIDTH % 32)) - 1UL)))

/* The reflected polynomial, for the LSB-first register used when input is reflected. */
__attribute__((unused)) static crc_t reflect(crc_t v, uint8_t bits) {
    crc_t r = 0;
    for (uint8_t i = 0; i < bits; i++) {
        r = (crc_t)((r << 1) | (v & 1));
        v >>= 1;
    }
    return r;
}

crc_t crc_compute(const uint8_t *data, uint8_t n) {
#if CRC_REFIN
    /* LSB-first register: equivalent to reflecting each byte and the register. */
    crc_t crc = reflect((crc_t)CRC_INIT, CRC_WIDTH);
    const crc_t poly = reflect((crc_t)CRC_POLY, CRC_WIDTH);
    while (n--) {
        crc ^= *data++;
        for (uint8_t b = 0; b < 8; b++)
            crc = (crc & 1) ? (crc_t)((crc >> 1) ^ poly) : (crc_t)(crc >> 1);
    }
#if !CRC_REFOUT
    crc = reflect(crc, CRC_WIDTH);
#endif
#else
    crc_t crc = (crc_t)CRC_INIT;
    while (n--) {
        crc ^= (crc_t)((crc_t)*data++ << (CRC_WIDTH - 8));
        for (uint8_t b = 0; b < 8; b++)
            crc = (crc & CRC_TOP) ? (crc_t)((crc << 1) ^ (crc_t)CRC_POLY) : (crc_t)(crc << 1);
    }
#if CRC_REFOUT
    crc = reflect(crc, CRC_WIDTH);
#endif
#endif
    return (crc_t)((crc ^ (crc_t)CRC_XOROUT) & CRC_MASK);
}
