/* The core's states and faults (rig_core_internal.h): state changes with their STATE frames,
 * latching a fault bit with its FAULT frame and the reaction of section 8 (a halt or a
 * controlled stop), ESTOP, the trajectory buffer's resets, and section 8's checks of the
 * present reading. */
#include "rig_core_internal.h"

#define HALTING_FAULTS                                                                   \
    (RIG_F_FORCE_LIMIT | RIG_F_TRAVEL_LIMIT | RIG_F_FOLLOWING_ERROR | RIG_F_LOAD_SATURATED | \
     RIG_F_LOAD_STUCK | RIG_F_DRIVER | RIG_BOARD_FAULTS)

/* The board's faults: it can no longer trust its sensing, timing or wiring, so the driver
 * is de-energised at once (stop category 0). The others halt holding position: a stepper
 * without current could be back-driven by the clamp's stored elastic energy. */
#define DEENERGISING_FAULTS RIG_BOARD_FAULTS

/* Python's round() of a float: nearest, ties to even, clipped to int32 (NaN gives 0). For
 * |x| >= 2^23 a float is already an integer, so the fractional part is exact below that. */
static int32_t round_half_even_f(float x) {
    if (!(x == x)) return 0;
    if (x >= 2147483647.0f) return INT32_MAX;
    if (x <= -2147483648.0f) return INT32_MIN;
    int64_t i = (int64_t)x; /* toward zero; |x| < 2^31 here */
    float frac = x - (float)i;
    if (frac > 0.5f || (frac == 0.5f && (i & 1) != 0)) i += 1;
    if (frac < -0.5f || (frac == -0.5f && (i & 1) != 0)) i -= 1;
    return clip_i64(i);
}

/* ---- state, faults, trajectory --------------------------------------------------------- */

void rig_set_state(rig_mcu *m, uint8_t new_state, uint8_t reason) {
    uint8_t p[RIG_LEN_STATE];
    rig_msg_state s = {m->state, new_state, reason, m->exec_index, m->sample};
    m->state = new_state;
    rig_wire_put_state(p, &s);
    rig_emit_event(m, RIG_MSG_STATE, p, sizeof p);
}

static void latch(rig_mcu *m, uint16_t bit, int32_t value, int32_t limit) {
    uint8_t p[RIG_LEN_FAULT];
    rig_msg_fault f = {bit, m->sample, m->state, value, limit};
    m->faults = (uint16_t)(m->faults | bit);
    rig_wire_put_fault(p, &f);
    rig_emit_event(m, RIG_MSG_FAULT, p, sizeof p);
}

/* The buffer is thrown away (a stop, a fault, ESTOP): no more chunks until a new
 * trajectory (rule 2); FINAL_RECEIVED cleared (docs/rig-protocol.md). */
void rig_discard_buffer(rig_mcu *m) {
    m->pt_head = 0;
    m->pt_count = 0;
    m->accepting = 0;
    m->final_received = 0;
    m->expected_enc = RIG_NO_CHECK;
}

void rig_clear_trajectory(rig_mcu *m) {
    rig_discard_buffer(m);
    m->next_index = 0;
    m->exec_index = 0;
    m->accepting = 1;
}

void rig_begin_stop(rig_mcu *m, uint8_t target, uint8_t reason) {
    rig_discard_buffer(m);
    m->stop_target = target;
    m->stop_pos_q16 = (int64_t)m->steps * Q16_ONE; /* vel_q16 holds the last period's move */
    rig_set_state(m, RIG_STATE_STOPPING, reason);
}

/* The reaction to newly latched bits (section 8): halt, or a controlled stop. */
static void react(rig_mcu *m, uint16_t bits) {
    if (bits & RIG_F_FOLLOWING_ERROR) m->referenced = 0; /* the encoder may have slipped */
    if (bits & DEENERGISING_FAULTS) m->driver_enabled = 0; /* low at this tick's end */
    if (bits & HALTING_FAULTS) {
        m->vel_q16 = 0;
        m->halt_pending = 1;
        rig_discard_buffer(m);
        /* ESTOP is the stronger state: a driver alarm there keeps it (our choice). */
        if (m->state != RIG_STATE_FAULT && m->state != RIG_STATE_ESTOP) {
            rig_set_state(m, RIG_STATE_FAULT, RIG_REASON_FAULT);
        }
    } else if (m->state == RIG_STATE_RUNNING) {
        rig_begin_stop(m, RIG_STATE_FAULT, RIG_REASON_FAULT);
    } else if (m->state == RIG_STATE_STOPPING) {
        m->stop_target = RIG_STATE_FAULT;
    } else if (m->state == RIG_STATE_IDLE) {
        /* as the model: at rest the buffer is kept (CLEAR_FAULT clears it) */
        rig_set_state(m, RIG_STATE_FAULT, RIG_REASON_FAULT);
    }
}

