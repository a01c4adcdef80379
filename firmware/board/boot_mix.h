/* The boot id's mixing, shared by both boards (NUCLEO-F446RE, the QEMU build). */
#ifndef BOOT_MIX_H
#define BOOT_MIX_H

#include <stdint.h>

/* A 32-bit avalanche (xor-shift-multiply): every input bit flips about half the output's. */
static inline uint32_t mix32(uint32_t h) {
    h ^= h >> 16;
    h *= 0x7FEB352Du;
    h ^= h >> 15;
    h *= 0x846CA68Bu;
    h ^= h >> 16;
    return h;
}

#endif
