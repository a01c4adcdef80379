/* The unit tests of the firmware core (firmware/core/) on the fake HAL: the harness and the
 * runner; the tests are in test_*.c (core_test.h lists them): the worked examples of
 * docs/rig-protocol-behaviour.md section 12 byte for byte, the framing rules of section 2
 * (docs/rig-protocol.md), the seq rules of section 6, and the behaviours of sections 5, 8 and 9
 * with docs/rig-protocol.md and docs/rig-protocol-behaviour.md that the conformance suite
 * compares with hil/emulators/mcu_model.py. Ends with the line
 * "core tests: N passed, 0 failed" (exit status 1 if any failed).
 */
#include "core_test.h"

#include <stdlib.h>

int cur_failed;
static int n_passed, n_failed;

/* ---- harness --------------------------------------------------------------------------- */

rig_mcu M;
msg out[1024];
size_t nout;
uint16_t host_seq;
static uint32_t t_now;
static const rig_calibration CAL = {1500, 1e-4f, 0u};

void boot(void) {
    fake_hal_reset();
    rig_boot(&M, 0x5EED0001u, CAL);
    t_now = 0;
    host_seq = 100;
    nout = 0;
}

/* Take everything the MCU queued and decode it; every frame must be valid. */
size_t drain(void) {
    static uint8_t bytes[RIG_TX_FIFO_BYTES];
    size_t n = rig_tx_take(&M, bytes, sizeof bytes);
    size_t start = 0;
    nout = 0;
    for (size_t i = 0; i < n; i++) {
        if (bytes[i] != 0) continue;
        rig_frame f;
        CHECK(rig_frame_decode(bytes + start, i - start, &f) == RIG_RX_FRAME);
        CHECK(nout < sizeof out / sizeof out[0]);
        if (nout < sizeof out / sizeof out[0]) {
            msg *o = &out[nout++];
            o->type = f.type;
            o->flags = f.flags;
            o->seq = f.seq;
            o->len = f.payload_len;
            memcpy(o->payload, rig_frame_payload(&f), f.payload_len);
            o->wire_len = i + 1 - start;
            memcpy(o->wire, bytes + start, o->wire_len);
        }
        start = i + 1;
    }
    CHECK(start == n); /* only whole frames */
    return nout;
}

void tick(void) {
    rig_tick(&M, t_now);
    t_now += 1000;
}

/* n ticks, draining after each; returns the last telemetry. */
rig_msg_telemetry ticks(int n) {
    rig_msg_telemetry t;
    memset(&t, 0, sizeof t);
    for (int i = 0; i < n; i++) {
        tick();
        drain();
        CHECK(nout >= 1);
        CHECK(out[nout - 1].type == RIG_MSG_TELEMETRY);
        rig_wire_get_telemetry(out[nout - 1].payload, out[nout - 1].len, &t);
    }
    return t;
}

void send_raw(uint8_t type, uint8_t flags, uint16_t seq, const uint8_t *p, size_t n) {
    uint8_t w[RIG_FRAME_MAX_WIRE];
    size_t k = rig_frame_build(type, flags, seq, p, n, w, sizeof w);
    CHECK(k > 0);
    rig_rx(&M, w, k);
}

/* Send a command with ACK_REQ and a new seq; drain; return the ACK's result (-1: none). */
int cmd(uint8_t type, const uint8_t *p, size_t n) {
    send_raw(type, RIG_FLAG_ACK_REQ, ++host_seq, p, n);
    drain();
    for (size_t i = 0; i < nout; i++) {
        if (out[i].type == RIG_MSG_ACK || out[i].type == RIG_MSG_HELLO_REPLY ||
            out[i].type == RIG_MSG_CALIBRATION) {
            return out[i].payload[2];
        }
    }
    return -1;
}

rig_msg_ack ack_of(size_t i) {
    rig_msg_ack a;
    memset(&a, 0, sizeof a);
    CHECK(i < nout && (out[i].type == RIG_MSG_ACK || out[i].type == RIG_MSG_HELLO_REPLY));
    if (i < nout) rig_wire_get_ack(out[i].payload, out[i].len, &a);
    return a;
}

int hello(void) {
    uint8_t p[RIG_LEN_HELLO];
    rig_msg_hello h = {1, 1, 0xCAFEF00Du};
    rig_wire_put_hello(p, &h);
    return cmd(RIG_MSG_HELLO, p, sizeof p);
}

rig_msg_config default_cfg(void) {
    rig_msg_config c = {400.0f, -50000, 400000, -20000, 200000, 1000, 0, 0.0f, 5e6f,
                        250,    250,    200};
    return c;
}

int config(const rig_msg_config *c) {
    uint8_t p[RIG_LEN_CONFIG];
    rig_wire_put_config(p, c);
    return cmd(RIG_MSG_CONFIG, p, sizeof p);
}

