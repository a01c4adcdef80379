/* The FMI guard's FMU states (see fmi2_guard.c): pythonfmu's state with the phase it was
 * taken in, and the checks of a serialised state before Python sees it. */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2_guard.h"

FMI2_Export fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *state) {
    Guard *g = (Guard *)c;
    if (!state) return refuse(g, "fmi2GetFMUstate: NULL state pointer");
    GuardState *s = (GuardState *)*state;  /* not NULL: a state of ours to overwrite */
    if (s && s->inner) {
        begin(g);
        in_fmi2FreeFMUstate(g->inner, &s->inner);
        s->inner = NULL;
    }
    if (!s && !(s = calloc(1, sizeof *s))) return refuse(g, "fmi2GetFMUstate: out of memory");
    fmi2Status status = CALL(g, in_fmi2GetFMUstate(g->inner, &s->inner));
    if (status > fmi2Warning || !s->inner) {
        if (s->inner) in_fmi2FreeFMUstate(g->inner, &s->inner);
        free(s);
        *state = NULL;
        return status > fmi2Warning ? status : fmi2Error;
    }
    s->phase = g->phase;
    *state = s;
    return status;
}

FMI2_Export fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate state) {
    Guard *g = (Guard *)c;
    GuardState *s = (GuardState *)state;
    if (!s || !s->inner) return refuse(g, "fmi2SetFMUstate: NULL state");
    fmi2Status status = CALL(g, in_fmi2SetFMUstate(g->inner, s->inner));
    if (status <= fmi2Warning) g->phase = s->phase;
    return status;
}

FMI2_Export fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *state) {
    Guard *g = (Guard *)c;
    if (!state || !*state) return fmi2OK;
    GuardState *s = (GuardState *)*state;
    fmi2Status status = s->inner ? CALL(g, in_fmi2FreeFMUstate(g->inner, &s->inner)) : fmi2OK;
    free(s);
    *state = NULL;
    return status;
}

FMI2_Export fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate state,
                                                  size_t *size) {
    Guard *g = (Guard *)c;
    GuardState *s = (GuardState *)state;
    if (!s || !s->inner || !size) return refuse(g, "fmi2SerializedFMUstateSize: NULL argument");
    return CALL(g, in_fmi2SerializedFMUstateSize(g->inner, s->inner, size));
}

FMI2_Export fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate state,
                                             fmi2Byte bytes[], size_t size) {
    Guard *g = (Guard *)c;
    GuardState *s = (GuardState *)state;
    if (!s || !s->inner || !bytes) return refuse(g, "fmi2SerializeFMUstate: NULL argument");
    return CALL(g, in_fmi2SerializeFMUstate(g->inner, s->inner, bytes, size));
}

static uint32_t crc32(const unsigned char *p, size_t n) {
    uint32_t crc = 0xFFFFFFFFu;
    while (n--) {
        crc ^= *p++;
        for (int k = 0; k < 8; k++) crc = (crc >> 1) ^ (0xEDB88320u & (0u - (crc & 1u)));
    }
    return ~crc;
}

static uint32_t le32(const unsigned char *p) {
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

/* Layout (fmu_src/state.py): magic, u32 version, u32 phase, u32 payload length, payload,
 * u32 CRC-32 of everything before it; little-endian. */
FMI2_Export fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte bytes[],
                                               size_t size, fmi2FMUstate *state) {
    Guard *g = (Guard *)c;
    const unsigned char *p = (const unsigned char *)bytes;
    const size_t head = sizeof GUARD_STATE_MAGIC - 1;
    if (!state) return refuse(g, "FMU state refused: NULL state pointer");
    *state = NULL;
    if (!bytes || size < head + 16 || memcmp(p, GUARD_STATE_MAGIC, head) != 0)
        return refuse(g, "FMU state refused: not a serialised ToggleClamp state");
    if (le32(p + head) != GUARD_STATE_VERSION)
        return refuse(g, "FMU state refused: format version %u, this FMU reads version %u",
                      (unsigned)le32(p + head), GUARD_STATE_VERSION);
    if (le32(p + head + 4) >= N_PHASES)
        return refuse(g, "FMU state refused: unknown phase code %u", (unsigned)le32(p + head + 4));
    if ((size_t)le32(p + head + 8) != size - head - 16)
        return refuse(g, "FMU state refused: truncated or padded (%lu bytes)",
                      (unsigned long)size);
    if (crc32(p, size - 4) != le32(p + size - 4))
        return refuse(g, "FMU state refused: checksum mismatch");
    GuardState *s = calloc(1, sizeof *s);
    if (!s) return refuse(g, "FMU state refused: out of memory");
    s->phase = (Phase)le32(p + head + 4);
    fmi2Status status = CALL(g, in_fmi2DeSerializeFMUstate(g->inner, bytes, size, &s->inner));
    if (status > fmi2Warning || !s->inner) {
        if (s->inner) in_fmi2FreeFMUstate(g->inner, &s->inner);
        free(s);
        return status > fmi2Warning ? status : fmi2Error;
    }
    *state = s;
    return status;
}
