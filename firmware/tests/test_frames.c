/* The core's unit tests (core_test.h): framing (section 2) and the worked examples of section
 * 12, byte for byte. */
#include "core_test.h"

/* ---- framing --------------------------------------------------------------------------- */

void test_crc_check_value(void) {
    const uint8_t s[] = "123456789";
    CHECK_EQ(rig_crc16(0xFFFF, s, 9), 0x29B1);
    /* the table against the bitwise definition, every byte value after every start */
    for (unsigned b = 0; b < 256; b++) {
        uint32_t c = 0xFFFFu ^ (b << 8);
        for (int k = 0; k < 8; k++) c = ((c & 0x8000u) ? ((c << 1) ^ 0x1021u) : (c << 1)) & 0xFFFFu;
        uint8_t byte = (uint8_t)b;
        CHECK_EQ(rig_crc16(0xFFFF, &byte, 1), c);
    }
}

void test_example_hello_wire(void) {
    const uint8_t payload[] = {0x01, 0x00, 0x78, 0x56, 0x34, 0x12};
    const uint8_t want[] = {0x04, 0x01, 0x01, 0x01, 0x02, 0x01, 0x07, 0x78,
                            0x56, 0x34, 0x12, 0xd6, 0xb7, 0x00};
    const uint8_t body[] = {0x01, 0x01, 0x01, 0x00, 0x01, 0x00, 0x78, 0x56, 0x34, 0x12};
    uint8_t w[64];
    CHECK_EQ(rig_crc16(0xFFFF, body, sizeof body), 0xB7D6);
    size_t n = rig_frame_build(0x01, 0x01, 0x0001, payload, sizeof payload, w, sizeof w);
    hexcmp(w, n, want, sizeof want);
    /* and the MCU takes it: a HELLO_REPLY echoing the nonce */
    boot();
    rig_rx(&M, want, sizeof want);
    drain();
    CHECK_EQ(nout, 2); /* HELLO_REPLY, then STATE BOOT -> IDLE */
    CHECK_EQ(out[0].type, RIG_MSG_HELLO_REPLY);
    rig_msg_hello_reply hr;
    CHECK(rig_wire_get_hello_reply(out[0].payload, out[0].len, &hr));
    CHECK_EQ(hr.ack.acked_seq, 1);
    CHECK_EQ(hr.ack.result, RIG_OK);
    CHECK_EQ(hr.ack.state, RIG_STATE_IDLE);
    CHECK_EQ(hr.host_nonce, 0x12345678u);
    CHECK_EQ(hr.boot_id, 0x5EED0001u);
    CHECK_EQ(hr.buffer_capacity, 2048);
    CHECK_EQ(hr.max_chunk_points, 30);
    CHECK_EQ(hr.fw_version, RIG_FW_VERSION);
    CHECK_EQ(hr.load_offset, 1500);
    CHECK(hr.load_gain_n == 1e-4f);
    CHECK_EQ(hr.adc_min, -8388608);
    CHECK_EQ(hr.adc_max, 8388607);
    CHECK_EQ(out[0].len, RIG_LEN_HELLO_REPLY);
    CHECK_EQ(hr.max_step_delta_limit, RIG_MAX_STEP_DELTA);
    /* a 1.2 MCU's 55 bytes still parse, stating no limit */
    CHECK(rig_wire_get_hello_reply(out[0].payload, RIG_LEN_HELLO_REPLY_1_2, &hr));
    CHECK_EQ(hr.max_step_delta_limit, 0xFFFFu);
    CHECK_EQ(out[1].type, RIG_MSG_STATE);
    CHECK_EQ(out[0].flags, 0);
}

void test_example_ack(void) {
    const uint8_t body[] = {0x80, 0x00, 0x00, 0x00, 0x01, 0x00, 0x00, 0x01,
                            0x0c, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x08};
    const uint8_t want[] = {0x02, 0x80, 0x01, 0x01, 0x02, 0x01, 0x01, 0x03, 0x01, 0x0c,
                            0x01, 0x01, 0x01, 0x01, 0x01, 0x04, 0x08, 0x92, 0x1a, 0x00};
    CHECK_EQ(rig_crc16(0xFFFF, body, sizeof body), 0x1A92);
    /* through the core: HELLO (seq 0), 12 samples, then a command with seq 1 answered
     * with MCU seq 0 (the counter set back for the example) */
    boot();
    uint8_t p[RIG_LEN_HELLO];
    rig_msg_hello h = {1, 0, 0x12345678u};
    rig_wire_put_hello(p, &h);
    send_raw(RIG_MSG_HELLO, RIG_FLAG_ACK_REQ, 0x0000, p, sizeof p);
    for (int i = 0; i < 12; i++) tick();
    drain();
    CHECK_EQ(M.sample, 12);
    M.tx_seq = 0;
    send_raw(RIG_MSG_CLEAR_FAULT, RIG_FLAG_ACK_REQ, 0x0001, NULL, 0);
    drain();
    CHECK_EQ(nout, 1);
    hexcmp(out[0].wire, out[0].wire_len, want, sizeof want);
}

