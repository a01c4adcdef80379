/* Little-endian field access and the message layouts (rig_wire.h). Shifts are done on
 * unsigned values only; signed integers and floats cross to and from uint32_t by memcpy of
 * their bits (two's complement and IEEE-754 binary32 on every target of this firmware), so
 * no conversion is implementation-defined. */
#include "rig_wire.h"

#include <string.h>

void rig_put_u16(uint8_t *p, uint16_t v) {
    p[0] = (uint8_t)(v & 0xFFu);
    p[1] = (uint8_t)(v >> 8);
}

void rig_put_u32(uint8_t *p, uint32_t v) {
    p[0] = (uint8_t)(v & 0xFFu);
    p[1] = (uint8_t)((v >> 8) & 0xFFu);
    p[2] = (uint8_t)((v >> 16) & 0xFFu);
    p[3] = (uint8_t)(v >> 24);
}

void rig_put_i32(uint8_t *p, int32_t v) {
    uint32_t u;
    memcpy(&u, &v, sizeof u);
    rig_put_u32(p, u);
}

void rig_put_f32(uint8_t *p, float v) {
    uint32_t u;
    memcpy(&u, &v, sizeof u);
    rig_put_u32(p, u);
}

uint16_t rig_get_u16(const uint8_t *p) { return (uint16_t)(p[0] | (uint16_t)(p[1] << 8)); }

uint32_t rig_get_u32(const uint8_t *p) {
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) |
           ((uint32_t)p[3] << 24);
}

int32_t rig_get_i32(const uint8_t *p) {
    uint32_t u = rig_get_u32(p);
    int32_t v;
    memcpy(&v, &u, sizeof v);
    return v;
}

float rig_get_f32(const uint8_t *p) {
    uint32_t u = rig_get_u32(p);
    float v;
    memcpy(&v, &u, sizeof v);
    return v;
}

/* ---- host -> MCU ---- */

bool rig_wire_get_hello(const uint8_t *p, size_t len, rig_msg_hello *out) {
    if (len < RIG_LEN_HELLO) return false;
    out->proto_major = p[0];
    out->proto_minor = p[1];
    out->host_nonce = rig_get_u32(p + 2);
    return true;
}

size_t rig_wire_put_hello(uint8_t *p, const rig_msg_hello *m) {
    p[0] = m->proto_major;
    p[1] = m->proto_minor;
    rig_put_u32(p + 2, m->host_nonce);
    return RIG_LEN_HELLO;
}

bool rig_wire_get_config(const uint8_t *p, size_t len, rig_msg_config *out) {
    if (len < RIG_LEN_CONFIG) return false;
    out->force_limit_n = rig_get_f32(p + 0);
    out->steps_min = rig_get_i32(p + 4);
    out->steps_max = rig_get_i32(p + 8);
    out->enc_min = rig_get_i32(p + 12);
    out->enc_max = rig_get_i32(p + 16);
    out->following_error_counts = rig_get_i32(p + 20);
    out->load_offset = rig_get_i32(p + 24);
    out->load_gain_n = rig_get_f32(p + 28);
    out->decel_steps_s2 = rig_get_f32(p + 32);
    out->max_step_delta = rig_get_u16(p + 36);
    out->heartbeat_timeout_ms = rig_get_u16(p + 38);
    out->stuck_samples = rig_get_u16(p + 40);
    return true;
}

size_t rig_wire_put_config(uint8_t *p, const rig_msg_config *m) {
    rig_put_f32(p + 0, m->force_limit_n);
    rig_put_i32(p + 4, m->steps_min);
    rig_put_i32(p + 8, m->steps_max);
    rig_put_i32(p + 12, m->enc_min);
    rig_put_i32(p + 16, m->enc_max);
    rig_put_i32(p + 20, m->following_error_counts);
    rig_put_i32(p + 24, m->load_offset);
    rig_put_f32(p + 28, m->load_gain_n);
    rig_put_f32(p + 32, m->decel_steps_s2);
    rig_put_u16(p + 36, m->max_step_delta);
    rig_put_u16(p + 38, m->heartbeat_timeout_ms);
    rig_put_u16(p + 40, m->stuck_samples);
    return RIG_LEN_CONFIG;
}

