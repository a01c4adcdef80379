/* The rig MCU's portable core (rig_core.h): docs/rig-protocol.md v1.1 with the decisions of
 * docs/rig-protocol.md, behaving on the wire as hil/emulators/mcu_model.py (corrected) does.
 *
 * Structure: rig_rx() -> framing (rig_frame.c) -> handle_frame(): type and length checks,
 * the seq rules of section 6, then one command; its reply is queued first and the FAULT and
 * STATE frames it caused after it. rig_tick(): heartbeat watchdog, motion (one hal_step),
 * inputs (one hal_read), the checks of section 8, telemetry. Everything the MCU sends goes
 * through tx_frame() into a FIFO of whole frames.
 *
 * Arithmetic rules: counts are int32 on the wire; differences and Q16 values are computed in
 * int64 so nothing overflows; wrapping u32 sums (offsets, time) are done in uint32_t. The
 * force check is single precision (the target's FPU). No heap, no libc but memcpy/memset,
 * no function pointers: dispatch is a switch on the (checked) type byte.
 *
 * Choices where the spec and the model are silent or disagree without a rule of docs/rig-protocol.md
 * (each is also commented where it is made):
 *  - ESTOP (command or stop input) sends a FAULT frame only when its bit is new (section 8);
 *    the model's estop() sends one for every ESTOP.
 *  - The stop input acts in every state, BOOT included (as the model's injected estop());
 *    the driver alarm latches DRIVER in every state but BOOT and keeps ESTOP as the state.
 *    CLEAR_FAULT's "present condition" list is section 8's (not the stop input or alarm).
 *  - All FAULT frames of a period's checks carry the period's state and precede its STATE
 *    frame (docs/rig-protocol.md: "before the period's STATE").
 *  - A halting fault found after the period's hal_step calls hal_step_halt() and the count
 *    not emitted is taken off `steps` before the telemetry (the count actually output).
 *  - A controlled stop starts from the present step rate: vel_q16 is the last period's
 *    move while running and is zeroed by a halt, ESTOP, the end of a run or of a ramp (the
 *    model keeps its _last_move through those, so a STOP or underrun before the first
 *    period of a later run would ramp from the old run's speed).
 *  - A dropped frame (tx FIFO full) still uses its MCU seq, so the host sees the gap.
 *  - Every accepted HELLO restores the stored calibration (docs/rig-protocol.md).
 *  - `steps` count from the boot position (the core's own output); `enc` from the first
 *    reading after boot. hal_driver_enable(false) is called at the first tick (the flag
 *    DRIVER_ENABLED is clear from boot).
 */
#include "rig_core.h"

#include <string.h>

#include "rig_frame.h"
#include "rig_wire.h"

#define HALTING_FAULTS                                                                   \
    (RIG_F_FORCE_LIMIT | RIG_F_TRAVEL_LIMIT | RIG_F_FOLLOWING_ERROR | RIG_F_LOAD_SATURATED | \
     RIG_F_LOAD_STUCK | RIG_F_DRIVER | RIG_BOARD_FAULTS)

/* The board's faults: it can no longer trust its sensing, timing or wiring, so the driver
 * is de-energised at once (stop category 0). The others halt holding position: a stepper
 * without current could be back-driven by the clamp's stored elastic energy. */
#define DEENERGISING_FAULTS RIG_BOARD_FAULTS

#define Q16_ONE 65536LL

_Static_assert(RIG_MAX_REPLY >= RIG_LEN_HELLO_REPLY && RIG_MAX_REPLY >= RIG_LEN_ACK,
               "a reply buffer holds the longest reply");

/* ---- small arithmetic helpers ---------------------------------------------------------- */

/* a + b modulo 2^32, as int32 (offsets: steps = hw_steps + steps_offset). */
static int32_t wrap_add(int32_t a, int32_t b) {
    uint32_t u = (uint32_t)a + (uint32_t)b;
    int32_t v;
    memcpy(&v, &u, sizeof v);
    return v;
}