/* Latch one fault bit (once: a latched bit sends nothing) and react. */
void rig_fault(rig_mcu *m, uint16_t bit, int32_t value, int32_t limit) {
    if (m->faults & bit) return;
    latch(m, bit, value, limit);
    react(m, bit);
}

/* ESTOP command or stop input: halt, driver off, ESTOP. The FAULT frame is sent when the
 * bit is new only (section 8: "each new bit also sends one FAULT frame"). */
void rig_estop(rig_mcu *m) {
    m->vel_q16 = 0;
    m->driver_enabled = 0;
    m->halt_pending = 1;
    rig_discard_buffer(m);
    if (!(m->faults & RIG_F_ESTOP)) latch(m, RIG_F_ESTOP, 0, 0);
    if (m->state != RIG_STATE_ESTOP) rig_set_state(m, RIG_STATE_ESTOP, RIG_REASON_FAULT);
}

void rig_restore_calibration(rig_mcu *m) {
    m->cfg.load_offset = m->stored.load_offset;
    m->cfg.load_gain_n = m->stored.load_gain_n;
}

/* The checks of section 8 on the present reading, in bit order
 * (docs/rig-protocol-behaviour.md): every failing check latches; each new bit sends its FAULT
 * frame (all with the period's state), and only then the reaction runs, so the period's STATE
 * frame follows every FAULT frame.
 * FOLLOWING_ERROR and LOAD_STUCK only in RUNNING. Returns the bits whose condition holds;
 * latches and reacts only when apply (CLEAR_FAULT asks with apply false). */
uint16_t rig_check_sensors(rig_mcu *m, bool apply) {
    const rig_config *c = &m->cfg;
    bool running = m->state == RIG_STATE_RUNNING;
    uint16_t found = 0, fresh = 0;
    int32_t value[5] = {0, 0, 0, 0, 0}, limit[5] = {0, 0, 0, 0, 0};
    static const uint16_t bits[5] = {RIG_F_FORCE_LIMIT, RIG_F_TRAVEL_LIMIT,
                                     RIG_F_FOLLOWING_ERROR, RIG_F_LOAD_SATURATED,
                                     RIG_F_LOAD_STUCK};
    /* force in single precision: (load_raw - load_offset) * load_gain_n. The difference is
     * exact in int64; converted from int32 when it fits (one VCVT on the M4F; the same
     * rounding as the int64 conversion, which libgcc does in software). */
    int64_t diff = (int64_t)m->load_raw - (int64_t)c->load_offset;
    float fdiff = (diff >= INT32_MIN && diff <= INT32_MAX) ? (float)(int32_t)diff : (float)diff;
    float force = fdiff * c->load_gain_n;
    float mag = force < 0.0f ? -force : force;
    if (mag > c->force_limit_n) {
        found |= RIG_F_FORCE_LIMIT;
        value[0] = round_half_even_f(force);
        limit[0] = round_half_even_f(c->force_limit_n);
    }
    /* travel: steps before enc; the bound crossed is the limit (docs/rig-protocol-behaviour.md) */
    if (m->steps < c->steps_min || m->steps > c->steps_max) {
        found |= RIG_F_TRAVEL_LIMIT;
        value[1] = m->steps;
        limit[1] = m->steps < c->steps_min ? c->steps_min : c->steps_max;
    } else if (m->enc < c->enc_min || m->enc > c->enc_max) {
        found |= RIG_F_TRAVEL_LIMIT;
        value[1] = m->enc;
        limit[1] = m->enc < c->enc_min ? c->enc_min : c->enc_max;
    }
    if (running && m->expected_enc != RIG_NO_CHECK) {
        int64_t err = (int64_t)m->enc - (int64_t)m->expected_enc;
        int64_t mag_err = err < 0 ? -err : err;
        if (mag_err > (int64_t)c->following_error_counts) {
            found |= RIG_F_FOLLOWING_ERROR;
            value[2] = clip_i64(err);
            limit[2] = c->following_error_counts;
        }
    }
    if (m->load_raw <= RIG_ADC_MIN || m->load_raw >= RIG_ADC_MAX) {
        found |= RIG_F_LOAD_SATURATED;
        value[3] = m->load_raw;
        limit[3] = (int32_t)RIG_ADC_MAX; /* adc_max for either rail (section 5) */
    }
    if (running && m->same_load >= (uint32_t)c->stuck_samples) {
        found |= RIG_F_LOAD_STUCK;
        value[4] = clip_u32(m->same_load);
        limit[4] = (int32_t)c->stuck_samples;
    }
    if (!apply) return found;
    for (unsigned i = 0; i < 5u; i++) {
        if ((found & bits[i]) && !(m->faults & bits[i])) {
            latch(m, bits[i], value[i], limit[i]);
            fresh = (uint16_t)(fresh | bits[i]);
        }
    }
    if (fresh) react(m, fresh);
    return found;
}
