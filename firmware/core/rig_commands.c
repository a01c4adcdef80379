/* The commands of section 5 (rig_core_internal.h): each checks its state and values,
 * changes the MCU and fills its reply (ACK, HELLO_REPLY or CALIBRATION); rig_execute()
 * dispatches one whose length rig_rx.c has checked. */
#include "rig_core_internal.h"

/* Finite binary32 (not NaN, not inf), by its exponent bits: no <math.h>. */
static bool finite_f(float x) {
    uint32_t u;
    memcpy(&u, &x, sizeof u);
    return (u & 0x7F800000u) != 0x7F800000u;
}

/* ---- commands -------------------------------------------------------------------------- */

static uint16_t buf_free(const rig_mcu *m) {
    return (uint16_t)(RIG_BUFFER_CAPACITY - m->pt_count);
}

static rig_msg_ack make_ack(const rig_mcu *m, uint16_t seq, uint8_t result) {
    rig_msg_ack a = {seq, result, m->state, m->sample, (uint16_t)m->pt_count, buf_free(m)};
    return a;
}

void rig_reply_ack(const rig_mcu *m, rig_reply *r, uint16_t seq, uint8_t result) {
    rig_msg_ack a = make_ack(m, seq, result);
    r->type = RIG_MSG_ACK;
    r->len = (uint8_t)rig_wire_put_ack(r->payload, &a);
}

static void cmd_hello(rig_mcu *m, const rig_msg_hello *h, uint16_t seq, rig_reply *r) {
    uint8_t result;
    if (m->state == RIG_STATE_RUNNING || m->state == RIG_STATE_STOPPING) {
        result = RIG_BAD_STATE;
    } else if (h->proto_major != RIG_PROTO_MAJOR) {
        result = RIG_VERSION_MISMATCH;
    } else {
        result = RIG_OK;
        m->session = 1;
        /* docs/rig-protocol.md: "a HELLO that opens a session" restores the stored calibration;
         * every accepted HELLO opens (or takes over) a session, so every one restores it. */
        rig_restore_calibration(m);
        if (m->state == RIG_STATE_BOOT) rig_set_state(m, RIG_STATE_IDLE, RIG_REASON_COMMAND);
    }
    rig_msg_hello_reply hr;
    hr.ack = make_ack(m, seq, result);
    hr.proto_major = RIG_PROTO_MAJOR;
    hr.proto_minor = RIG_PROTO_MINOR;
    hr.fw_version = RIG_FW_VERSION;
    hr.boot_id = m->boot_id;
    hr.host_nonce = h->host_nonce;
    hr.telemetry_hz = RIG_TELEMETRY_HZ;
    hr.point_period_us = RIG_POINT_PERIOD_US;
    hr.max_chunk_points = RIG_MAX_CHUNK_POINTS;
    hr.buffer_capacity = RIG_BUFFER_CAPACITY;
    hr.step_nm = RIG_STEP_NM;
    hr.enc_nm = RIG_ENC_NM;
    hr.load_offset = m->cfg.load_offset;
    hr.load_gain_n = m->cfg.load_gain_n;
    hr.adc_min = (int32_t)RIG_ADC_MIN;
    hr.adc_max = (int32_t)RIG_ADC_MAX;
    hr.max_step_delta_limit = (uint16_t)RIG_MAX_STEP_DELTA;
    r->type = RIG_MSG_HELLO_REPLY;
    r->len = (uint8_t)rig_wire_put_hello_reply(r->payload, &hr);
}

/* 1.3: STORE_CALIBRATION (IDLE; a finite gain > 0, an offset strictly inside the ADC's
 * rails) writes record seq + 1 and puts it in use; NVM_ERROR keeps the previous one. */
static uint8_t cmd_store_calibration(rig_mcu *m, const rig_msg_store_calibration *c) {
    if (m->state != RIG_STATE_IDLE) return RIG_BAD_STATE;
    if (!finite_f(c->load_gain_n) || !(c->load_gain_n > 0.0f) ||
        c->load_offset <= (int32_t)RIG_ADC_MIN || c->load_offset >= (int32_t)RIG_ADC_MAX)
        return RIG_BAD_VALUE;
    rig_calibration cal = {c->load_offset, c->load_gain_n, m->stored.seq + 1u};
    if (!hal_nvm_store(&cal)) return RIG_NVM_ERROR;
    m->stored = cal;
    rig_restore_calibration(m);
    return RIG_OK;
}