static int32_t wrap_sub(int32_t a, int32_t b) {
    uint32_t u = (uint32_t)a - (uint32_t)b;
    int32_t v;
    memcpy(&v, &u, sizeof v);
    return v;
}

/* The model's clip of a FAULT value/limit to the i32 field. */
static int32_t clip_i64(int64_t v) {
    if (v > INT32_MAX) return INT32_MAX;
    if (v < INT32_MIN) return INT32_MIN;
    return (int32_t)v;
}

static int32_t clip_u32(uint32_t v) { return v > (uint32_t)INT32_MAX ? INT32_MAX : (int32_t)v; }

/* floor(x / 65536) without relying on the implementation-defined >> of negative values. */
static int64_t floor_q16(int64_t x) {
    int64_t q = x / Q16_ONE;
    if (x % Q16_ONE != 0 && x < 0) q -= 1;
    return q;
}

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

/* Finite binary32 (not NaN, not inf), by its exponent bits: no <math.h>. */
static bool finite_f(float x) {
    uint32_t u;
    memcpy(&u, &x, sizeof u);
    return (u & 0x7F800000u) != 0x7F800000u;
}

/* docs/rig-protocol.md: dv = round(decel * 1e-6 * 65536), from the f32 value in double, once at
 * CONFIG. The double operations are the model's, in its order: (double)decel is exact, the
 * product with the double nearest 1e-6 is correctly rounded (IEEE-754, as in Python), and
 * * 65536 is exact (a power of two), so the result is bit-identical to the model's before
 * the final rounding, which is Python's round() (half to even). For the default 5e6: 5e6 is
 * exact in binary32; 5e6 * 1e-6 rounds to exactly 5.0 in double (the error of the constant
 * 1e-6, ~4.5e-23, times 5e6 is ~2.3e-16, below half an ulp of 5.0, 4.4e-16); 5.0 * 65536 =
 * 327680.0 exactly -> dv = 327680 (5 steps per period per period = 1 m/s^2 at 1 ms).
 * On the Cortex-M4F double is done in software (libgcc), once per CONFIG. */
int64_t rig_stop_dv_q16(float decel_steps_s2) {
    double x = (double)decel_steps_s2 * 1e-6 * 65536.0;
    if (!(x > 0.0)) return 0;
    if (x >= 4611686018427387904.0) return 4611686018427387904LL; /* 2^62: a dead stop */
    int64_t i = (int64_t)x;
    double frac = x - (double)i; /* exact: x < 2^62 and x >= 2^53 is an integer */
    if (frac > 0.5 || (frac == 0.5 && (i & 1) != 0)) i += 1;
    return i;
}

/* ---- transmit -------------------------------------------------------------------------- */

size_t rig_tx_pending(const rig_mcu *m) { return (size_t)(m->tx_head - m->tx_tail); }

size_t rig_tx_take(rig_mcu *m, uint8_t *out, size_t max) {
    size_t n = rig_tx_pending(m);
    if (n > max) n = max;
    for (size_t i = 0; i < n; i++) {
        out[i] = m->tx_fifo[(m->tx_tail + (uint32_t)i) & (RIG_TX_FIFO_BYTES - 1u)];
    }
    m->tx_tail += (uint32_t)n;
    return n;
}

/* One MCU frame: flags 0, the MCU's own seq. The seq counts every frame built, also one
 * dropped for lack of FIFO room (the host then sees the gap; our choice, the spec only says
 * the seq counts every frame the MCU sends). A frame that does not fit is dropped whole. */
