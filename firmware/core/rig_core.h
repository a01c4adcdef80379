/* The rig firmware's portable core: docs/rig-protocol.md (version 1.3) in C11, with no
 * hardware access (that is rig_hal.h) and no heap: the whole MCU is one rig_mcu that the
 * board allocates statically.
 *
 * A board does three things:
 *   - feeds every received serial byte to rig_rx() (from its main loop, never from an
 *     interrupt that can preempt rig_tick());
 *   - calls rig_tick() once per period (1 kHz), with the scheduled time of the period's
 *     sensor reading in us since boot;
 *   - sends what rig_tx_take() hands it (a transmit FIFO: one period can queue more than
 *     a millisecond of a 921 600-baud UART carries, docs/firmware.md).
 */
#ifndef RIG_CORE_H
#define RIG_CORE_H

#include <stddef.h>
#include <stdint.h>

#include "rig_frame.h"
#include "rig_hal.h"

#define RIG_PROTO_MAJOR 1u
#define RIG_PROTO_MINOR 3u
#define RIG_FW_VERSION 0x0103u
#define RIG_TELEMETRY_HZ 1000u
#define RIG_POINT_PERIOD_US 1000u
#define RIG_MAX_CHUNK_POINTS 30u
#define RIG_BUFFER_CAPACITY 2048u /* trajectory points (16 KiB) */
#define RIG_STEP_NM 200u
#define RIG_ENC_NM 1000u
/* The most steps a board emits in one period (the NUCLEO's TIM1 burst: 256 pulses at 4 us):
 * CONFIG refuses a larger max_step_delta and HELLO_REPLY states it (1.3). */
#define RIG_MAX_STEP_DELTA 256u
#define RIG_ADC_MIN (-8388608L)
#define RIG_ADC_MAX 8388607L
#define RIG_MAX_PAYLOAD 250u
#define RIG_MAX_ENCODED 258u      /* COBS of the largest body, without the delimiter */
#define RIG_TX_FIFO_BYTES 4096u   /* power of two */
#define RIG_NO_CHECK INT32_MIN    /* enc_expected: do not check the following error */
#define RIG_MAX_REPLY 57u         /* HELLO_REPLY, the longest reply (RIG_LEN_HELLO_REPLY) */

/* The session's limits (CONFIG, protocol section 5). */
typedef struct {
    float force_limit_n;
    int32_t steps_min, steps_max, enc_min, enc_max;
    int32_t following_error_counts;
    int32_t load_offset;
    float load_gain_n;
    float decel_steps_s2;
    uint16_t max_step_delta, heartbeat_timeout_ms, stuck_samples;
} rig_config;

typedef struct {
    int32_t steps, enc_expected;
} rig_point;

/* Counters a board or a test may read; the core never resets them except at boot. */
typedef struct {
    uint32_t frames_ok;   /* frames with a good CRC */
    uint32_t frames_bad;  /* invalid COBS, body < 6 or > 256 bytes, bad CRC: dropped */
    uint32_t rx_overflows; /* runs of more than 258 bytes without a delimiter: discarded */
    uint32_t tx_dropped;  /* frames that did not fit whole in the tx FIFO: dropped whole */
} rig_stats;

/* States (section 9), results (section 5, ACK), fault bits (section 8), STATE reasons,
 * telemetry flags, message types (section 4). */