static void reply_calibration(const rig_mcu *m, rig_reply *r, uint16_t seq, uint8_t result) {
    rig_msg_calibration c = {make_ack(m, seq, result), m->stored.seq, m->stored.load_offset,
                             m->stored.load_gain_n};
    r->type = RIG_MSG_CALIBRATION;
    r->len = (uint8_t)rig_wire_put_calibration(r->payload, &c);
}

/* Rule 7 of TRAJ_CHUNK for one point under the limits c, after the point (or position)
 * *prev: OUT_OF_LIMITS outside [steps_min, steps_max], BAD_VALUE for a jump above
 * max_step_delta, else RIG_OK and *prev becomes the point. */
static uint8_t point_rule(int32_t steps_min, int32_t steps_max, uint16_t max_step_delta,
                          int64_t *prev, int32_t s) {
    if (s < steps_min || s > steps_max) return RIG_OUT_OF_LIMITS;
    int64_t d = (int64_t)s - *prev;
    if (d < 0) d = -d;
    if (d > (int64_t)max_step_delta) return RIG_BAD_VALUE;
    *prev = s;
    return RIG_OK;
}

/* Version 1.2: a CONFIG re-checks every buffered point (from the present position: in
 * IDLE the buffer holds a trajectory from its point 0) against its new limits, with the
 * answer of a loop over them in order (the first failing point's result). In IDLE, the
 * only state CONFIG is taken in, the buffer is slots 0..pt_count-1 appended in order since
 * it was last emptied (a run leaves for IDLE only with its buffer empty or discarded, and
 * a chunk with first_index 0 clears it), so every block's summary is exact: a block is
 * read point by point only when it holds a failing point, and the loop's first failure is
 * in the first such block. At most one block of points is read (docs/firmware-emulated.md: a tick
 * is never late for a CONFIG; the loop over 2048 points took 56 105 instructions). */
static uint8_t buffered_points_rule(const rig_mcu *m, const rig_msg_config *c) {
    int64_t prev = m->steps;
    for (uint32_t first = 0; first < m->pt_count; first += RIG_BLOCK_POINTS) {
        const rig_block *b = &m->blocks[first / RIG_BLOCK_POINTS];
        uint32_t end = first + RIG_BLOCK_POINTS < m->pt_count ? first + RIG_BLOCK_POINTS
                                                               : m->pt_count;
        int64_t lead = (int64_t)m->points[first].steps - prev;
        if (lead < 0) lead = -lead;
        bool fails = b->min_steps < c->steps_min || b->max_steps > c->steps_max ||
                     b->max_jump > c->max_step_delta || lead > (int64_t)c->max_step_delta;
        if (!fails) {
            prev = m->points[end - 1u].steps;
            continue;
        }
        for (uint32_t k = first; k < end; k++) {
            uint8_t r = point_rule(c->steps_min, c->steps_max, c->max_step_delta, &prev,
                                   m->points[k].steps);
            if (r != RIG_OK) return r;
        }
    }
    return RIG_OK;
}

/* A point was stored in `slot`: its block's summary (buffered_points_rule). */
static void summarise_point(rig_mcu *m, uint32_t slot) {
    rig_block *b = &m->blocks[slot / RIG_BLOCK_POINTS];
    int32_t s = m->points[slot].steps;
    if (slot % RIG_BLOCK_POINTS == 0u) {
        b->min_steps = s;
        b->max_steps = s;
        b->max_jump = 0;
        return;
    }
    int64_t d = (int64_t)s - (int64_t)m->points[slot - 1u].steps;
    uint32_t jump = (uint32_t)(d < 0 ? -d : d);
    if (s < b->min_steps) b->min_steps = s;
    if (s > b->max_steps) b->max_steps = s;
    if (jump > b->max_jump) b->max_jump = jump;
}