void test_example_telemetry(void) {
    const uint8_t want[] = {0x02, 0x82, 0x04, 0x03, 0x02, 0x01, 0x05, 0xed, 0x5e, 0xdc, 0x05,
                            0x01, 0x04, 0x5a, 0xe4, 0x16, 0x03, 0x30, 0x75, 0x01, 0x03, 0xe4,
                            0x2e, 0x01, 0x04, 0x9c, 0xda, 0x01, 0x03, 0xdb, 0x05, 0x01, 0x03,
                            0x24, 0x02, 0x01, 0x05, 0x02, 0x1b, 0x04, 0x07, 0x00};
    rig_msg_telemetry t = {0x5EED0001u, 1500, 1500250, 30000, 12004, 121500, 1499, 548, 0,
                           RIG_STATE_RUNNING, 0x1B};
    uint8_t p[RIG_LEN_TELEMETRY], w[64];
    CHECK_EQ(rig_wire_put_telemetry(p, &t), 34);
    size_t n = rig_frame_build(RIG_MSG_TELEMETRY, 0, 0x0203, p, sizeof p, w, sizeof w);
    hexcmp(w, n, want, sizeof want);
    /* decoding the example gives the fields back, CRC 0x0704 */
    rig_frame f;
    CHECK(rig_frame_decode(want, sizeof want - 1, &f) == RIG_RX_FRAME);
    CHECK_EQ(f.seq, 0x0203);
    rig_msg_telemetry back;
    CHECK(rig_wire_get_telemetry(rig_frame_payload(&f), f.payload_len, &back));
    CHECK_EQ(back.t_us, 1500250u);
    CHECK_EQ(back.buf_level, 548);
    CHECK(memcmp(&back, &t, sizeof t) == 0 || back.flags == 0x1B);
}

void test_cobs_long_runs(void) {
    uint8_t in[600], enc[700], dec[700];
    for (size_t n = 0; n <= 520; n++) {
        for (size_t i = 0; i < n; i++) in[i] = (uint8_t)((i * 7u + n) % 5u == 0 ? 0 : i * 13u + 1u);
        size_t e = rig_cobs_encode(in, n, enc, sizeof enc);
        CHECK(e >= 1 && e <= n + n / 254 + 1);
        for (size_t i = 0; i < e; i++) CHECK(enc[i] != 0);
        size_t d = 0;
        CHECK(rig_cobs_decode(enc, e, dec, sizeof dec, &d));
        CHECK_EQ(d, n);
        CHECK(memcmp(in, dec, n) == 0);
    }
    /* 254 non-zero bytes: FF + 254 bytes + 01 */
    memset(in, 0x11, 254);
    CHECK_EQ(rig_cobs_encode(in, 254, enc, sizeof enc), 256);
    CHECK_EQ(enc[0], 0xFF);
    CHECK_EQ(enc[255], 0x01);
    /* a code running past the end is an error */
    const uint8_t bad[] = {0x05, 0x01, 0x02};
    size_t d;
    CHECK(!rig_cobs_decode(bad, sizeof bad, dec, sizeof dec, &d));
}

/* A HELLO with a 250-byte payload whose body has no zero byte: 258 COBS bytes + 0x00. */
void test_259_byte_frame_accepted(void) {
    boot();
    uint8_t p[250], w[300];
    size_t n = 0;
    for (unsigned fill = 1; fill < 256 && n != 259; fill++) {
        memset(p, (int)fill, sizeof p);
        p[0] = 1;
        p[1] = 1;
        n = rig_frame_build(RIG_MSG_HELLO, RIG_FLAG_ACK_REQ, 0x0101, p, sizeof p, w, sizeof w);
    }
    CHECK_EQ(n, 259);
    rig_rx(&M, w, n);
    drain();
    CHECK_EQ(M.stats.frames_ok, 1);
    CHECK(nout >= 1 && out[0].type == RIG_MSG_HELLO_REPLY);
    CHECK_EQ(ack_of(0).result, RIG_OK);
}

