#include "cobs.h"

uint8_t cobs_encode(const uint8_t *in, uint8_t n, uint8_t *out) {
    uint8_t code_at = 0, code = 1, o = 1;
    for (uint8_t i = 0; i < n; i++) {
        if (in[i] == 0) {
            out[code_at] = code;
            code_at = o++;
            code = 1;
        } else {
            out[o++] = in[i];
            if (++code == 0xFF) {
                out[code_at] = code;
                code_at = o++;
                code = 1;
            }
        }
    }
    out[code_at] = code;
    return o;
}

uint8_t cobs_decode(const uint8_t *in, uint8_t n, uint8_t *out) {
    uint8_t i = 0, o = 0;
    while (i < n) {
        uint8_t code = in[i++];
        if (code == 0 || (uint16_t)i + code - 1 > n)
            return 0;
        for (uint8_t k = 1; k < code; k++) {
            if (in[i] == 0)
                return 0;
            out[o++] = in[i++];
        }
        if (code != 0xFF && i < n)
            out[o++] = 0;
    }
    return o;
}
