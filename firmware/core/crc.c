/* CRC over the catalogue parameters (Rocksoft model), table-driven with the table built at boot. */
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

/* One table entry per byte value, in the register's own bit order: built once by crc_init()
   from the parameters above (512 B of RAM for a 16-bit CRC, 1 KiB for 32-bit), so the
   per-byte cost is one lookup instead of eight shifts. */
static crc_t table[256];

void crc_init(void) {
    for (uint16_t b = 0; b < 256; b++) {
#if CRC_REFIN
        const crc_t poly = reflect((crc_t)CRC_POLY, CRC_WIDTH);
        crc_t r = (crc_t)b;
        for (uint8_t k = 0; k < 8; k++)
            r = (r & 1) ? (crc_t)((r >> 1) ^ poly) : (crc_t)(r >> 1);
#else
        crc_t r = (crc_t)((crc_t)b << (CRC_WIDTH - 8));
        for (uint8_t k = 0; k < 8; k++)
            r = (r & CRC_TOP) ? (crc_t)((r << 1) ^ (crc_t)CRC_POLY) : (crc_t)(r << 1);
#endif
        table[b] = (crc_t)(r & CRC_MASK);
    }
}

crc_t crc_compute(const uint8_t *data, uint8_t n) {
#if CRC_REFIN
    /* LSB-first register: equivalent to reflecting each byte and the register. */
    crc_t crc = reflect((crc_t)CRC_INIT, CRC_WIDTH);
    while (n--)
        crc = (crc_t)((CRC_WIDTH > 8 ? crc >> 8 : 0) ^ table[(uint8_t)(crc ^ *data++)]);
#if !CRC_REFOUT
    crc = reflect(crc, CRC_WIDTH);
#endif
#else
    crc_t crc = (crc_t)CRC_INIT;
    while (n--)
        crc = (crc_t)(((CRC_WIDTH > 8 ? crc << 8 : 0) ^ table[(uint8_t)((crc >> (CRC_WIDTH - 8)) ^ *data++)]) & CRC_MASK);
#if CRC_REFOUT
    crc = reflect(crc, CRC_WIDTH);
#endif
#endif
    return (crc_t)((crc ^ (crc_t)CRC_XOROUT) & CRC_MASK);
}