void test_overflow_junk_and_bit_flips_dropped(void) {
    boot();
    uint8_t junk[600];
    /* 259 non-zero bytes then a delimiter: an overflow, discarded to the delimiter */
    memset(junk, 0x41, 259);
    junk[259] = 0;
    rig_rx(&M, junk, 260);
    CHECK_EQ(M.stats.rx_overflows, 1);
    CHECK_EQ(drain(), 0);
    /* a long run split over many calls, then a good frame after it is accepted */
    memset(junk, 0x42, sizeof junk);
    for (int i = 0; i < 5; i++) rig_rx(&M, junk, sizeof junk);
    uint8_t zero = 0;
    rig_rx(&M, &zero, 1);
    CHECK_EQ(M.stats.rx_overflows, 2);
    CHECK_EQ(hello(), RIG_OK);
    /* empty frames are ignored silently */
    uint8_t zeros[5] = {0};
    uint32_t bad0 = M.stats.frames_bad;
    rig_rx(&M, zeros, sizeof zeros);
    CHECK_EQ(M.stats.frames_bad, bad0);
    /* junk: random bytes with delimiters */
    uint32_t x = 12345;
    for (int i = 0; i < 2000; i++) {
        x = x * 1103515245u + 12345u;
        junk[i % 64] = (uint8_t)(x >> 24);
        if (i % 64 == 63) rig_rx(&M, junk, 64);
    }
    CHECK_EQ(drain(), 0);
    CHECK(M.stats.frames_bad > bad0);
    /* every single bit flip of a valid START frame: dropped without a reply */
    uint8_t w[32];
    size_t n = rig_frame_build(RIG_MSG_START, RIG_FLAG_ACK_REQ, 0x3333, NULL, 0, w, sizeof w);
    for (size_t byte = 0; byte + 1 < n; byte++) {
        for (int bit = 0; bit < 8; bit++) {
            uint8_t c[32];
            memcpy(c, w, n);
            c[byte] ^= (uint8_t)(1u << bit);
            rig_rx(&M, &zero, 1);
            rig_rx(&M, c, n);
            CHECK_EQ(drain(), 0);
        }
    }
    CHECK_EQ(M.state, RIG_STATE_IDLE);
    /* truncated frames */
    for (size_t k = 1; k + 1 < n; k++) {
        rig_rx(&M, w, k);
        rig_rx(&M, &zero, 1);
        CHECK_EQ(drain(), 0);
    }
}

void test_unknown_and_short(void) {
    session();
    uint8_t p[8] = {0};
    CHECK_EQ(cmd(0x80, NULL, 0), RIG_UNKNOWN_TYPE); /* an MCU type from the host */
    CHECK_EQ(cmd(0x84, p, 8), RIG_UNKNOWN_TYPE);
    CHECK_EQ(cmd(0x0D, NULL, 0), RIG_UNKNOWN_TYPE);
    CHECK_EQ(cmd(RIG_MSG_STORE_CALIBRATION, p, 7), RIG_BAD_LENGTH);
    CHECK_EQ(cmd(0x00, NULL, 0), RIG_UNKNOWN_TYPE);
    CHECK_EQ(cmd(RIG_MSG_SET_POSITION, p, 7), RIG_BAD_LENGTH);
    CHECK_EQ(cmd(RIG_MSG_CONFIG, p, 8), RIG_BAD_LENGTH);
    CHECK_EQ(cmd(RIG_MSG_HELLO, p, 5), RIG_BAD_LENGTH);
    /* a chunk: n = 0, n = 31, shorter than 6 + 8n */
    uint8_t c[250];
    int32_t s[31] = {0};
    size_t len = chunk_payload(c, 0, 0, s, NULL, 2);
    CHECK_EQ(cmd(RIG_MSG_TRAJ_CHUNK, c, len - 1), RIG_BAD_LENGTH);
    c[5] = 0;
    CHECK_EQ(cmd(RIG_MSG_TRAJ_CHUNK, c, len), RIG_BAD_LENGTH);
    len = chunk_payload(c, 0, 0, s, NULL, 30);
    c[5] = 31;
    CHECK_EQ(cmd(RIG_MSG_TRAJ_CHUNK, c, len + 4), RIG_BAD_LENGTH);
    CHECK_EQ(cmd(RIG_MSG_TRAJ_CHUNK, c, 5), RIG_BAD_LENGTH);
    /* longer than the layout: accepted, extra ignored */
    len = chunk_payload(c, 0, 0, s, NULL, 2);
    CHECK_EQ(cmd(RIG_MSG_TRAJ_CHUNK, c, len + 7), RIG_OK);
    CHECK_EQ(M.pt_count, 2);
    CHECK_EQ(cmd(RIG_MSG_STOP, p, 8), RIG_OK);
    /* a heartbeat is never answered, not even a short one with ACK_REQ; it feeds the
     * watchdog */
    CHECK_EQ(cmd(RIG_MSG_HEARTBEAT, p, 2), -1);
    CHECK_EQ(cmd(RIG_MSG_HEARTBEAT, p, 4), -1);
    CHECK_EQ(nout, 0);
}