static uint8_t cmd_config(rig_mcu *m, const rig_msg_config *c) {
    if (m->state != RIG_STATE_IDLE) return RIG_BAD_STATE;
    bool valid = c->force_limit_n > 0.0f && c->steps_min < c->steps_max &&
                 c->enc_min < c->enc_max && c->following_error_counts > 0 &&
                 c->load_gain_n >= 0.0f && c->decel_steps_s2 > 0.0f &&
                 c->max_step_delta > 0 && c->max_step_delta <= RIG_MAX_STEP_DELTA &&
                 c->heartbeat_timeout_ms > 0 &&
                 c->stuck_samples > 0 && finite_f(c->force_limit_n) &&
                 finite_f(c->load_gain_n) && finite_f(c->decel_steps_s2);
    /* a deceleration below half a Q16 step per period^2 (~7.6 steps/s^2) would never stop */
    if (!valid || rig_stop_dv_q16(c->decel_steps_s2) == 0) return RIG_BAD_VALUE;
    if (!(c->steps_min <= m->steps && m->steps <= c->steps_max && c->enc_min <= m->enc &&
          m->enc <= c->enc_max)) {
        return RIG_OUT_OF_LIMITS; /* limits that exclude the present position */
    }
    uint8_t buffered = buffered_points_rule(m, c); /* refused: nothing changes */
    if (buffered != RIG_OK) return buffered;
    rig_config n;
    n.force_limit_n = c->force_limit_n;
    n.steps_min = c->steps_min;
    n.steps_max = c->steps_max;
    n.enc_min = c->enc_min;
    n.enc_max = c->enc_max;
    n.following_error_counts = c->following_error_counts;
    /* gain 0 keeps the calibration in use, offset included (the model's reading of "keeps
     * the stored calibration": an override of this session stays). */
    if (c->load_gain_n == 0.0f) {
        n.load_offset = m->cfg.load_offset;
        n.load_gain_n = m->cfg.load_gain_n;
    } else {
        n.load_offset = c->load_offset;
        n.load_gain_n = c->load_gain_n;
    }
    n.decel_steps_s2 = c->decel_steps_s2;
    n.max_step_delta = c->max_step_delta;
    n.heartbeat_timeout_ms = c->heartbeat_timeout_ms;
    n.stuck_samples = c->stuck_samples;
    m->cfg = n;
    m->stop_dv_q16 = rig_stop_dv_q16(n.decel_steps_s2);
    return RIG_OK;
}

/* TRAJ_CHUNK, its length already checked: rules 1-7 of section 5 in order. */
static uint8_t cmd_chunk(rig_mcu *m, const uint8_t *payload, const rig_msg_chunk_head *h) {
    if (h->first_index == 0 && m->state == RIG_STATE_IDLE) rig_clear_trajectory(m); /* rule 1 */
    if ((m->state != RIG_STATE_IDLE && m->state != RIG_STATE_RUNNING) || !m->accepting) {
        return RIG_BAD_STATE; /* rule 2 */
    }
    uint64_t end = (uint64_t)h->first_index + h->n;
    if (end <= m->next_index) return RIG_OK;                  /* rule 3: late duplicate */
    if (h->first_index != m->next_index) return RIG_SEQUENCE_GAP; /* rule 4 */
    if (m->final_received) return RIG_BAD_STATE;              /* rule 5 */
    if (h->n > buf_free(m)) return RIG_NO_SPACE;              /* rule 6 */
    int64_t prev = m->steps; /* rule 7 */
    if (m->pt_count > 0) {
        uint32_t last = (m->pt_head + m->pt_count - 1u) & (RIG_BUFFER_CAPACITY - 1u);
        prev = m->points[last].steps;
    }
    for (unsigned k = 0; k < h->n; k++) {
        int32_t s, e;
        rig_wire_get_point(payload, k, &s, &e);
        (void)e;
        uint8_t r = point_rule(m->cfg.steps_min, m->cfg.steps_max, m->cfg.max_step_delta,
                               &prev, s);
        if (r != RIG_OK) return r;
    }
    for (unsigned k = 0; k < h->n; k++) {
        uint32_t slot = (m->pt_head + m->pt_count) & (RIG_BUFFER_CAPACITY - 1u);
        rig_wire_get_point(payload, k, &m->points[slot].steps, &m->points[slot].enc_expected);
        summarise_point(m, slot);
        m->pt_count++;
    }
    m->next_index += h->n;
    m->final_received = (h->flags & RIG_CHUNK_FINAL) ? 1u : 0u;
    return RIG_OK;
}

static uint8_t cmd_start(rig_mcu *m) {
    if (m->faults) return RIG_FAULT_ACTIVE;
    if (m->state != RIG_STATE_IDLE) return RIG_BAD_STATE;
    if (m->pt_count == 0) return RIG_EMPTY;
    m->driver_enabled = 1;
    m->awaiting_power = 1; /* the first point waits for hal_driver_powered() */
    m->same_load = 0; /* the run's first sample counts 1 (docs/rig-protocol-behaviour.md) */
    rig_set_state(m, RIG_STATE_RUNNING, RIG_REASON_COMMAND);
    return RIG_OK;
}

