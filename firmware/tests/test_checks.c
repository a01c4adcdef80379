/* The core's unit tests (core_test.h): the checks of section 8, ESTOP, the driver and the
 * board's faults. */
#include "core_test.h"

/* ---- checks of section 8 ----------------------------------------------------------------- */

void test_load_stuck_at_exactly_stuck_samples(void) {
    session();
    rig_msg_config c = default_cfg();
    c.stuck_samples = 5;
    CHECK_EQ(config(&c), RIG_OK);
    int32_t pts[20] = {0};
    CHECK_EQ(chunk(0, 0, pts, 20), RIG_OK);
    fake.load_stuck = true;
    ticks(3); /* identical in IDLE: not checked there */
    CHECK_EQ(simple(RIG_MSG_START), RIG_OK);
    for (int i = 1; i <= 4; i++) {
        rig_msg_telemetry t = ticks(1);
        CHECK_EQ(t.state, RIG_STATE_RUNNING);
        CHECK_EQ(count_type(RIG_MSG_FAULT), 0);
    }
    rig_msg_telemetry t = ticks(1);
    CHECK_EQ(t.state, RIG_STATE_FAULT);
    rig_msg_fault f = fault_of(0);
    CHECK_EQ(f.fault, RIG_F_LOAD_STUCK);
    CHECK_EQ(f.value, 5);
    CHECK_EQ(f.limit, 5);
    CHECK_EQ(t.faults, RIG_F_LOAD_STUCK);
    CHECK_EQ(t.buf_level, 0);
    CHECK(!(t.flags & RIG_TF_FINAL_RECEIVED));
    CHECK(fake.halts >= 1);
}

void test_travel_limit_lower_bound(void) {
    session();
    uint8_t p[8];
    rig_put_i32(p, -50001);
    rig_put_i32(p + 4, 0);
    CHECK_EQ(cmd(RIG_MSG_SET_POSITION, p, 8), RIG_OK);
    rig_msg_telemetry t = ticks(1);
    CHECK_EQ(t.steps, -50001);
    CHECK_EQ(t.state, RIG_STATE_FAULT);
    CHECK(t.flags & RIG_TF_REFERENCED);
    rig_msg_fault f = fault_of(0);
    CHECK_EQ(f.fault, RIG_F_TRAVEL_LIMIT);
    CHECK_EQ(f.value, -50001);
    CHECK_EQ(f.limit, -50000);
    CHECK_EQ(f.state, RIG_STATE_IDLE);
    /* CLEAR_FAULT refused while the condition holds */
    CHECK_EQ(simple(RIG_MSG_CLEAR_FAULT), RIG_FAULT_ACTIVE);
    CHECK_EQ(M.state, RIG_STATE_FAULT);
    /* the platen's lower bound, steps inside */
    session();
    fake.enc_base -= 20001;
    t = ticks(1);
    CHECK_EQ(t.enc, -20001);
    f = fault_of(0);
    CHECK_EQ(f.fault, RIG_F_TRAVEL_LIMIT);
    CHECK_EQ(f.value, -20001);
    CHECK_EQ(f.limit, -20000);
    fake.enc_base += 20001;
    ticks(1);
    CHECK_EQ(simple(RIG_MSG_CLEAR_FAULT), RIG_OK);
    CHECK_EQ(M.state, RIG_STATE_IDLE);
    CHECK_EQ(M.faults, 0);
}

void test_rail_latches_saturated_and_force(void) {
    session();
    fake.load_base = 8388607;
    fake.load_stuck = true;
    rig_msg_telemetry t = ticks(1);
    CHECK_EQ(nout, 4); /* FAULT, FAULT, STATE, TELEMETRY */
    CHECK_EQ(out[0].type, RIG_MSG_FAULT);
    CHECK_EQ(out[1].type, RIG_MSG_FAULT);
    CHECK_EQ(out[2].type, RIG_MSG_STATE);
    rig_msg_fault f0 = fault_of(0), f1 = fault_of(1);
    CHECK_EQ(f0.fault, RIG_F_FORCE_LIMIT);
    CHECK_EQ(f0.value, 839); /* (8388607 - 1500) * 1e-4 = 838.71 N */
    CHECK_EQ(f0.limit, 400);
    CHECK_EQ(f0.state, RIG_STATE_IDLE);
    CHECK_EQ(f1.fault, RIG_F_LOAD_SATURATED);
    CHECK_EQ(f1.value, 8388607);
    CHECK_EQ(f1.limit, 8388607);
    CHECK_EQ(f1.state, RIG_STATE_IDLE);
    CHECK_EQ(t.faults, RIG_F_FORCE_LIMIT | RIG_F_LOAD_SATURATED);
    CHECK_EQ(t.state, RIG_STATE_FAULT);
    CHECK(t.flags & RIG_TF_LOAD_SATURATED);
    /* latched bits send nothing more */
    ticks(1);
    CHECK_EQ(nout, 1);
    /* the lower rail: value the reading, limit adc_max */
    session();
    fake.load_base = -8388608;
    fake.load_stuck = true;
    ticks(1);
    CHECK_EQ(fault_of(0).value, -839);
    CHECK_EQ(fault_of(1).value, -8388608);
    CHECK_EQ(fault_of(1).limit, 8388607);
}