bool rig_wire_get_chunk_head(const uint8_t *p, size_t len, rig_msg_chunk_head *out) {
    if (len < RIG_LEN_CHUNK_HEAD) return false;
    out->first_index = rig_get_u32(p);
    out->flags = p[4];
    out->n = p[5];
    return true;
}

void rig_wire_get_point(const uint8_t *payload, unsigned k, int32_t *steps, int32_t *enc) {
    const uint8_t *q = payload + RIG_LEN_CHUNK_HEAD + (size_t)k * RIG_LEN_POINT;
    *steps = rig_get_i32(q);
    *enc = rig_get_i32(q + 4);
}

bool rig_wire_get_set_position(const uint8_t *p, size_t len, rig_msg_set_position *out) {
    if (len < RIG_LEN_SET_POSITION) return false;
    out->steps = rig_get_i32(p);
    out->enc = rig_get_i32(p + 4);
    return true;
}

/* ---- MCU -> host ---- */

size_t rig_wire_put_ack(uint8_t *p, const rig_msg_ack *m) {
    rig_put_u16(p + 0, m->acked_seq);
    p[2] = m->result;
    p[3] = m->state;
    rig_put_u32(p + 4, m->sample);
    rig_put_u16(p + 8, m->buf_level);
    rig_put_u16(p + 10, m->buf_free);
    return RIG_LEN_ACK;
}

bool rig_wire_get_ack(const uint8_t *p, size_t len, rig_msg_ack *out) {
    if (len < RIG_LEN_ACK) return false;
    out->acked_seq = rig_get_u16(p + 0);
    out->result = p[2];
    out->state = p[3];
    out->sample = rig_get_u32(p + 4);
    out->buf_level = rig_get_u16(p + 8);
    out->buf_free = rig_get_u16(p + 10);
    return true;
}

size_t rig_wire_put_hello_reply(uint8_t *p, const rig_msg_hello_reply *m) {
    rig_wire_put_ack(p, &m->ack);
    p[12] = m->proto_major;
    p[13] = m->proto_minor;
    rig_put_u16(p + 14, m->fw_version);
    rig_put_u32(p + 16, m->boot_id);
    rig_put_u32(p + 20, m->host_nonce);
    rig_put_u16(p + 24, m->telemetry_hz);
    rig_put_u16(p + 26, m->point_period_us);
    p[28] = m->max_chunk_points;
    rig_put_u16(p + 29, m->buffer_capacity);
    rig_put_u32(p + 31, m->step_nm);
    rig_put_u32(p + 35, m->enc_nm);
    rig_put_i32(p + 39, m->load_offset);
    rig_put_f32(p + 43, m->load_gain_n);
    rig_put_i32(p + 47, m->adc_min);
    rig_put_i32(p + 51, m->adc_max);
    rig_put_u16(p + 55, m->max_step_delta_limit);
    return RIG_LEN_HELLO_REPLY;
}

bool rig_wire_get_hello_reply(const uint8_t *p, size_t len, rig_msg_hello_reply *out) {
    if (len < RIG_LEN_HELLO_REPLY_1_2) return false;
    rig_wire_get_ack(p, len, &out->ack);
    out->proto_major = p[12];
    out->proto_minor = p[13];
    out->fw_version = rig_get_u16(p + 14);
    out->boot_id = rig_get_u32(p + 16);
    out->host_nonce = rig_get_u32(p + 20);
    out->telemetry_hz = rig_get_u16(p + 24);
    out->point_period_us = rig_get_u16(p + 26);
    out->max_chunk_points = p[28];
    out->buffer_capacity = rig_get_u16(p + 29);
    out->step_nm = rig_get_u32(p + 31);
    out->enc_nm = rig_get_u32(p + 35);
    out->load_offset = rig_get_i32(p + 39);
    out->load_gain_n = rig_get_f32(p + 43);
    out->adc_min = rig_get_i32(p + 47);
    out->adc_max = rig_get_i32(p + 51);
    out->max_step_delta_limit =
        len >= RIG_LEN_HELLO_REPLY ? rig_get_u16(p + 55) : (uint16_t)0xFFFFu;
    return true;
}

