/* What the core's unit tests share (firmware/tests/, on the fake HAL): the CHECK macros,
 * the harness (core_test.c: an MCU booted on the fake HAL, commands sent as framed bytes, the
 * frames it sends decoded into `out`) and the test functions, one file per part of the
 * protocol:
 *
 *   test_frames.c    framing (section 2) and the worked examples of section 12
 *   test_seq.c       the seq rules of section 6
 *   test_motion.c    runs, TRAJ_CHUNK's rules, the controlled stop, underruns
 *   test_checks.c    the checks of section 8, ESTOP, the driver, the board's faults
 *   test_commands.c  CONFIG, telemetry and the tx FIFO, SET_POSITION, BYE, the calibration
 */
#ifndef CORE_TEST_H
#define CORE_TEST_H

#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include "fake_hal.h"
#include "rig_core.h"
#include "rig_frame.h"
#include "rig_wire.h"

extern int cur_failed; /* the running test failed a check */

#define CHECK(cond)                                                         \
    do {                                                                    \
        if (!(cond)) {                                                      \
            fprintf(stderr, "  %s:%d: CHECK(%s) failed\n", __FILE__, __LINE__, #cond); \
            cur_failed = 1;                                                 \
        }                                                                   \
    } while (0)

#define CHECK_EQ(a, b)                                                                 \
    do {                                                                               \
        long long a_ = (long long)(a), b_ = (long long)(b);                            \
        if (a_ != b_) {                                                                \
            fprintf(stderr, "  %s:%d: %s == %lld, expected %s == %lld\n", __FILE__, __LINE__, \
                    #a, a_, #b, b_);                                                   \
            cur_failed = 1;                                                            \
        }                                                                              \
    } while (0)

/* ---- harness (core_test.c) ------------------------------------------------------------- */

typedef struct {
    uint8_t type, flags;
    uint16_t seq;
    uint8_t payload[RIG_FRAME_MAX_PAYLOAD];
    size_t len;
    uint8_t wire[RIG_FRAME_MAX_WIRE];
    size_t wire_len;
} msg;

extern rig_mcu M;        /* the MCU under test */
extern msg out[1024];    /* the frames of the last drain() */
extern size_t nout;
extern uint16_t host_seq; /* the last seq cmd() sent */

void boot(void);
/* Take everything the MCU queued and decode it; every frame must be valid. */
size_t drain(void);
void tick(void);
/* n ticks, draining after each; returns the last telemetry. */
rig_msg_telemetry ticks(int n);
void send_raw(uint8_t type, uint8_t flags, uint16_t seq, const uint8_t *p, size_t n);
/* Send a command with ACK_REQ and a new seq; drain; return the ACK's result (-1: none). */
int cmd(uint8_t type, const uint8_t *p, size_t n);
rig_msg_ack ack_of(size_t i);
int hello(void);
rig_msg_config default_cfg(void);
int config(const rig_msg_config *c);
size_t chunk_payload(uint8_t *p, uint32_t first, uint8_t flags, const int32_t *steps,
                     const int32_t *enc, unsigned n);
int chunk(uint32_t first, uint8_t flags, const int32_t *steps, unsigned n);
int simple(uint8_t type);
size_t count_type(uint8_t type);
const msg *nth_of(uint8_t type, size_t nth);
rig_msg_fault fault_of(size_t nth);
rig_msg_state state_of(size_t nth);
/* n ticks without a session: no telemetry (docs/rig-protocol.md, section 5). */
void silent_ticks(int n);
void session(void);
void hexcmp(const uint8_t *got, size_t n_got, const uint8_t *want, size_t n_want);

/* ---- the tests --------------------------------------------------------------------------- */

/* test_frames.c */
void test_crc_check_value(void);
void test_example_hello_wire(void);
void test_example_ack(void);
void test_example_telemetry(void);
void test_cobs_long_runs(void);
void test_259_byte_frame_accepted(void);
void test_overflow_junk_and_bit_flips_dropped(void);
void test_unknown_and_short(void);
/* test_seq.c */
void test_seq_rules(void);
void test_no_reply_without_ack_req(void);
/* test_motion.c */
void test_run_of_n_points(void);
void test_chunk_rules(void);
void test_stop_ramp_q16(void);
void test_stop_at_standstill(void);
void test_underrun(void);
/* test_checks.c */
void test_load_stuck_at_exactly_stuck_samples(void);
void test_travel_limit_lower_bound(void);
void test_rail_latches_saturated_and_force(void);
void test_force_limit_and_following_error(void);
void test_heartbeat_loss_at_rest(void);
void test_heartbeat_loss_running(void);
void test_estop_and_driver(void);
void test_board_faults_de_energise_and_limits_hold(void);
void test_the_first_point_waits_for_the_drivers_power(void);
/* test_commands.c */
void test_config_rules(void);
void test_config_rechecks_buffered_points(void);
void test_telemetry_only_in_a_session_and_tx_fifo(void);
void test_set_position_and_bye(void);
void test_store_and_read_calibration(void);

#endif
