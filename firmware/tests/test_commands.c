/* The core's unit tests (core_test.h): CONFIG, telemetry and the tx FIFO, SET_POSITION, BYE and
 * the calibration. */
#include "core_test.h"

void test_config_rules(void) {
    session();
    rig_msg_config c = default_cfg();
    c.steps_min = c.steps_max;
    CHECK_EQ(config(&c), RIG_BAD_VALUE);
    c = default_cfg();
    uint32_t nan_bits = 0x7FC00000u, inf_bits = 0x7F800000u;
    memcpy(&c.force_limit_n, &nan_bits, 4);
    CHECK_EQ(config(&c), RIG_BAD_VALUE);
    c = default_cfg();
    memcpy(&c.decel_steps_s2, &inf_bits, 4);
    CHECK_EQ(config(&c), RIG_BAD_VALUE);
    c = default_cfg();
    c.load_gain_n = -1e-4f;
    CHECK_EQ(config(&c), RIG_BAD_VALUE);
    c = default_cfg();
    c.stuck_samples = 0;
    CHECK_EQ(config(&c), RIG_BAD_VALUE);
    c = default_cfg();
    c.steps_min = 1;
    CHECK_EQ(config(&c), RIG_OUT_OF_LIMITS);
    c = default_cfg();
    c.load_offset = 77;
    c.load_gain_n = 2e-4f;
    CHECK_EQ(config(&c), RIG_OK);
    CHECK_EQ(M.cfg.load_offset, 77);
    /* gain 0 keeps the calibration in use */
    c = default_cfg();
    c.load_offset = 5;
    CHECK_EQ(config(&c), RIG_OK);
    CHECK_EQ(M.cfg.load_offset, 77);
    /* a HELLO that opens a session restores the stored calibration */
    CHECK_EQ(hello(), RIG_OK);
    rig_msg_hello_reply hr;
    rig_wire_get_hello_reply(out[0].payload, out[0].len, &hr);
    CHECK_EQ(hr.load_offset, 1500);
    /* not in RUNNING; no session in BOOT */
    int32_t pts[3] = {0, 0, 0};
    CHECK_EQ(chunk(0, 0, pts, 3), RIG_OK);
    CHECK_EQ(simple(RIG_MSG_START), RIG_OK);
    CHECK_EQ(config(&c), RIG_BAD_STATE);
    CHECK_EQ(hello(), RIG_BAD_STATE);
    CHECK_EQ(simple(RIG_MSG_BYE), RIG_BAD_STATE);
    boot();
    CHECK_EQ(config(&c), RIG_NO_SESSION);
    CHECK_EQ(simple(RIG_MSG_STOP), RIG_OK);
    CHECK_EQ(ack_of(0).state, RIG_STATE_BOOT);
}

/* Version 1.2: a CONFIG re-checks the buffered points against its limits (issue 35: a
 * CONFIG of a smaller max_step_delta after larger jumps were buffered let them run); 1.3:
 * never above RIG_MAX_STEP_DELTA, the most steps a board emits in a period. */
void test_config_rechecks_buffered_points(void) {
    session();
    rig_msg_config c = default_cfg();
    c.max_step_delta = RIG_MAX_STEP_DELTA + 1u;
    CHECK_EQ(config(&c), RIG_BAD_VALUE); /* above what the board can emit */
    c.max_step_delta = RIG_MAX_STEP_DELTA;
    CHECK_EQ(config(&c), RIG_OK);
    int32_t jumps[3] = {200, 400, 600}; /* the first from the present position, 0 */
    CHECK_EQ(chunk(0, RIG_CHUNK_FINAL, jumps, 3), RIG_OK);
    c.max_step_delta = 150;
    CHECK_EQ(config(&c), RIG_BAD_VALUE);
    CHECK_EQ(M.cfg.max_step_delta, RIG_MAX_STEP_DELTA); /* refused: nothing changed */
    c.max_step_delta = 199;                              /* point 0 is 200 steps from the table */
    CHECK_EQ(config(&c), RIG_BAD_VALUE);
    c.max_step_delta = RIG_MAX_STEP_DELTA;
    c.steps_max = 599; /* narrowed travel: the last point is outside */
    CHECK_EQ(config(&c), RIG_OUT_OF_LIMITS);
    CHECK_EQ(M.cfg.steps_max, 400000);
    c.steps_max = 600;
    c.max_step_delta = 200; /* every point still passes: accepted */
    CHECK_EQ(config(&c), RIG_OK);
    CHECK_EQ(M.cfg.max_step_delta, 200);
    CHECK_EQ(M.pt_count, 3);
    /* the run obeys what the MCU accepted */
    CHECK_EQ(simple(RIG_MSG_START), RIG_OK);
    rig_msg_telemetry tel = ticks(1);
    CHECK_EQ(tel.steps, 200);
    tel = ticks(3);
    CHECK_EQ(tel.state, RIG_STATE_IDLE);
    CHECK_EQ(tel.faults, 0);
    /* with the buffer empty only the present position counts */
    c.max_step_delta = 150;
    CHECK_EQ(config(&c), RIG_OK);
}