size_t rig_wire_put_telemetry(uint8_t *p, const rig_msg_telemetry *m) {
    rig_put_u32(p + 0, m->boot_id);
    rig_put_u32(p + 4, m->sample);
    rig_put_u32(p + 8, m->t_us);
    rig_put_i32(p + 12, m->steps);
    rig_put_i32(p + 16, m->enc);
    rig_put_i32(p + 20, m->load_raw);
    rig_put_u32(p + 24, m->exec_index);
    rig_put_u16(p + 28, m->buf_level);
    rig_put_u16(p + 30, m->faults);
    p[32] = m->state;
    p[33] = m->flags;
    return RIG_LEN_TELEMETRY;
}

bool rig_wire_get_telemetry(const uint8_t *p, size_t len, rig_msg_telemetry *out) {
    if (len < RIG_LEN_TELEMETRY) return false;
    out->boot_id = rig_get_u32(p + 0);
    out->sample = rig_get_u32(p + 4);
    out->t_us = rig_get_u32(p + 8);
    out->steps = rig_get_i32(p + 12);
    out->enc = rig_get_i32(p + 16);
    out->load_raw = rig_get_i32(p + 20);
    out->exec_index = rig_get_u32(p + 24);
    out->buf_level = rig_get_u16(p + 28);
    out->faults = rig_get_u16(p + 30);
    out->state = p[32];
    out->flags = p[33];
    return true;
}

size_t rig_wire_put_fault(uint8_t *p, const rig_msg_fault *m) {
    rig_put_u16(p + 0, m->fault);
    rig_put_u32(p + 2, m->sample);
    p[6] = m->state;
    rig_put_i32(p + 7, m->value);
    rig_put_i32(p + 11, m->limit);
    return RIG_LEN_FAULT;
}

bool rig_wire_get_fault(const uint8_t *p, size_t len, rig_msg_fault *out) {
    if (len < RIG_LEN_FAULT) return false;
    out->fault = rig_get_u16(p + 0);
    out->sample = rig_get_u32(p + 2);
    out->state = p[6];
    out->value = rig_get_i32(p + 7);
    out->limit = rig_get_i32(p + 11);
    return true;
}

size_t rig_wire_put_state(uint8_t *p, const rig_msg_state *m) {
    p[0] = m->old_state;
    p[1] = m->new_state;
    p[2] = m->reason;
    rig_put_u32(p + 3, m->exec_index);
    rig_put_u32(p + 7, m->sample);
    return RIG_LEN_STATE;
}

bool rig_wire_get_state(const uint8_t *p, size_t len, rig_msg_state *out) {
    if (len < RIG_LEN_STATE) return false;
    out->old_state = p[0];
    out->new_state = p[1];
    out->reason = p[2];
    out->exec_index = rig_get_u32(p + 3);
    out->sample = rig_get_u32(p + 7);
    return true;
}

/* ---- 1.3: the stored calibration ---- */

bool rig_wire_get_store_calibration(const uint8_t *p, size_t len,
                                    rig_msg_store_calibration *out) {
    if (len < RIG_LEN_STORE_CALIBRATION) return false;
    out->load_offset = rig_get_i32(p);
    out->load_gain_n = rig_get_f32(p + 4);
    return true;
}

size_t rig_wire_put_store_calibration(uint8_t *p, const rig_msg_store_calibration *m) {
    rig_put_i32(p, m->load_offset);
    rig_put_f32(p + 4, m->load_gain_n);
    return RIG_LEN_STORE_CALIBRATION;
}

size_t rig_wire_put_calibration(uint8_t *p, const rig_msg_calibration *m) {
    rig_wire_put_ack(p, &m->ack);
    rig_put_u32(p + 12, m->cal_seq);
    rig_put_i32(p + 16, m->load_offset);
    rig_put_f32(p + 20, m->load_gain_n);
    return RIG_LEN_CALIBRATION;
}

bool rig_wire_get_calibration(const uint8_t *p, size_t len, rig_msg_calibration *out) {
    if (len < RIG_LEN_CALIBRATION) return false;
    rig_wire_get_ack(p, len, &out->ack);
    out->cal_seq = rig_get_u32(p + 12);
    out->load_offset = rig_get_i32(p + 16);
    out->load_gain_n = rig_get_f32(p + 20);
    return true;
}