static uint8_t cmd_stop(rig_mcu *m) {
    if (m->state == RIG_STATE_RUNNING) rig_begin_stop(m, RIG_STATE_IDLE, RIG_REASON_COMMAND);
    if (m->state == RIG_STATE_IDLE || m->state == RIG_STATE_STOPPING) rig_discard_buffer(m);
    return RIG_OK;
}

static uint8_t cmd_clear_fault(rig_mcu *m) {
    if (m->state != RIG_STATE_FAULT && m->state != RIG_STATE_ESTOP) return RIG_OK;
    if (rig_check_sensors(m, false) || m->board_faults) return RIG_FAULT_ACTIVE;
    m->faults = 0;
    rig_clear_trajectory(m);
    rig_set_state(m, RIG_STATE_IDLE, RIG_REASON_COMMAND);
    return RIG_OK;
}

static uint8_t cmd_set_position(rig_mcu *m, const rig_msg_set_position *sp) {
    if (m->state != RIG_STATE_IDLE) return RIG_BAD_STATE;
    m->steps_offset = wrap_sub(sp->steps, m->hw_steps);
    m->enc_offset = wrap_sub(sp->enc, m->hw_enc);
    m->steps = sp->steps;
    m->enc = sp->enc;
    m->referenced = 1;
    rig_clear_trajectory(m);
    return RIG_OK;
}

static uint8_t cmd_bye(rig_mcu *m) {
    if (m->state == RIG_STATE_RUNNING || m->state == RIG_STATE_STOPPING) return RIG_BAD_STATE;
    m->session = 0;
    rig_restore_calibration(m); /* docs/rig-protocol.md */
    if (m->state == RIG_STATE_IDLE) rig_set_state(m, RIG_STATE_BOOT, RIG_REASON_COMMAND);
    return RIG_OK;
}

/* Execute one command whose payload length has been checked; fill its reply. */
void rig_execute(rig_mcu *m, const rig_frame *f, rig_reply *r) {
    const uint8_t *p = rig_frame_payload(f);
    size_t len = f->payload_len;
    uint8_t result = RIG_OK;
    if (f->type == RIG_MSG_HELLO) {
        rig_msg_hello h;
        (void)rig_wire_get_hello(p, len, &h);
        cmd_hello(m, &h, f->seq, r);
        return;
    }
    if (f->type == RIG_MSG_ESTOP) {
        rig_estop(m);
        rig_reply_ack(m, r, f->seq, RIG_OK);
        return;
    }
    if (!m->session && f->type != RIG_MSG_STOP) {
        rig_reply_ack(m, r, f->seq, RIG_NO_SESSION);
        return;
    }
    switch (f->type) {
    case RIG_MSG_CONFIG: {
        rig_msg_config c;
        (void)rig_wire_get_config(p, len, &c);
        result = cmd_config(m, &c);
        break;
    }
    case RIG_MSG_TRAJ_CHUNK: {
        rig_msg_chunk_head h;
        (void)rig_wire_get_chunk_head(p, len, &h);
        result = cmd_chunk(m, p, &h);
        break;
    }
    case RIG_MSG_START:
        result = cmd_start(m);
        break;
    case RIG_MSG_STOP:
        result = cmd_stop(m);
        break;
    case RIG_MSG_CLEAR_FAULT:
        result = cmd_clear_fault(m);
        break;
    case RIG_MSG_SET_POSITION: {
        rig_msg_set_position sp;
        (void)rig_wire_get_set_position(p, len, &sp);
        result = cmd_set_position(m, &sp);
        break;
    }
    case RIG_MSG_BYE:
        result = cmd_bye(m);
        break;
    case RIG_MSG_STORE_CALIBRATION: {
        rig_msg_store_calibration c;
        (void)rig_wire_get_store_calibration(p, len, &c);
        reply_calibration(m, r, f->seq, cmd_store_calibration(m, &c));
        return;
    }
    case RIG_MSG_READ_CALIBRATION:
        reply_calibration(m, r, f->seq, RIG_OK);
        return;
    default:
        result = RIG_UNKNOWN_TYPE; /* not reached: the caller checked the type */
        break;
    }
    rig_reply_ack(m, r, f->seq, result);
}