void test_telemetry_only_in_a_session_and_tx_fifo(void) {
    boot();
    silent_ticks(3); /* no host, no telemetry; the sample count runs on */
    CHECK_EQ(hello(), RIG_OK);
    for (int i = 3; i < 6; i++) {
        rig_msg_telemetry t = ticks(1);
        CHECK_EQ(t.state, RIG_STATE_IDLE);
        CHECK_EQ(t.sample, (uint32_t)i);
        CHECK_EQ(t.t_us, (uint32_t)i * 1000u);
        CHECK_EQ(t.boot_id, 0x5EED0001u);
        CHECK(t.flags & RIG_TF_SESSION);
        CHECK_EQ(out[nout - 1].flags, 0);
    }
    CHECK_EQ(simple(RIG_MSG_BYE), RIG_OK); /* the session ends: telemetry stops */
    silent_ticks(3);
    CHECK_EQ(hello(), RIG_OK);
    fake.home_switch = true;
    rig_msg_telemetry t = ticks(1);
    CHECK(t.flags & RIG_TF_HOME_SWITCH);
    CHECK(!(t.flags & RIG_TF_REFERENCED));
    /* MCU seq counts every frame */
    uint16_t s0 = out[0].seq;
    tick();
    tick();
    drain();
    CHECK_EQ(out[0].seq, (uint16_t)(s0 + 1));
    CHECK_EQ(out[1].seq, (uint16_t)(s0 + 2));
    /* a full FIFO drops whole frames and counts them */
    uint32_t dropped = M.stats.tx_dropped;
    for (int i = 0; i < 200; i++) tick(); /* 42 bytes each: 4096 / 42 = 97 fit */
    CHECK_EQ(rig_tx_pending(&M), 97u * 42u);
    CHECK_EQ(M.stats.tx_dropped - dropped, 200u - 97u);
    /* partial takes: the stream is still whole frames */
    uint8_t buf[4096];
    size_t got = 0;
    while (rig_tx_pending(&M)) got += rig_tx_take(&M, buf + got, 5);
    CHECK_EQ(got, 97u * 42u);
    size_t frames = 0, start = 0;
    for (size_t i = 0; i < got; i++) {
        if (buf[i]) continue;
        rig_frame f;
        CHECK(rig_frame_decode(buf + start, i - start, &f) == RIG_RX_FRAME);
        start = i + 1;
        frames++;
    }
    CHECK_EQ(frames, 97);
}

void test_set_position_and_bye(void) {
    session();
    ticks(2);
    uint8_t sp[8];
    rig_put_i32(sp, 5000);
    rig_put_i32(sp + 4, 700);
    CHECK_EQ(cmd(RIG_MSG_SET_POSITION, sp, 8), RIG_OK);
    rig_msg_telemetry t = ticks(1);
    CHECK_EQ(t.steps, 5000);
    CHECK_EQ(t.enc, 700);
    CHECK(t.flags & RIG_TF_REFERENCED);
    CHECK(!(t.flags & RIG_TF_MOVING)); /* a new reference is no move */
    CHECK_EQ(simple(RIG_MSG_BYE), RIG_OK);
    CHECK_EQ(M.state, RIG_STATE_BOOT);
    CHECK_EQ(state_of(0).reason, RIG_REASON_COMMAND);
    CHECK_EQ(simple(RIG_MSG_BYE), RIG_NO_SESSION);
    /* link lost while running: controlled stop, LINK_LOST, session ended */
    session();
    int32_t pts[10] = {10, 20, 30, 40, 50, 60, 70, 80, 90, 100};
    CHECK_EQ(chunk(0, 0, pts, 10), RIG_OK);
    CHECK_EQ(simple(RIG_MSG_START), RIG_OK);
    ticks(3);
    rig_link_lost(&M);
    drain();
    CHECK_EQ(state_of(0).reason, RIG_REASON_LINK_LOST);
    silent_ticks(1); /* the session ended: the stop goes on, without telemetry */
    CHECK_EQ(M.steps, 30 + 5);
    silent_ticks(2);
    CHECK_EQ(M.state, RIG_STATE_IDLE);
}

