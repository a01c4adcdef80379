/* Little-endian packing of the rig protocol's message layouts (docs/rig-protocol.md
 * sections 4-5), byte by byte: the layouts are packed and several fields are unaligned
 * (HELLO_REPLY has a u16 at offset 29), so no C struct is ever overlaid on wire bytes.
 *
 * Readers take the payload length and return false when it is shorter than the layout
 * (bytes beyond it are ignored: the extension rule of section 2); writers return the
 * number of bytes written into a buffer of at least the layout's size.
 */
#ifndef RIG_WIRE_H
#define RIG_WIRE_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

/* payload sizes */
#define RIG_LEN_HELLO 6u
#define RIG_LEN_HEARTBEAT 4u
#define RIG_LEN_CONFIG 42u
#define RIG_LEN_CHUNK_HEAD 6u
#define RIG_LEN_POINT 8u
#define RIG_LEN_SET_POSITION 8u
#define RIG_LEN_STORE_CALIBRATION 8u /* 1.3 */
#define RIG_LEN_CALIBRATION 24u      /* 1.3: the reply */
#define RIG_LEN_ACK 12u
#define RIG_LEN_HELLO_REPLY 57u
#define RIG_LEN_HELLO_REPLY_1_2 55u /* without max_step_delta_limit */
#define RIG_LEN_TELEMETRY 34u
#define RIG_LEN_FAULT 15u
#define RIG_LEN_STATE 11u

/* scalar access, little-endian, any alignment */
void rig_put_u16(uint8_t *p, uint16_t v);
void rig_put_u32(uint8_t *p, uint32_t v);
void rig_put_i32(uint8_t *p, int32_t v);
void rig_put_f32(uint8_t *p, float v);
uint16_t rig_get_u16(const uint8_t *p);
uint32_t rig_get_u32(const uint8_t *p);
int32_t rig_get_i32(const uint8_t *p);
float rig_get_f32(const uint8_t *p);

/* ---- host -> MCU ---- */
typedef struct {
    uint8_t proto_major, proto_minor;
    uint32_t host_nonce;
} rig_msg_hello;

typedef struct {
    float force_limit_n;
    int32_t steps_min, steps_max, enc_min, enc_max, following_error_counts, load_offset;
    float load_gain_n, decel_steps_s2;
    uint16_t max_step_delta, heartbeat_timeout_ms, stuck_samples;
} rig_msg_config;

typedef struct {
    uint32_t first_index;
    uint8_t flags, n;
} rig_msg_chunk_head;

typedef struct {
    int32_t steps, enc;
} rig_msg_set_position;

bool rig_wire_get_hello(const uint8_t *p, size_t len, rig_msg_hello *out);
bool rig_wire_get_config(const uint8_t *p, size_t len, rig_msg_config *out);
/* The chunk's head only: the caller checks n (1..30) and len >= 6 + 8n. */
bool rig_wire_get_chunk_head(const uint8_t *p, size_t len, rig_msg_chunk_head *out);
/* Point k of a chunk whose length was checked. */
void rig_wire_get_point(const uint8_t *payload, unsigned k, int32_t *steps, int32_t *enc);
bool rig_wire_get_set_position(const uint8_t *p, size_t len, rig_msg_set_position *out);

/* 1.3: STORE_CALIBRATION's payload (load_offset i32, load_gain_n f32) */
typedef struct {
    int32_t load_offset;
    float load_gain_n;
} rig_msg_store_calibration;

bool rig_wire_get_store_calibration(const uint8_t *p, size_t len,
                                    rig_msg_store_calibration *out);
size_t rig_wire_put_store_calibration(uint8_t *p, const rig_msg_store_calibration *m);

/* writers used by tests and the fuzzer to build host frames */
size_t rig_wire_put_hello(uint8_t *p, const rig_msg_hello *m);
size_t rig_wire_put_config(uint8_t *p, const rig_msg_config *m);

/* ---- MCU -> host ---- */
typedef struct {
    uint16_t acked_seq;
    uint8_t result, state;
    uint32_t sample;
    uint16_t buf_level, buf_free;
} rig_msg_ack;

typedef struct {
    rig_msg_ack ack;
    uint8_t proto_major, proto_minor;
    uint16_t fw_version;
    uint32_t boot_id, host_nonce;
    uint16_t telemetry_hz, point_period_us;
    uint8_t max_chunk_points;
    uint16_t buffer_capacity;
    uint32_t step_nm, enc_nm;
    int32_t load_offset;
    float load_gain_n;
    int32_t adc_min, adc_max;
    uint16_t max_step_delta_limit; /* 1.3; 65535 from a 1.2 MCU (no stated limit) */
} rig_msg_hello_reply;

typedef struct {
    uint32_t boot_id, sample, t_us;
    int32_t steps, enc, load_raw;
    uint32_t exec_index;
    uint16_t buf_level, faults;
    uint8_t state, flags;
} rig_msg_telemetry;

typedef struct {
    uint16_t fault;
    uint32_t sample;
    uint8_t state;
    int32_t value, limit;
} rig_msg_fault;

typedef struct {
    uint8_t old_state, new_state, reason;
    uint32_t exec_index, sample;
} rig_msg_state;

/* 1.3: CALIBRATION, the answer to STORE_CALIBRATION and READ_CALIBRATION */
typedef struct {
    rig_msg_ack ack;
    uint32_t cal_seq;
    int32_t load_offset;
    float load_gain_n;
} rig_msg_calibration;

size_t rig_wire_put_calibration(uint8_t *p, const rig_msg_calibration *m);
bool rig_wire_get_calibration(const uint8_t *p, size_t len, rig_msg_calibration *out);

size_t rig_wire_put_ack(uint8_t *p, const rig_msg_ack *m);
size_t rig_wire_put_hello_reply(uint8_t *p, const rig_msg_hello_reply *m);
size_t rig_wire_put_telemetry(uint8_t *p, const rig_msg_telemetry *m);
size_t rig_wire_put_fault(uint8_t *p, const rig_msg_fault *m);
size_t rig_wire_put_state(uint8_t *p, const rig_msg_state *m);

bool rig_wire_get_ack(const uint8_t *p, size_t len, rig_msg_ack *out);
bool rig_wire_get_hello_reply(const uint8_t *p, size_t len, rig_msg_hello_reply *out);
bool rig_wire_get_telemetry(const uint8_t *p, size_t len, rig_msg_telemetry *out);
bool rig_wire_get_fault(const uint8_t *p, size_t len, rig_msg_fault *out);
bool rig_wire_get_state(const uint8_t *p, size_t len, rig_msg_state *out);

#endif