static void tx_frame(rig_mcu *m, uint8_t type, const uint8_t *payload, size_t len) {
    uint8_t wire[RIG_FRAME_HEADER + RIG_MAX_REPLY + RIG_FRAME_CRC + 4];
    size_t n = rig_frame_build(type, 0, m->tx_seq, payload, len, wire, sizeof wire);
    m->tx_seq++;
    size_t room = RIG_TX_FIFO_BYTES - rig_tx_pending(m);
    if (n == 0 || n > room) {
        m->stats.tx_dropped++;
        return;
    }
    for (size_t i = 0; i < n; i++) {
        m->tx_fifo[(m->tx_head + (uint32_t)i) & (RIG_TX_FIFO_BYTES - 1u)] = wire[i];
    }
    m->tx_head += (uint32_t)n;
}

/* A FAULT or STATE frame: sent at once, or held while a command is executed (its reply
 * goes first). */
static void emit_event(rig_mcu *m, uint8_t type, const uint8_t *payload, size_t len) {
    if (m->events_deferred && m->event_count < RIG_EVENT_SLOTS && len <= RIG_EVENT_MAX) {
        rig_event *e = &m->events[m->event_count++];
        e->type = type;
        e->len = (uint8_t)len;
        memcpy(e->payload, payload, len);
        return;
    }
    tx_frame(m, type, payload, len);
}

static void flush_events(rig_mcu *m) {
    for (uint8_t i = 0; i < m->event_count; i++) {
        tx_frame(m, m->events[i].type, m->events[i].payload, m->events[i].len);
    }
    m->event_count = 0;
    m->events_deferred = 0;
}

/* ---- state, faults, trajectory --------------------------------------------------------- */

static void set_state(rig_mcu *m, uint8_t new_state, uint8_t reason) {
    uint8_t p[RIG_LEN_STATE];
    rig_msg_state s = {m->state, new_state, reason, m->exec_index, m->sample};
    m->state = new_state;
    rig_wire_put_state(p, &s);
    emit_event(m, RIG_MSG_STATE, p, sizeof p);
}

static void latch(rig_mcu *m, uint16_t bit, int32_t value, int32_t limit) {
    uint8_t p[RIG_LEN_FAULT];
    rig_msg_fault f = {bit, m->sample, m->state, value, limit};
    m->faults = (uint16_t)(m->faults | bit);
    rig_wire_put_fault(p, &f);
    emit_event(m, RIG_MSG_FAULT, p, sizeof p);
}

/* The buffer is thrown away (a stop, a fault, ESTOP): no more chunks until a new
 * trajectory (rule 2); FINAL_RECEIVED cleared (docs/rig-protocol.md). */
static void discard_buffer(rig_mcu *m) {
    m->pt_head = 0;
    m->pt_count = 0;
    m->accepting = 0;
    m->final_received = 0;
    m->expected_enc = RIG_NO_CHECK;
}

static void clear_trajectory(rig_mcu *m) {
    discard_buffer(m);
    m->next_index = 0;
    m->exec_index = 0;
    m->accepting = 1;
}

static void begin_stop(rig_mcu *m, uint8_t target, uint8_t reason) {
    discard_buffer(m);
    m->stop_target = target;
    m->stop_pos_q16 = (int64_t)m->steps * Q16_ONE; /* vel_q16 holds the last period's move */
    set_state(m, RIG_STATE_STOPPING, reason);
}

/* The reaction to newly latched bits (section 8): halt, or a controlled stop. */
static void react(rig_mcu *m, uint16_t bits) {
    if (bits & RIG_F_FOLLOWING_ERROR) m->referenced = 0; /* the encoder may have slipped */
    if (bits & DEENERGISING_FAULTS) m->driver_enabled = 0; /* low at this tick's end */
    if (bits & HALTING_FAULTS) {
        m->vel_q16 = 0;
        m->halt_pending = 1;
        discard_buffer(m);
        /* ESTOP is the stronger state: a driver alarm there keeps it (our choice). */
        if (m->state != RIG_STATE_FAULT && m->state != RIG_STATE_ESTOP) {
            set_state(m, RIG_STATE_FAULT, RIG_REASON_FAULT);
        }
    } else if (m->state == RIG_STATE_RUNNING) {
        begin_stop(m, RIG_STATE_FAULT, RIG_REASON_FAULT);
    } else if (m->state == RIG_STATE_STOPPING) {
        m->stop_target = RIG_STATE_FAULT;
    } else if (m->state == RIG_STATE_IDLE) {
        /* as the model: at rest the buffer is kept (CLEAR_FAULT clears it) */
        set_state(m, RIG_STATE_FAULT, RIG_REASON_FAULT);
    }
}

