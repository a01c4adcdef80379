/* One period of the core (rig_core.h: rig_tick): heartbeat watchdog, motion (exactly one
 * hal_step: a run's next point or the controlled stop's Q16 law), inputs (exactly one
 * hal_read), the checks of section 8 (rig_state.c) and telemetry. */
#include "rig_core_internal.h"

/* floor(x / 65536) without relying on the implementation-defined >> of negative values. */
static int64_t floor_q16(int64_t x) {
    int64_t q = x / Q16_ONE;
    if (x % Q16_ONE != 0 && x < 0) q -= 1;
    return q;
}

/* ---- one period ------------------------------------------------------------------------ */

/* RUNNING: the next point, the end of the run, or an underrun. Returns the step delta. */
static int32_t run_step(rig_mcu *m) {
    if (m->pt_count > 0) {
        rig_point pt = m->points[m->pt_head];
        m->pt_head = (m->pt_head + 1u) & (RIG_BUFFER_CAPACITY - 1u);
        m->pt_count--;
        int64_t delta = (int64_t)pt.steps - (int64_t)m->steps;
        m->expected_enc = pt.enc_expected;
        m->exec_index++;
        m->vel_q16 = delta * Q16_ONE;
        return clip_i64(delta); /* |delta| <= max_step_delta (rule 7) */
    }
    if (m->final_received) {
        m->vel_q16 = 0;
        m->expected_enc = RIG_NO_CHECK;
        rig_set_state(m, RIG_STATE_IDLE, RIG_REASON_RUN_COMPLETE);
    } else {
        rig_fault(m, RIG_F_BUFFER_UNDERRUN, clip_u32(m->exec_index), clip_u32(m->next_index));
    }
    return 0;
}

/* STOPPING: one period of the Q16 stop law (docs/rig-protocol-behaviour.md). Returns the step
 * delta. */
static int32_t decelerate(rig_mcu *m) {
    int64_t v = m->vel_q16;
    int64_t mag = v < 0 ? -v : v;
    mag = mag > m->stop_dv_q16 ? mag - m->stop_dv_q16 : 0;
    v = v < 0 ? -mag : mag;
    m->vel_q16 = v;
    m->stop_pos_q16 += v;
    int64_t target = floor_q16(m->stop_pos_q16 + Q16_ONE / 2); /* round half up */
    if (target < m->cfg.steps_min || target > m->cfg.steps_max) {
        m->vel_q16 = 0;
        rig_fault(m, RIG_F_TRAVEL_LIMIT, clip_i64(target),
                  target < m->cfg.steps_min ? m->cfg.steps_min : m->cfg.steps_max);
        return 0;
    }
    int64_t delta = target - (int64_t)m->steps;
    if (v == 0) rig_set_state(m, m->stop_target, RIG_REASON_STOP_COMPLETE);
    return clip_i64(delta);
}

static void sync_driver(rig_mcu *m) {
    if (m->driver_applied != m->driver_enabled) {
        hal_driver_enable(m->driver_enabled != 0);
        m->driver_applied = m->driver_enabled;
    }
}

/* A halt: cancel the pulses of the present period that were not emitted. */
static void apply_halt(rig_mcu *m) {
    if (!m->halt_pending) return;
    m->halt_pending = 0;
    int32_t unemitted = hal_step_halt();
    if (unemitted != 0) {
        m->hw_steps = wrap_sub(m->hw_steps, unemitted);
        m->steps = wrap_add(m->hw_steps, m->steps_offset);
    }
}

static void send_telemetry(rig_mcu *m) {
    uint8_t flags = 0;
    if (m->steps != m->period_start_steps) flags |= RIG_TF_MOVING; /* moved this period */
    if (m->final_received) flags |= RIG_TF_FINAL_RECEIVED;
    if (!(RIG_ADC_MIN < m->load_raw && m->load_raw < RIG_ADC_MAX)) flags |= RIG_TF_LOAD_SATURATED;
    if (m->session) flags |= RIG_TF_SESSION;
    if (m->driver_enabled) flags |= RIG_TF_DRIVER_ENABLED;
    if (m->home_switch) flags |= RIG_TF_HOME_SWITCH;
    if (m->referenced) flags |= RIG_TF_REFERENCED;
    rig_msg_telemetry t = {m->boot_id, m->sample, m->t_us, m->steps, m->enc, m->load_raw,
                           m->exec_index, (uint16_t)m->pt_count, m->faults, m->state, flags};
    uint8_t p[RIG_LEN_TELEMETRY];
    rig_wire_put_telemetry(p, &t);
    rig_tx_frame(m, RIG_MSG_TELEMETRY, p, sizeof p);
}

