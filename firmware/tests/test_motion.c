/* The core's unit tests (core_test.h): runs, TRAJ_CHUNK's rules, the Q16 controlled stop and
 * underruns. */
#include "core_test.h"

/* ---- motion ------------------------------------------------------------------------------ */

void test_run_of_n_points(void) {
    session();
    CHECK_EQ(M.steps, 0);
    CHECK_EQ(M.enc, 0); /* the first reading is count 0 */
    enum { N = 75 };
    int32_t pts[N];
    for (int i = 0; i < N; i++) pts[i] = (i + 1) * 10;
    CHECK_EQ(chunk(0, 0, pts, 30), RIG_OK);
    CHECK_EQ(chunk(30, 0, pts + 30, 30), RIG_OK);
    CHECK_EQ(chunk(60, RIG_CHUNK_FINAL, pts + 60, 15), RIG_OK);
    CHECK_EQ(chunk(60, RIG_CHUNK_FINAL, pts + 60, 15), RIG_OK); /* late duplicate: rule 3 */
    CHECK_EQ(M.pt_count, N);
    CHECK_EQ(simple(RIG_MSG_START), RIG_OK);
    uint32_t s0 = ack_of(0).sample;
    CHECK_EQ(fake.driver_on, false);
    for (int i = 0; i < N; i++) {
        rig_msg_telemetry t = ticks(1);
        CHECK_EQ(t.sample, s0 + (uint32_t)i);
        CHECK_EQ(t.state, RIG_STATE_RUNNING);
        CHECK_EQ(t.steps, pts[i]);
        CHECK_EQ(t.exec_index, (uint32_t)i + 1);
        CHECK_EQ(t.buf_level, N - i - 1);
        CHECK(t.flags & RIG_TF_MOVING);
        CHECK(t.flags & RIG_TF_FINAL_RECEIVED);
        CHECK(t.flags & RIG_TF_DRIVER_ENABLED);
        CHECK(t.flags & RIG_TF_SESSION);
        CHECK_EQ(fake.last_delta, 10);
    }
    CHECK_EQ(fake.driver_on, true);
    rig_msg_telemetry t = ticks(1);
    CHECK_EQ(t.sample, s0 + N);
    CHECK_EQ(t.state, RIG_STATE_IDLE);
    CHECK_EQ(t.exec_index, N);
    CHECK(!(t.flags & RIG_TF_MOVING));
    CHECK_EQ(nout, 2);
    rig_msg_state st = state_of(0);
    CHECK_EQ(st.old_state, RIG_STATE_RUNNING);
    CHECK_EQ(st.new_state, RIG_STATE_IDLE);
    CHECK_EQ(st.reason, RIG_REASON_RUN_COMPLETE);
    CHECK_EQ(st.exec_index, N);
    CHECK_EQ(st.sample, s0 + N);
    CHECK_EQ(fake.hw_steps, pts[N - 1]);
    /* one kick, one step, one read per tick, step before read */
    CHECK_EQ(fake.kicks, fake.read_calls);
    CHECK_EQ(fake.steps_calls, fake.read_calls);
    CHECK_EQ(fake.order_errors, 0);
}

void test_chunk_rules(void) {
    session();
    int32_t pts[30];
    for (int i = 0; i < 30; i++) pts[i] = i;
    CHECK_EQ(chunk(5, 0, pts, 3), RIG_SEQUENCE_GAP);
    CHECK_EQ(chunk(0, 0, pts, 30), RIG_OK);
    CHECK_EQ(chunk(10, 0, pts, 3), RIG_OK); /* all buffered */
    CHECK_EQ(chunk(29, 0, pts, 3), RIG_SEQUENCE_GAP);
    int32_t far[1] = {29 + 251};
    CHECK_EQ(chunk(30, 0, far, 1), RIG_BAD_VALUE);
    int32_t out_of[1] = {-50001};
    CHECK_EQ(chunk(30, 0, out_of, 1), RIG_OUT_OF_LIMITS);
    int32_t next[1] = {29 + 250};
    CHECK_EQ(chunk(30, RIG_CHUNK_FINAL, next, 1), RIG_OK);
    CHECK_EQ(chunk(31, 0, next, 1), RIG_BAD_STATE); /* after FINAL: rule 5 */
    /* fill the buffer: NO_SPACE changes nothing */
    CHECK_EQ(chunk(0, 0, pts, 30), RIG_OK); /* index 0 in IDLE: a new trajectory */
    CHECK_EQ(M.pt_count, 30);
    uint32_t idx = 30;
    int32_t flat[30];
    for (int i = 0; i < 30; i++) flat[i] = 29;
    while (M.pt_count + 30 <= RIG_BUFFER_CAPACITY) {
        CHECK_EQ(chunk(idx, 0, flat, 30), RIG_OK);
        idx += 30;
    }
    CHECK_EQ(chunk(idx, 0, flat, 30), RIG_NO_SPACE);
    CHECK_EQ(ack_of(0).buf_level, M.pt_count);
    CHECK_EQ(ack_of(0).buf_free, RIG_BUFFER_CAPACITY - M.pt_count);
    /* STOP in IDLE discards: rule 2 until a chunk with index 0 */
    CHECK_EQ(simple(RIG_MSG_STOP), RIG_OK);
    CHECK_EQ(M.pt_count, 0);
    CHECK_EQ(chunk(idx, 0, flat, 1), RIG_BAD_STATE);
    CHECK_EQ(simple(RIG_MSG_START), RIG_EMPTY);
    CHECK_EQ(chunk(0, 0, pts, 3), RIG_OK);
}