/* Latch one fault bit (once: a latched bit sends nothing) and react. */
static void fault(rig_mcu *m, uint16_t bit, int32_t value, int32_t limit) {
    if (m->faults & bit) return;
    latch(m, bit, value, limit);
    react(m, bit);
}

/* ESTOP command or stop input: halt, driver off, ESTOP. The FAULT frame is sent when the
 * bit is new only (section 8: "each new bit also sends one FAULT frame"). */
static void estop(rig_mcu *m) {
    m->vel_q16 = 0;
    m->driver_enabled = 0;
    m->halt_pending = 1;
    discard_buffer(m);
    if (!(m->faults & RIG_F_ESTOP)) latch(m, RIG_F_ESTOP, 0, 0);
    if (m->state != RIG_STATE_ESTOP) set_state(m, RIG_STATE_ESTOP, RIG_REASON_FAULT);
}

static void restore_calibration(rig_mcu *m) {
    m->cfg.load_offset = m->stored.load_offset;
    m->cfg.load_gain_n = m->stored.load_gain_n;
}

/* The checks of section 8 on the present reading, in bit order (docs/rig-protocol.md): every
 * failing check latches; each new bit sends its FAULT frame (all with the period's state),
 * and only then the reaction runs, so the period's STATE frame follows every FAULT frame.
 * FOLLOWING_ERROR and LOAD_STUCK only in RUNNING. Returns the bits whose condition holds;
 * latches and reacts only when apply (CLEAR_FAULT asks with apply false). */