void test_force_limit_and_following_error(void) {
    session();
    fake.load_base = 1500 + 4000001; /* 400.0001 N (+1 count of noise) */
    ticks(1);
    CHECK_EQ(fault_of(0).fault, RIG_F_FORCE_LIMIT);
    CHECK_EQ(fault_of(0).value, 400);
    session();
    uint8_t sp[8];
    rig_put_i32(sp, 0);
    rig_put_i32(sp + 4, 0);
    CHECK_EQ(cmd(RIG_MSG_SET_POSITION, sp, 8), RIG_OK);
    int32_t steps[3] = {100, 200, 300}, enc[3] = {0, RIG_NO_CHECK, 1301};
    uint8_t c[64];
    size_t len = chunk_payload(c, 0, 0, steps, enc, 3);
    CHECK_EQ(cmd(RIG_MSG_TRAJ_CHUNK, c, len), RIG_OK);
    CHECK_EQ(simple(RIG_MSG_START), RIG_OK);
    ticks(2); /* enc stays 0: 0 vs 0, then not checked */
    rig_msg_telemetry t = ticks(1);
    CHECK_EQ(t.state, RIG_STATE_FAULT);
    CHECK_EQ(fault_of(0).fault, RIG_F_FOLLOWING_ERROR);
    CHECK_EQ(fault_of(0).value, -1301);
    CHECK_EQ(fault_of(0).limit, 1000);
    CHECK(!(t.flags & RIG_TF_REFERENCED)); /* dropped by FOLLOWING_ERROR */
}

void test_heartbeat_loss_at_rest(void) {
    session(); /* HELLO between tick 0 (t 0) and tick 1: last_rx_us = 0 */
    for (int i = 1; i <= 250; i++) {
        rig_msg_telemetry t = ticks(1);
        CHECK_EQ(t.state, RIG_STATE_IDLE);
    }
    rig_msg_telemetry t = ticks(1); /* t_us 251000: silence 251 ms > 250 */
    CHECK_EQ(t.state, RIG_STATE_FAULT);
    CHECK_EQ(t.faults, RIG_F_HEARTBEAT_LOST);
    rig_msg_fault f = fault_of(0);
    CHECK_EQ(f.value, 251);
    CHECK_EQ(f.limit, 250);
    CHECK_EQ(f.state, RIG_STATE_IDLE);
    CHECK_EQ(state_of(0).reason, RIG_REASON_FAULT);
    CHECK(t.flags & RIG_TF_SESSION); /* the session stays open */
    /* a heartbeat does not clear it; CLEAR_FAULT does */
    uint8_t hb[4] = {0};
    send_raw(RIG_MSG_HEARTBEAT, 0, ++host_seq, hb, 4);
    CHECK_EQ(simple(RIG_MSG_CLEAR_FAULT), RIG_OK);
    t = ticks(1);
    CHECK_EQ(t.state, RIG_STATE_IDLE);
    /* heartbeats keep it alive */
    for (int i = 0; i < 1000; i++) {
        if (i % 20 == 0) send_raw(RIG_MSG_HEARTBEAT, 0, ++host_seq, hb, 4);
        t = ticks(1);
    }
    CHECK_EQ(t.state, RIG_STATE_IDLE);
    /* BYE disarms it */
    CHECK_EQ(simple(RIG_MSG_BYE), RIG_OK);
    silent_ticks(600);
    CHECK_EQ(M.state, RIG_STATE_BOOT);
    CHECK_EQ(M.faults, 0);
}

void test_heartbeat_loss_running(void) {
    session();
    rig_msg_config c = default_cfg();
    c.heartbeat_timeout_ms = 10;
    CHECK_EQ(config(&c), RIG_OK);
    int32_t pts[30];
    for (int i = 0; i < 30; i++) pts[i] = 20 * (i + 1);
    CHECK_EQ(chunk(0, 0, pts, 30), RIG_OK);
    CHECK_EQ(simple(RIG_MSG_START), RIG_OK);
    rig_msg_telemetry t;
    int i = 0;
    do {
        t = ticks(1);
        i++;
    } while (t.state == RIG_STATE_RUNNING && i < 50);
    CHECK_EQ(t.state, RIG_STATE_STOPPING);
    CHECK_EQ(fault_of(0).fault, RIG_F_HEARTBEAT_LOST);
    CHECK_EQ(fault_of(0).value, 11);
    CHECK_EQ(fault_of(0).limit, 10);
    do {
        t = ticks(1);
        i++;
    } while (t.state == RIG_STATE_STOPPING && i < 100);
    CHECK_EQ(t.state, RIG_STATE_FAULT);
}