enum {
    RIG_STATE_BOOT = 0, RIG_STATE_IDLE = 1, RIG_STATE_RUNNING = 2, RIG_STATE_STOPPING = 3,
    RIG_STATE_FAULT = 4, RIG_STATE_ESTOP = 5
};
enum {
    RIG_OK = 0, RIG_BAD_STATE = 1, RIG_BAD_LENGTH = 2, RIG_BAD_VALUE = 3, RIG_NO_SPACE = 4,
    RIG_SEQUENCE_GAP = 5, RIG_OUT_OF_LIMITS = 6, RIG_NO_SESSION = 7, RIG_UNKNOWN_TYPE = 8,
    RIG_VERSION_MISMATCH = 9, RIG_FAULT_ACTIVE = 10, RIG_EMPTY = 11, RIG_STALE = 12,
    RIG_NVM_ERROR = 13 /* 1.3: the calibration did not verify in non-volatile memory */
};
enum {
    RIG_F_FORCE_LIMIT = 0x0001, RIG_F_TRAVEL_LIMIT = 0x0002, RIG_F_FOLLOWING_ERROR = 0x0004,
    RIG_F_BUFFER_UNDERRUN = 0x0008, RIG_F_LOAD_SATURATED = 0x0010, RIG_F_LOAD_STUCK = 0x0020,
    RIG_F_HEARTBEAT_LOST = 0x0040, RIG_F_ESTOP = 0x0080, RIG_F_DRIVER = 0x0100,
    RIG_F_INTERNAL = 0x0200, RIG_F_OVERTRAVEL = 0x0400, RIG_F_LOAD_ADC = 0x0800,
    RIG_F_CLOCK = 0x1000, RIG_F_STOP_CHAIN = 0x2000
};
/* The faults only a board reports (rig_inputs.board_faults). */
#define RIG_BOARD_FAULTS                                                                   \
    (RIG_F_INTERNAL | RIG_F_OVERTRAVEL | RIG_F_LOAD_ADC | RIG_F_CLOCK | RIG_F_STOP_CHAIN)
enum {
    RIG_REASON_COMMAND = 0, RIG_REASON_RUN_COMPLETE = 1, RIG_REASON_FAULT = 2,
    RIG_REASON_STOP_COMPLETE = 3, RIG_REASON_LINK_LOST = 4
};
enum {
    RIG_TF_MOVING = 0x01, RIG_TF_FINAL_RECEIVED = 0x02, RIG_TF_LOAD_SATURATED = 0x04,
    RIG_TF_SESSION = 0x08, RIG_TF_DRIVER_ENABLED = 0x10, RIG_TF_HOME_SWITCH = 0x20,
    RIG_TF_REFERENCED = 0x40
};
enum {
    RIG_MSG_HELLO = 0x01, RIG_MSG_HEARTBEAT = 0x02, RIG_MSG_CONFIG = 0x03,
    RIG_MSG_TRAJ_CHUNK = 0x04, RIG_MSG_START = 0x05, RIG_MSG_STOP = 0x06,
    RIG_MSG_ESTOP = 0x07, RIG_MSG_CLEAR_FAULT = 0x08, RIG_MSG_SET_POSITION = 0x09,
    RIG_MSG_BYE = 0x0A, RIG_MSG_STORE_CALIBRATION = 0x0B, RIG_MSG_READ_CALIBRATION = 0x0C,
    RIG_MSG_ACK = 0x80, RIG_MSG_HELLO_REPLY = 0x81, RIG_MSG_TELEMETRY = 0x82,
    RIG_MSG_FAULT = 0x83, RIG_MSG_STATE = 0x84, RIG_MSG_CALIBRATION = 0x85
};
#define RIG_CHUNK_FINAL 0x01u

/* CONFIG's re-check of the buffered points (rule 7) reads a block only when its summary
 * says a point in it fails: at most RIG_BLOCK_POINTS points instead of the whole buffer. */
#define RIG_BLOCK_POINTS 64u
#define RIG_BLOCKS (RIG_BUFFER_CAPACITY / RIG_BLOCK_POINTS)

/* Summary of a block of buffered points: their least and greatest step count and the
 * largest |step change| from the point before (the block's first point of the buffer
 * excluded: its change is from the present position, read at CONFIG). */
typedef struct {
    int32_t min_steps, max_steps;
    uint32_t max_jump;
} rig_block;

#define RIG_EVENT_SLOTS 8u   /* FAULT/STATE frames a command may cause, sent after its reply */
#define RIG_EVENT_MAX 15u    /* largest event payload (FAULT) */

/* A FAULT or STATE frame held back until the reply of the command that caused it is sent
 * (the reply comes first, as in hil/emulators/mcu_model.py). */
typedef struct {
    uint8_t type, len;
    uint8_t payload[RIG_EVENT_MAX];
} rig_event;