size_t chunk_payload(uint8_t *p, uint32_t first, uint8_t flags, const int32_t *steps,
                            const int32_t *enc, unsigned n) {
    rig_put_u32(p, first);
    p[4] = flags;
    p[5] = (uint8_t)n;
    for (unsigned k = 0; k < n; k++) {
        rig_put_i32(p + 6 + 8 * k, steps[k]);
        rig_put_i32(p + 10 + 8 * k, enc ? enc[k] : RIG_NO_CHECK);
    }
    return 6 + 8 * (size_t)n;
}

int chunk(uint32_t first, uint8_t flags, const int32_t *steps, unsigned n) {
    uint8_t p[RIG_FRAME_MAX_PAYLOAD];
    size_t len = chunk_payload(p, first, flags, steps, NULL, n);
    return cmd(RIG_MSG_TRAJ_CHUNK, p, len);
}

int simple(uint8_t type) { return cmd(type, NULL, 0); }

size_t count_type(uint8_t type) {
    size_t k = 0;
    for (size_t i = 0; i < nout; i++) k += out[i].type == type;
    return k;
}

const msg *nth_of(uint8_t type, size_t nth) {
    for (size_t i = 0; i < nout; i++) {
        if (out[i].type == type && nth-- == 0) return &out[i];
    }
    return NULL;
}

rig_msg_fault fault_of(size_t nth) {
    rig_msg_fault f;
    memset(&f, 0, sizeof f);
    const msg *m = nth_of(RIG_MSG_FAULT, nth);
    CHECK(m != NULL);
    if (m) rig_wire_get_fault(m->payload, m->len, &f);
    return f;
}

rig_msg_state state_of(size_t nth) {
    rig_msg_state s;
    memset(&s, 0, sizeof s);
    const msg *m = nth_of(RIG_MSG_STATE, nth);
    CHECK(m != NULL);
    if (m) rig_wire_get_state(m->payload, m->len, &s);
    return s;
}

/* n ticks without a session: no telemetry (docs/rig-protocol.md, section 5). */
void silent_ticks(int n) {
    for (int i = 0; i < n; i++) {
        tick();
        drain();
        for (size_t k = 0; k < nout; k++) CHECK(out[k].type != RIG_MSG_TELEMETRY);
    }
}

void session(void) {
    boot();
    silent_ticks(1);
    CHECK_EQ(hello(), RIG_OK);
    CHECK_EQ(M.state, RIG_STATE_IDLE);
}

void hexcmp(const uint8_t *got, size_t n_got, const uint8_t *want, size_t n_want) {
    CHECK_EQ(n_got, n_want);
    if (n_got == n_want && memcmp(got, want, n_got) != 0) {
        fprintf(stderr, "  bytes differ:\n  got ");
        for (size_t i = 0; i < n_got; i++) fprintf(stderr, "%02x ", got[i]);
        fprintf(stderr, "\n  want ");
        for (size_t i = 0; i < n_want; i++) fprintf(stderr, "%02x ", want[i]);
        fprintf(stderr, "\n");
        cur_failed = 1;
    }
}

/* ---- main ---------------------------------------------------------------------------------- */

typedef struct {
    const char *name;
    void (*fn)(void);
} test_case;

#define T(fn) {#fn, fn}
static const test_case tests[] = {
    T(test_crc_check_value),
    T(test_example_hello_wire),
    T(test_example_ack),
    T(test_example_telemetry),
    T(test_cobs_long_runs),
    T(test_259_byte_frame_accepted),
    T(test_overflow_junk_and_bit_flips_dropped),
    T(test_unknown_and_short),
    T(test_seq_rules),
    T(test_no_reply_without_ack_req),
    T(test_run_of_n_points),
    T(test_chunk_rules),
    T(test_stop_ramp_q16),
    T(test_stop_at_standstill),
    T(test_underrun),
    T(test_load_stuck_at_exactly_stuck_samples),
    T(test_travel_limit_lower_bound),
    T(test_rail_latches_saturated_and_force),
    T(test_force_limit_and_following_error),
    T(test_heartbeat_loss_at_rest),
    T(test_heartbeat_loss_running),
    T(test_estop_and_driver),
    T(test_config_rules),
    T(test_config_rechecks_buffered_points),
    T(test_board_faults_de_energise_and_limits_hold),
    T(test_the_first_point_waits_for_the_drivers_power),
    T(test_telemetry_only_in_a_session_and_tx_fifo),
    T(test_set_position_and_bye),
    T(test_store_and_read_calibration),
};

int main(void) {
    for (size_t i = 0; i < sizeof tests / sizeof tests[0]; i++) {
        cur_failed = 0;
        tests[i].fn();
        if (cur_failed) {
            fprintf(stderr, "FAIL %s\n", tests[i].name);
            n_failed++;
        } else {
            n_passed++;
        }
    }
    printf("core tests: %d passed, %d failed\n", n_passed, n_failed);
    return n_failed ? EXIT_FAILURE : EXIT_SUCCESS;
}
