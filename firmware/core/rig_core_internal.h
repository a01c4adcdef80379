/* The core's own interface between its files (not for boards or tests: rig_core.h is).
 *
 *   rig_core.c      the overview, boot, the CONFIG deceleration (rig_stop_dv_q16)
 *   rig_tx.c        the transmit FIFO and the FAULT/STATE frames held behind a reply
 *   rig_state.c     state changes, faults, the trajectory buffer's resets, section 8's checks
 *   rig_commands.c  the commands (section 5) and their replies
 *   rig_rx.c        received frames: type and length rules, section 6's seq rules
 *   rig_tick.c      one period: watchdog, motion, inputs, checks, telemetry
 *
 * The small arithmetic helpers are static inline here: several files need them, and they
 * are the core's hot path (one or two instructions each once inlined).
 */
#ifndef RIG_CORE_INTERNAL_H
#define RIG_CORE_INTERNAL_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "rig_core.h"
#include "rig_frame.h"
#include "rig_wire.h"

#define Q16_ONE 65536LL

/* ---- small arithmetic helpers ---------------------------------------------------------- */

/* a + b modulo 2^32, as int32 (offsets: steps = hw_steps + steps_offset). */
static inline int32_t wrap_add(int32_t a, int32_t b) {
    uint32_t u = (uint32_t)a + (uint32_t)b;
    int32_t v;
    memcpy(&v, &u, sizeof v);
    return v;
}

static inline int32_t wrap_sub(int32_t a, int32_t b) {
    uint32_t u = (uint32_t)a - (uint32_t)b;
    int32_t v;
    memcpy(&v, &u, sizeof v);
    return v;
}

/* The model's clip of a FAULT value/limit to the i32 field. */
static inline int32_t clip_i64(int64_t v) {
    if (v > INT32_MAX) return INT32_MAX;
    if (v < INT32_MIN) return INT32_MIN;
    return (int32_t)v;
}

static inline int32_t clip_u32(uint32_t v) {
    return v > (uint32_t)INT32_MAX ? INT32_MAX : (int32_t)v;
}

/* ---- rig_tx.c -------------------------------------------------------------------------- */

void rig_tx_frame(rig_mcu *m, uint8_t type, const uint8_t *payload, size_t len);
void rig_emit_event(rig_mcu *m, uint8_t type, const uint8_t *payload, size_t len);
void rig_flush_events(rig_mcu *m);

/* ---- rig_state.c ----------------------------------------------------------------------- */

void rig_set_state(rig_mcu *m, uint8_t new_state, uint8_t reason);
void rig_fault(rig_mcu *m, uint16_t bit, int32_t value, int32_t limit);
void rig_estop(rig_mcu *m);
uint16_t rig_check_sensors(rig_mcu *m, bool apply);
void rig_discard_buffer(rig_mcu *m);
void rig_clear_trajectory(rig_mcu *m);
void rig_begin_stop(rig_mcu *m, uint8_t target, uint8_t reason);
void rig_restore_calibration(rig_mcu *m);

/* ---- rig_commands.c -------------------------------------------------------------------- */

/* A reply (ACK or HELLO_REPLY payload) being built for the present command. */
typedef struct {
    uint8_t type, len;
    uint8_t payload[RIG_MAX_REPLY];
} rig_reply;

_Static_assert(RIG_MAX_REPLY >= RIG_LEN_HELLO_REPLY && RIG_MAX_REPLY >= RIG_LEN_ACK,
               "a reply buffer holds the longest reply");

void rig_reply_ack(const rig_mcu *m, rig_reply *r, uint16_t seq, uint8_t result);
void rig_execute(rig_mcu *m, const rig_frame *f, rig_reply *r);

#endif