/* The CALIBRATION reply among the drained frames. */
static rig_msg_calibration calibration_reply(void) {
    rig_msg_calibration c;
    memset(&c, 0, sizeof c);
    size_t found = 0;
    for (size_t i = 0; i < nout; i++) {
        if (out[i].type == RIG_MSG_CALIBRATION) {
            CHECK(rig_wire_get_calibration(out[i].payload, out[i].len, &c));
            found++;
        }
    }
    CHECK_EQ(found, 1);
    return c;
}

static float f32_inf(void) {
    uint32_t bits = 0x7F800000u;
    float f;
    memcpy(&f, &bits, sizeof f);
    return f;
}

static int store_cal(int32_t offset, float gain) {
    uint8_t p[RIG_LEN_STORE_CALIBRATION];
    rig_msg_store_calibration s = {offset, gain};
    rig_wire_put_store_calibration(p, &s);
    return cmd(RIG_MSG_STORE_CALIBRATION, p, sizeof p);
}

/* 1.3: STORE_CALIBRATION writes record seq + 1 through hal_nvm_store and puts it in use;
 * refusals (state, values, a write that does not verify) keep the previous record. */
void test_store_and_read_calibration(void) {
    CHECK_EQ(store_cal(100, 1e-4f), RIG_NO_SESSION); /* BOOT: no session */
    session();
    CHECK_EQ(simple(RIG_MSG_READ_CALIBRATION), RIG_OK);
    rig_msg_calibration c = calibration_reply();
    CHECK_EQ(c.cal_seq, 0);
    CHECK_EQ(c.load_offset, 1500);
    CHECK_EQ(store_cal(-20000, 1.25e-4f), RIG_OK);
    c = calibration_reply();
    CHECK_EQ(c.cal_seq, 1);
    CHECK_EQ(c.load_offset, -20000);
    CHECK(c.load_gain_n == 1.25e-4f);
    CHECK_EQ(fake.nvm_writes, 1);
    CHECK_EQ(fake.nvm.seq, 1);
    CHECK_EQ(M.cfg.load_offset, -20000); /* in use at once */
    CHECK_EQ(store_cal(0, 0.0f), RIG_BAD_VALUE);
    CHECK_EQ(store_cal(0, -1e-4f), RIG_BAD_VALUE);
    CHECK_EQ(store_cal((int32_t)RIG_ADC_MAX, 1e-4f), RIG_BAD_VALUE);
    CHECK_EQ(store_cal(0, f32_inf()), RIG_BAD_VALUE);
    fake.nvm_fail = true;
    CHECK_EQ(store_cal(7, 1e-4f), RIG_NVM_ERROR);
    c = calibration_reply();
    CHECK_EQ(c.cal_seq, 1); /* the previous record stays */
    CHECK_EQ(M.cfg.load_offset, -20000);
    fake.nvm_fail = false;
    CHECK_EQ(fake.nvm_writes, 2); /* the refused values never reached the NVM */
    /* a retransmission is answered again, not written again */
    uint8_t p[RIG_LEN_STORE_CALIBRATION];
    rig_msg_store_calibration s = {42, 2e-4f};
    rig_wire_put_store_calibration(p, &s);
    send_raw(RIG_MSG_STORE_CALIBRATION, RIG_FLAG_ACK_REQ, ++host_seq, p, sizeof p);
    drain();
    send_raw(RIG_MSG_STORE_CALIBRATION, RIG_FLAG_ACK_REQ | RIG_FLAG_RETRY, host_seq, p,
             sizeof p);
    drain();
    CHECK_EQ(calibration_reply().cal_seq, 2);
    CHECK_EQ(fake.nvm_writes, 3);
    /* not while running */
    int32_t steps[2] = {10, 20};
    CHECK_EQ(chunk(0, RIG_CHUNK_FINAL, steps, 2), RIG_OK);
    CHECK_EQ(simple(RIG_MSG_START), RIG_OK);
    CHECK_EQ(store_cal(5, 1e-4f), RIG_BAD_STATE);
    CHECK_EQ(simple(RIG_MSG_READ_CALIBRATION), RIG_OK); /* reading is allowed */
}