void rig_tick(rig_mcu *m, uint32_t t_us) {
    hal_watchdog_kick();
    m->t_us = t_us;
    m->events_deferred = 0;
    /* an ESTOP received since the last tick: cancel what is left of that period's pulses */
    apply_halt(m);
    sync_driver(m);
    /* heartbeat watchdog (docs/rig-protocol-behaviour.md) */
    if (m->session) {
        uint32_t silence = t_us - m->last_rx_us;
        uint32_t timeout = (uint32_t)m->cfg.heartbeat_timeout_ms * 1000u;
        if (silence > timeout) {
            rig_fault(m, RIG_F_HEARTBEAT_LOST, clip_u32(silence / 1000u),
                      (int32_t)m->cfg.heartbeat_timeout_ms);
        }
    }
    /* motion: exactly one hal_step per tick, before the reading. MOVING compares the count
     * with the one before this period's motion (a SET_POSITION is no move), as the model. */
    m->period_start_steps = m->steps;
    int32_t delta = 0;
    if (m->state == RIG_STATE_RUNNING && m->awaiting_power && !hal_driver_powered()) {
        /* not one step into an unpowered driver: the run's first point waits (the board
         * names a chain that never confirms, STOP_CHAIN, and the halt emits nothing) */
    } else if (m->state == RIG_STATE_RUNNING) {
        m->awaiting_power = 0;
        delta = run_step(m);
    } else if (m->state == RIG_STATE_STOPPING) {
        delta = decelerate(m);
    }
    m->halt_pending = 0; /* a halt decided above applies to this period's (zero) output */
    hal_step(delta);
    m->hw_steps = wrap_add(m->hw_steps, delta);
    m->steps = wrap_add(m->hw_steps, m->steps_offset);
    /* inputs: exactly one hal_read per tick */
    rig_inputs in;
    memset(&in, 0, sizeof in);
    hal_read(&in);
    if (!m->have_reading) {
        /* the first reading after boot is encoder count 0 (a SET_POSITION before it keeps
         * its value); steps count from the boot position: the core's own output */
        m->enc_offset = wrap_sub(m->enc_offset, in.enc);
    }
    m->hw_enc = in.enc;
    m->enc = wrap_add(in.enc, m->enc_offset);
    if (m->have_reading && in.load_raw == m->load_raw) {
        if (m->same_load < UINT32_MAX) m->same_load++;
    } else {
        m->same_load = 1;
    }
    m->load_raw = in.load_raw;
    m->home_switch = in.home_switch ? 1u : 0u;
    m->stop_input = in.stop_input ? 1u : 0u;
    m->driver_alarm = in.driver_alarm ? 1u : 0u;
    m->have_reading = 1;
    /* checks of section 8 */
    if (m->state == RIG_STATE_IDLE || m->state == RIG_STATE_RUNNING ||
        m->state == RIG_STATE_STOPPING) {
        (void)rig_check_sensors(m, true);
    }
    /* the stop input acts in every state, as the ESTOP command (the model's injection) */
    if (m->stop_input) rig_estop(m);
    /* the driver alarm: every state but BOOT (no check runs in BOOT) */
    if (m->driver_alarm && m->state != RIG_STATE_BOOT) rig_fault(m, RIG_F_DRIVER, 0, 0);
    /* the board's own faults: every state but BOOT, in bit order */
    m->board_faults = (uint16_t)(in.board_faults & RIG_BOARD_FAULTS);
    if (m->board_faults && m->state != RIG_STATE_BOOT) {
        for (uint16_t bit = RIG_F_INTERNAL; bit <= RIG_F_STOP_CHAIN; bit = (uint16_t)(bit << 1))
            if (m->board_faults & bit) rig_fault(m, bit, in.board_detail, 0);
    }
    apply_halt(m);
    sync_driver(m);
    if (m->session) send_telemetry(m); /* no host, no telemetry (docs/rig-protocol.md 5) */
    m->sample++;
}