static uint16_t check_sensors(rig_mcu *m, bool apply) {
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
    /* travel: steps before enc; the bound crossed is the limit (docs/rig-protocol.md) */
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

/* ---- boot ------------------------------------------------------------------------------ */

static void default_config(rig_config *c, rig_calibration cal) {
    c->force_limit_n = 400.0f;
    c->steps_min = -50000;
    c->steps_max = 400000;
    c->enc_min = -20000;
    c->enc_max = 200000;
    c->following_error_counts = 1000;
    c->load_offset = cal.load_offset;
    c->load_gain_n = cal.load_gain_n;
    c->decel_steps_s2 = 5e6f;
    c->max_step_delta = 250;
    c->heartbeat_timeout_ms = 250;
    c->stuck_samples = 200;
}

void rig_boot(rig_mcu *m, uint32_t boot_id, rig_calibration stored) {
    memset(m, 0, sizeof *m);
    m->boot_id = boot_id;
    m->stored = stored;
    m->state = RIG_STATE_BOOT;
    default_config(&m->cfg, stored);
    m->stop_dv_q16 = rig_stop_dv_q16(m->cfg.decel_steps_s2);
    m->driver_applied = 0xFF; /* unknown: the first tick tells the driver (off) */
    m->stop_target = RIG_STATE_IDLE;
    clear_trajectory(m);
}

/* ---- commands -------------------------------------------------------------------------- */

static uint16_t buf_free(const rig_mcu *m) {
    return (uint16_t)(RIG_BUFFER_CAPACITY - m->pt_count);
}

static rig_msg_ack make_ack(const rig_mcu *m, uint16_t seq, uint8_t result) {
    rig_msg_ack a = {seq, result, m->state, m->sample, (uint16_t)m->pt_count, buf_free(m)};
    return a;
}

/* A reply (ACK or HELLO_REPLY payload) being built for the present command. */
typedef struct {
    uint8_t type, len;
    uint8_t payload[RIG_MAX_REPLY];
} reply_buf;

static void reply_ack(const rig_mcu *m, reply_buf *r, uint16_t seq, uint8_t result) {
    rig_msg_ack a = make_ack(m, seq, result);
    r->type = RIG_MSG_ACK;
    r->len = (uint8_t)rig_wire_put_ack(r->payload, &a);
}

static void cmd_hello(rig_mcu *m, const rig_msg_hello *h, uint16_t seq, reply_buf *r) {
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
        restore_calibration(m);
        if (m->state == RIG_STATE_BOOT) set_state(m, RIG_STATE_IDLE, RIG_REASON_COMMAND);
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
    restore_calibration(m);
    return RIG_OK;
}

static void reply_calibration(const rig_mcu *m, reply_buf *r, uint16_t seq, uint8_t result) {
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
 * in the first such block. At most one block of points is read (docs/firmware.md: a tick
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
    if (h->first_index == 0 && m->state == RIG_STATE_IDLE) clear_trajectory(m); /* rule 1 */
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
    m->same_load = 0; /* the run's first sample counts 1 (docs/rig-protocol.md) */
    set_state(m, RIG_STATE_RUNNING, RIG_REASON_COMMAND);
    return RIG_OK;
}

static uint8_t cmd_stop(rig_mcu *m) {
    if (m->state == RIG_STATE_RUNNING) begin_stop(m, RIG_STATE_IDLE, RIG_REASON_COMMAND);
    if (m->state == RIG_STATE_IDLE || m->state == RIG_STATE_STOPPING) discard_buffer(m);
    return RIG_OK;
}

static uint8_t cmd_clear_fault(rig_mcu *m) {
    if (m->state != RIG_STATE_FAULT && m->state != RIG_STATE_ESTOP) return RIG_OK;
    if (check_sensors(m, false) || m->board_faults) return RIG_FAULT_ACTIVE;
    m->faults = 0;
    clear_trajectory(m);
    set_state(m, RIG_STATE_IDLE, RIG_REASON_COMMAND);
    return RIG_OK;
}

static uint8_t cmd_set_position(rig_mcu *m, const rig_msg_set_position *sp) {
    if (m->state != RIG_STATE_IDLE) return RIG_BAD_STATE;
    m->steps_offset = wrap_sub(sp->steps, m->hw_steps);
    m->enc_offset = wrap_sub(sp->enc, m->hw_enc);
    m->steps = sp->steps;
    m->enc = sp->enc;
    m->referenced = 1;
    clear_trajectory(m);
    return RIG_OK;
}

static uint8_t cmd_bye(rig_mcu *m) {
    if (m->state == RIG_STATE_RUNNING || m->state == RIG_STATE_STOPPING) return RIG_BAD_STATE;
    m->session = 0;
    restore_calibration(m); /* docs/rig-protocol.md */
    if (m->state == RIG_STATE_IDLE) set_state(m, RIG_STATE_BOOT, RIG_REASON_COMMAND);
    return RIG_OK;
}

/* Execute one command whose payload length has been checked; fill its reply. */
static void execute(rig_mcu *m, const rig_frame *f, reply_buf *r) {
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
        estop(m);
        reply_ack(m, r, f->seq, RIG_OK);
        return;
    }
    if (!m->session && f->type != RIG_MSG_STOP) {
        reply_ack(m, r, f->seq, RIG_NO_SESSION);
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
    reply_ack(m, r, f->seq, result);
}

/* Minimal payload length of a host type; -1: unknown type. TRAJ_CHUNK is checked whole
 * by chunk_length_ok. */
static int min_payload(uint8_t type) {
    switch (type) {
    case RIG_MSG_HELLO: return (int)RIG_LEN_HELLO;
    case RIG_MSG_HEARTBEAT: return (int)RIG_LEN_HEARTBEAT;
    case RIG_MSG_CONFIG: return (int)RIG_LEN_CONFIG;
    case RIG_MSG_TRAJ_CHUNK: return (int)RIG_LEN_CHUNK_HEAD;
    case RIG_MSG_START:
    case RIG_MSG_STOP:
    case RIG_MSG_ESTOP:
    case RIG_MSG_CLEAR_FAULT:
    case RIG_MSG_BYE: return 0;
    case RIG_MSG_SET_POSITION: return (int)RIG_LEN_SET_POSITION;
    case RIG_MSG_STORE_CALIBRATION: return (int)RIG_LEN_STORE_CALIBRATION;
    case RIG_MSG_READ_CALIBRATION: return 0;
    default: return -1;
    }
}

static bool chunk_length_ok(const uint8_t *p, size_t len) {
    rig_msg_chunk_head h;
    if (!rig_wire_get_chunk_head(p, len, &h)) return false;
    if (h.n == 0 || h.n > RIG_MAX_CHUNK_POINTS) return false;
    return len >= RIG_LEN_CHUNK_HEAD + (size_t)h.n * RIG_LEN_POINT;
}

static bool seq_newer(uint16_t seq, uint16_t last) {
    uint16_t d = (uint16_t)(seq - last);
    return d != 0 && d < 0x8000u;
}

static bool seq_stale(uint16_t seq, uint16_t last) { return seq_newer(last, seq); }

static void send_reply(rig_mcu *m, const reply_buf *r) { tx_frame(m, r->type, r->payload, r->len); }

/* One valid host frame (good CRC): section 2's type/length rules, section 6's seq rules
 * with docs/rig-protocol.md, then the command. */
static void handle_frame(rig_mcu *m, const rig_frame *f) {
    bool ack_req = (f->flags & RIG_FLAG_ACK_REQ) != 0;
    reply_buf r;
    m->last_rx_us = m->t_us; /* any valid host frame feeds the watchdog (docs/rig-protocol.md) */
    int need = f->type >= 0x80u ? -1 : min_payload(f->type);
    if (need < 0) { /* unknown, or an MCU->host type: an unknown command */
        if (ack_req) {
            reply_ack(m, &r, f->seq, RIG_UNKNOWN_TYPE);
            send_reply(m, &r);
        }
        return;
    }
    if (f->type == RIG_MSG_HEARTBEAT) return; /* never answered, whatever its length */
    bool len_ok = f->type == RIG_MSG_TRAJ_CHUNK
                      ? chunk_length_ok(rig_frame_payload(f), f->payload_len)
                      : f->payload_len >= (size_t)need;
    if (!len_ok) {
        if (ack_req) {
            reply_ack(m, &r, f->seq, RIG_BAD_LENGTH);
            send_reply(m, &r);
        }
        return;
    }
    bool store;
    bool is_stop = f->type == RIG_MSG_STOP || f->type == RIG_MSG_ESTOP;
    m->events_deferred = 1;
    m->event_count = 0;
    if (f->type == RIG_MSG_HELLO) {
        execute(m, f, &r);
        store = true; /* a new host starts at a random seq, whatever the answer */
    } else if (is_stop) {
        /* always executed, also with the stored seq (docs/rig-protocol.md); stored only when
         * newer, so an old seq does not re-base the order */
        execute(m, f, &r);
        store = !m->have_last_seq || seq_newer(f->seq, m->last_seq);
    } else if (m->have_last_seq && f->seq == m->last_seq) {
        /* a retransmission: the stored reply again, not executed again */
        r.type = m->last_reply_type;
        r.len = m->last_reply_len;
        memcpy(r.payload, m->last_reply, sizeof r.payload);
        store = false;
    } else if (m->have_last_seq && seq_stale(f->seq, m->last_seq)) {
        reply_ack(m, &r, f->seq, RIG_STALE);
        store = false;
    } else {
        execute(m, f, &r);
        store = true;
    }
    if (store) {
        m->have_last_seq = 1;
        m->last_seq = f->seq;
        m->last_reply_type = r.type;
        m->last_reply_len = r.len;
        memcpy(m->last_reply, r.payload, sizeof m->last_reply);
    }
    if (ack_req) send_reply(m, &r);
    flush_events(m);
}

void rig_rx(rig_mcu *m, const uint8_t *data, size_t n) {
    if (m == NULL || data == NULL) return;
    for (size_t i = 0; i < n; i++) {
        switch (rig_frame_rx_byte(&m->rx, data[i], &m->frame)) {
        case RIG_RX_FRAME:
            m->stats.frames_ok++;
            handle_frame(m, &m->frame);
            break;
        case RIG_RX_BAD:
            m->stats.frames_bad++;
            break;
        case RIG_RX_OVERFLOW:
            m->stats.rx_overflows++;
            break;
        case RIG_RX_NONE:
        default:
            break;
        }
    }
}

void rig_link_lost(rig_mcu *m) {
    m->session = 0;
    restore_calibration(m); /* docs/rig-protocol.md */
    if (m->state == RIG_STATE_RUNNING) begin_stop(m, RIG_STATE_IDLE, RIG_REASON_LINK_LOST);
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
        set_state(m, RIG_STATE_IDLE, RIG_REASON_RUN_COMPLETE);
    } else {
        fault(m, RIG_F_BUFFER_UNDERRUN, clip_u32(m->exec_index), clip_u32(m->next_index));
    }
    return 0;
}

/* STOPPING: one period of the Q16 stop law (docs/rig-protocol.md). Returns the step delta. */
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
        fault(m, RIG_F_TRAVEL_LIMIT, clip_i64(target),
              target < m->cfg.steps_min ? m->cfg.steps_min : m->cfg.steps_max);
        return 0;
    }
    int64_t delta = target - (int64_t)m->steps;
    if (v == 0) set_state(m, m->stop_target, RIG_REASON_STOP_COMPLETE);
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
    tx_frame(m, RIG_MSG_TELEMETRY, p, sizeof p);
}

