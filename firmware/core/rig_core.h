/* The rig firmware's portable core: docs/rig-protocol.md (version 1.1) in C11, with no
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

#include "rig_hal.h"

#define RIG_PROTO_MAJOR 1u
#define RIG_PROTO_MINOR 1u
#define RIG_FW_VERSION 0x0101u
#define RIG_TELEMETRY_HZ 1000u
#define RIG_POINT_PERIOD_US 1000u
#define RIG_MAX_CHUNK_POINTS 30u
#define RIG_BUFFER_CAPACITY 2048u /* trajectory points (16 KiB) */
#define RIG_STEP_NM 200u
#define RIG_ENC_NM 1000u
#define RIG_ADC_MIN (-8388608L)
#define RIG_ADC_MAX 8388607L
#define RIG_MAX_PAYLOAD 250u
#define RIG_MAX_ENCODED 258u      /* COBS of the largest body, without the delimiter */
#define RIG_TX_FIFO_BYTES 4096u   /* power of two */
#define RIG_NO_CHECK INT32_MIN    /* enc_expected: do not check the following error */

/* The load-cell calibration stored in non-volatile memory (protocol section 3). */
typedef struct {
    int32_t load_offset; /* ADC counts at zero force */
    float load_gain_n;   /* N per ADC count */
} rig_calibration;

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
    uint32_t frames_ok, frames_bad, rx_overflows, tx_dropped;
} rig_stats;

/* The whole MCU. Fields are the core's; boards read them only through the functions below
 * (tests may read them). */
typedef struct {
    /* receiver */
    uint8_t rx_buf[RIG_MAX_ENCODED];
    uint16_t rx_len;
    uint8_t rx_overflow;
    /* transmitter: a FIFO of whole frames */
    uint8_t tx_fifo[RIG_TX_FIFO_BYTES];
    uint32_t tx_head, tx_tail;
    uint16_t tx_seq;
    /* session, state, faults */
    uint32_t boot_id;
    uint8_t state, session, referenced, driver_enabled;
    uint16_t faults;
    rig_calibration stored;
    rig_config cfg;
    int32_t last_seq; /* -1: none */
    uint8_t last_reply[12 + 43];
    uint8_t last_reply_len, last_reply_type;
    /* time */
    uint32_t sample, t_us, last_rx_us;
    uint8_t rx_since_tick;
    /* counts: core = hardware + offset */
    int32_t steps, enc, load_raw, prev_load_raw;
    int32_t steps_offset, enc_offset;
    int32_t hw_steps;
    uint8_t home_switch, moving;
    uint16_t same_load;
    /* trajectory ring */
    rig_point points[RIG_BUFFER_CAPACITY];
    uint32_t pt_head, pt_count;
    uint32_t next_index, exec_index;
    uint8_t final_received, accepting;
    int32_t expected_enc;
    /* controlled stop, Q16 fixed point (1/65536 step) */
    int64_t stop_pos_q16;
    int32_t stop_speed_q16; /* signed steps per period << 16 */
    int32_t last_delta;
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

#endif