/* The whole MCU. Fields are the core's; boards read them only through the functions below
 * (tests may read them; firmware/host reads boot_id, state, steps, enc, load_raw). */
typedef struct {
    /* receiver */
    rig_frame_rx rx;
    rig_frame frame; /* the frame being executed (kept here, not on a small MCU stack) */
    /* transmitter: a FIFO of whole frames, free-running indices */
    uint8_t tx_fifo[RIG_TX_FIFO_BYTES];
    uint32_t tx_head, tx_tail;
    uint16_t tx_seq;
    rig_event events[RIG_EVENT_SLOTS];
    uint8_t event_count, events_deferred;
    /* session, state, faults */
    uint32_t boot_id;
    uint8_t state, session, referenced;
    uint8_t driver_enabled, driver_applied; /* applied: what hal_driver_enable last got */
    uint8_t awaiting_power; /* START given, the driver's power not yet confirmed */
    uint16_t faults;
    rig_calibration stored;
    rig_config cfg;
    int64_t stop_dv_q16; /* stop deceleration per period, Q16 steps/period (from cfg) */
    uint8_t have_last_seq;
    uint16_t last_seq;
    uint8_t last_reply[RIG_MAX_REPLY];
    uint8_t last_reply_len, last_reply_type;
    /* time */
    uint32_t sample, t_us, last_rx_us;
    /* counts: steps = hw_steps + steps_offset, enc = hw_enc + enc_offset (mod 2^32) */
    int32_t steps, enc, load_raw;
    int32_t hw_steps, hw_enc;
    int32_t steps_offset, enc_offset;
    int32_t period_start_steps; /* steps before this period's motion: MOVING */
    uint8_t have_reading, home_switch, stop_input, driver_alarm;
    uint16_t board_faults; /* the board's faults of the last reading (present conditions) */
    uint8_t halt_pending; /* ESTOP from rig_rx: hal_step_halt at the next tick */
    uint32_t same_load;   /* consecutive samples with a bit-identical load_raw */
    /* trajectory ring */
    rig_point points[RIG_BUFFER_CAPACITY];
    uint32_t pt_head, pt_count;
    rig_block blocks[RIG_BLOCKS]; /* of slots 0..pt_count-1: valid in IDLE (rig_commands.c) */
    uint32_t next_index, exec_index;
    uint8_t final_received, accepting;
    int32_t expected_enc;
    /* controlled stop, Q16 fixed point (1/65536 step) */
    int64_t stop_pos_q16;
    int64_t vel_q16; /* signed steps per period << 16: the last period's move */
    uint8_t stop_target;
    rig_stats stats;
} rig_mcu;

/* Power-on or reset: a new boot_id (non-zero, from the board's entropy source, different
 * from the previous one), no session, counts at 0 at the present position, unreferenced,
 * defaults of CONFIG with the stored calibration. */
void rig_boot(rig_mcu *m, uint32_t boot_id, rig_calibration stored);

/* Bytes received from the host, in order; complete frames are executed at once and their
 * replies queued. */
void rig_rx(rig_mcu *m, const uint8_t *data, size_t n);

/* One period: heartbeat watchdog, motion (hal_step), inputs (hal_read), the checks of
 * section 8, telemetry. t_us: the period's scheduled time in us since boot. */
void rig_tick(rig_mcu *m, uint32_t t_us);

/* The host vanished (USB detach, DTR dropped): controlled stop, session ended. */
void rig_link_lost(rig_mcu *m);

/* Move up to max queued bytes (whole frames or parts of one) to out; returns how many. */
size_t rig_tx_take(rig_mcu *m, uint8_t *out, size_t max);

/* Bytes waiting in the transmit FIFO. */
size_t rig_tx_pending(const rig_mcu *m);

/* Q16 stop deceleration per period for a CONFIG's decel_steps_s2
 * (docs/rig-protocol-behaviour.md, section 8):
 * round(decel * 1e-6 * 65536), half to even as Python's round(), clamped to [0, 2^62]. */
int64_t rig_stop_dv_q16(float decel_steps_s2);

#endif