void test_estop_and_driver(void) {
    session();
    int32_t pts[10] = {10, 20, 30, 40, 50, 60, 70, 80, 90, 100};
    CHECK_EQ(chunk(0, 0, pts, 10), RIG_OK);
    CHECK_EQ(simple(RIG_MSG_START), RIG_OK);
    ticks(2);
    CHECK(fake.driver_on);
    fake.halt_return = 3; /* 3 pulses of the period not emitted */
    CHECK_EQ(simple(RIG_MSG_ESTOP), RIG_OK);
    CHECK_EQ(nout, 3); /* ACK, FAULT, STATE */
    CHECK_EQ(out[0].type, RIG_MSG_ACK);
    CHECK_EQ(out[1].type, RIG_MSG_FAULT);
    CHECK_EQ(out[2].type, RIG_MSG_STATE);
    CHECK_EQ(fault_of(0).value, 0);
    rig_msg_telemetry t = ticks(1);
    CHECK_EQ(t.state, RIG_STATE_ESTOP);
    CHECK_EQ(t.steps, 17); /* the count actually output */
    CHECK_EQ(fake.hw_steps, 17);
    CHECK(!fake.driver_on);
    CHECK(!(t.flags & RIG_TF_DRIVER_ENABLED));
    CHECK_EQ(simple(RIG_MSG_CLEAR_FAULT), RIG_OK);
    CHECK(!fake.driver_on); /* stays off until the next START */
    /* the stop input: ESTOP in any state, FAULT frame once */
    fake.stop_input = true;
    ticks(1);
    CHECK_EQ(M.state, RIG_STATE_ESTOP);
    CHECK_EQ(count_type(RIG_MSG_FAULT), 1);
    ticks(1);
    CHECK_EQ(count_type(RIG_MSG_FAULT), 0);
    fake.stop_input = false;
    CHECK_EQ(simple(RIG_MSG_CLEAR_FAULT), RIG_OK);
    /* driver alarm: DRIVER, halt */
    fake.driver_alarm = true;
    t = ticks(1);
    CHECK_EQ(t.state, RIG_STATE_FAULT);
    CHECK_EQ(t.faults, RIG_F_DRIVER);
}

/* The board's faults take the enable low at the tick that latched them (stop category 0);
 * FORCE_LIMIT halts holding position, the driver energised (docs/rig-protocol-behaviour.md 8). */
void test_board_faults_de_energise_and_limits_hold(void) {
    static const uint16_t board[5] = {RIG_F_INTERNAL, RIG_F_OVERTRAVEL, RIG_F_LOAD_ADC,
                                      RIG_F_CLOCK, RIG_F_STOP_CHAIN};
    int32_t pts[10] = {10, 20, 30, 40, 50, 60, 70, 80, 90, 100};
    for (unsigned i = 0; i < 5u; i++) {
        session();
        CHECK_EQ(chunk(0, 0, pts, 10), RIG_OK);
        CHECK_EQ(simple(RIG_MSG_START), RIG_OK);
        ticks(2);
        CHECK(fake.driver_on);
        fake.board_faults = board[i];
        rig_msg_telemetry t = ticks(1);
        CHECK_EQ(t.state, RIG_STATE_FAULT);
        CHECK_EQ(t.faults, board[i]);
        CHECK(!fake.driver_on);
        CHECK(!(t.flags & RIG_TF_DRIVER_ENABLED));
        fake.board_faults = 0;
    }
    session();
    CHECK_EQ(chunk(0, 0, pts, 10), RIG_OK);
    CHECK_EQ(simple(RIG_MSG_START), RIG_OK);
    ticks(2);
    fake.load_base = 1500 + 4000001; /* 400.0001 N */
    rig_msg_telemetry t = ticks(1);
    CHECK_EQ(t.faults, RIG_F_FORCE_LIMIT);
    CHECK(fake.driver_on); /* holding */
    CHECK(t.flags & RIG_TF_DRIVER_ENABLED);
}

/* START enables the driver; the run's first point waits until its power is confirmed
 * (hal_driver_powered): no step into an open stop chain, the board names it. */
void test_the_first_point_waits_for_the_drivers_power(void) {
    session();
    int32_t pts[3] = {10, 20, 30};
    CHECK_EQ(chunk(0, 0, pts, 3), RIG_OK);
    fake.chain_open = true;
    CHECK_EQ(simple(RIG_MSG_START), RIG_OK);
    rig_msg_telemetry t = ticks(5);
    CHECK(fake.driver_on);
    CHECK_EQ(t.state, RIG_STATE_RUNNING);
    CHECK_EQ(t.exec_index, 0);
    CHECK_EQ(fake.hw_steps, 0);
    fake.board_faults = RIG_F_STOP_CHAIN; /* the board's 20 ticks */
    t = ticks(1);
    CHECK_EQ(t.state, RIG_STATE_FAULT);
    CHECK_EQ(fake.hw_steps, 0);
    CHECK(!fake.driver_on);
    fake.board_faults = 0;
    fake.chain_open = false;
    /* powered at once: the first point in the START tick, as before */
    session();
    CHECK_EQ(chunk(0, 0, pts, 3), RIG_OK);
    CHECK_EQ(simple(RIG_MSG_START), RIG_OK);
    t = ticks(1);
    CHECK_EQ(t.exec_index, 1);
    CHECK_EQ(t.steps, 10);
}