void rig_tick(rig_mcu *m, uint32_t t_us) {
    hal_watchdog_kick();
    m->t_us = t_us;
    m->events_deferred = 0;
    /* an ESTOP received since the last tick: cancel what is left of that period's pulses */
    apply_halt(m);
    sync_driver(m);
    /* heartbeat watchdog (docs/rig-protocol.md) */
    if (m->session) {
        uint32_t silence = t_us - m->last_rx_us;
        uint32_t timeout = (uint32_t)m->cfg.heartbeat_timeout_ms * 1000u;
        if (silence > timeout) {
            fault(m, RIG_F_HEARTBEAT_LOST, clip_u32(silence / 1000u),
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
        (void)check_sensors(m, true);
    }
    /* the stop input acts in every state, as the ESTOP command (the model's injection) */
    if (m->stop_input) estop(m);
    /* the driver alarm: every state but BOOT (no check runs in BOOT) */
    if (m->driver_alarm && m->state != RIG_STATE_BOOT) fault(m, RIG_F_DRIVER, 0, 0);
    /* the board's own faults: every state but BOOT, in bit order */
    m->board_faults = (uint16_t)(in.board_faults & RIG_BOARD_FAULTS);
    if (m->board_faults && m->state != RIG_STATE_BOOT) {
        for (uint16_t bit = RIG_F_INTERNAL; bit <= RIG_F_STOP_CHAIN; bit = (uint16_t)(bit << 1))
            if (m->board_faults & bit) fault(m, bit, in.board_detail, 0);
    }
    apply_halt(m);
    sync_driver(m);
    if (m->session) send_telemetry(m); /* no host, no telemetry (docs/rig-protocol.md 5) */
    m->sample++;
}