void test_stop_ramp_q16(void) {
    session();
    rig_msg_config c = default_cfg();
    c.max_step_delta = 200;
    CHECK_EQ(config(&c), RIG_OK);
    CHECK_EQ(M.stop_dv_q16, 327680);
    int32_t pts[30];
    for (int i = 0; i < 30; i++) pts[i] = 125 * (i + 1); /* 25 mm/s */
    CHECK_EQ(chunk(0, 0, pts, 30), RIG_OK);
    CHECK_EQ(simple(RIG_MSG_START), RIG_OK);
    ticks(10);
    CHECK_EQ(M.steps, 1250);
    CHECK_EQ(simple(RIG_MSG_STOP), RIG_OK);
    CHECK_EQ(M.state, RIG_STATE_STOPPING);
    CHECK_EQ(M.pt_count, 0);
    int32_t prev = 1250;
    int periods = 0;
    for (;;) {
        rig_msg_telemetry t = ticks(1);
        periods++;
        int32_t d = t.steps - prev;
        prev = t.steps;
        if (t.state != RIG_STATE_STOPPING) {
            CHECK_EQ(t.state, RIG_STATE_IDLE);
            CHECK_EQ(d, 0);
            CHECK(!(t.flags & RIG_TF_MOVING));
            CHECK_EQ(state_of(0).reason, RIG_REASON_STOP_COMPLETE);
            break;
        }
        CHECK_EQ(d, 125 - 5 * periods);
        CHECK(periods < 100);
        if (periods >= 100) break;
    }
    CHECK_EQ(periods, 25);
    CHECK_EQ(prev - 1250, 1500); /* 0.30 mm */
    /* dv rounding, half to even as Python's round() */
    CHECK_EQ(rig_stop_dv_q16(1e6f), 65536);
    CHECK_EQ(rig_stop_dv_q16(3.3e6f), 216269);
    CHECK_EQ(rig_stop_dv_q16(7.62939453125f), 0); /* exactly 0.5 -> 0 */
    CHECK_EQ(rig_stop_dv_q16(22.88818359375f), 2); /* exactly 1.5 -> 2 */
}

void test_stop_at_standstill(void) {
    session();
    int32_t pts[5] = {0, 0, 0, 0, 0};
    CHECK_EQ(chunk(0, 0, pts, 5), RIG_OK);
    CHECK_EQ(simple(RIG_MSG_START), RIG_OK);
    ticks(2); /* a hold: zero-step periods */
    CHECK_EQ(simple(RIG_MSG_STOP), RIG_OK);
    CHECK_EQ(M.state, RIG_STATE_STOPPING);
    rig_msg_telemetry t = ticks(1);
    CHECK_EQ(t.state, RIG_STATE_IDLE);
    CHECK_EQ(state_of(0).old_state, RIG_STATE_STOPPING);
    CHECK_EQ(state_of(0).reason, RIG_REASON_STOP_COMPLETE);
    /* STOP right after START, before any period */
    CHECK_EQ(chunk(0, 0, pts, 5), RIG_OK);
    CHECK_EQ(simple(RIG_MSG_START), RIG_OK);
    CHECK_EQ(simple(RIG_MSG_STOP), RIG_OK);
    t = ticks(1);
    CHECK_EQ(t.state, RIG_STATE_IDLE);
    CHECK_EQ(t.exec_index, 0);
}

void test_underrun(void) {
    session();
    int32_t pts[3] = {100, 200, 300};
    CHECK_EQ(chunk(0, 0, pts, 3), RIG_OK);
    CHECK_EQ(simple(RIG_MSG_START), RIG_OK);
    ticks(3);
    rig_msg_telemetry t = ticks(1); /* the 4th point is due: underrun */
    CHECK_EQ(t.state, RIG_STATE_STOPPING);
    CHECK_EQ(t.steps, 300); /* no move in the underrun's period */
    rig_msg_fault f = fault_of(0);
    CHECK_EQ(f.fault, RIG_F_BUFFER_UNDERRUN);
    CHECK_EQ(f.value, 3);
    CHECK_EQ(f.limit, 3);
    CHECK_EQ(f.state, RIG_STATE_RUNNING);
    CHECK_EQ(state_of(0).reason, RIG_REASON_FAULT);
    /* then the ramp from 100 steps/period: 95, 90, ... 5, then standstill -> FAULT */
    int32_t prev = 300;
    for (int k = 1; k <= 20; k++) {
        t = ticks(1);
        CHECK_EQ(t.steps - prev, 100 - 5 * k);
        prev = t.steps;
    }
    CHECK_EQ(t.state, RIG_STATE_FAULT);
    CHECK_EQ(state_of(0).reason, RIG_REASON_STOP_COMPLETE);
    CHECK_EQ(state_of(0).new_state, RIG_STATE_FAULT);
}
