/* Unit tests of the firmware core (firmware/core/) on the fake HAL: the worked examples of
 * docs/rig-protocol.md section 12 byte for byte, the framing rules of section 2, the seq
 * rules of section 6, and the behaviours of sections 5, 8 and 9 with docs/rig-protocol.md that
 * the conformance suite compares with hil/emulators/mcu_model.py. Ends with the line
 * "core tests: N passed, 0 failed" (exit status 1 if any failed).
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fake_hal.h"
#include "rig_core.h"
#include "rig_frame.h"
#include "rig_wire.h"

static int n_passed, n_failed, cur_failed;

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

/* ---- harness --------------------------------------------------------------------------- */

typedef struct {
    uint8_t type, flags;
    uint16_t seq;
    uint8_t payload[RIG_FRAME_MAX_PAYLOAD];
    size_t len;
    uint8_t wire[RIG_FRAME_MAX_WIRE];
    size_t wire_len;
} msg;

static rig_mcu M;
static msg out[1024];
static size_t nout;
static uint32_t t_now;
static uint16_t host_seq;
static const rig_calibration CAL = {1500, 1e-4f, 0u};

static void boot(void) {
    fake_hal_reset();
    rig_boot(&M, 0x5EED0001u, CAL);
    t_now = 0;
    host_seq = 100;
    nout = 0;
}

/* Take everything the MCU queued and decode it; every frame must be valid. */
static size_t drain(void) {
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

static void tick(void) {
    rig_tick(&M, t_now);
    t_now += 1000;
}

/* n ticks, draining after each; returns the last telemetry. */
static rig_msg_telemetry ticks(int n) {
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

static void send_raw(uint8_t type, uint8_t flags, uint16_t seq, const uint8_t *p, size_t n) {
    uint8_t w[RIG_FRAME_MAX_WIRE];
    size_t k = rig_frame_build(type, flags, seq, p, n, w, sizeof w);
    CHECK(k > 0);
    rig_rx(&M, w, k);
}

/* Send a command with ACK_REQ and a new seq; drain; return the ACK's result (-1: none). */
static int cmd(uint8_t type, const uint8_t *p, size_t n) {
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

static rig_msg_ack ack_of(size_t i) {
    rig_msg_ack a;
    memset(&a, 0, sizeof a);
    CHECK(i < nout && (out[i].type == RIG_MSG_ACK || out[i].type == RIG_MSG_HELLO_REPLY));
    if (i < nout) rig_wire_get_ack(out[i].payload, out[i].len, &a);
    return a;
}

static int hello(void) {
    uint8_t p[RIG_LEN_HELLO];
    rig_msg_hello h = {1, 1, 0xCAFEF00Du};
    rig_wire_put_hello(p, &h);
    return cmd(RIG_MSG_HELLO, p, sizeof p);
}

static rig_msg_config default_cfg(void) {
    rig_msg_config c = {400.0f, -50000, 400000, -20000, 200000, 1000, 0, 0.0f, 5e6f,
                        250,    250,    200};
    return c;
}

static int config(const rig_msg_config *c) {
    uint8_t p[RIG_LEN_CONFIG];
    rig_wire_put_config(p, c);
    return cmd(RIG_MSG_CONFIG, p, sizeof p);
}

static size_t chunk_payload(uint8_t *p, uint32_t first, uint8_t flags, const int32_t *steps,
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

static int chunk(uint32_t first, uint8_t flags, const int32_t *steps, unsigned n) {
    uint8_t p[RIG_FRAME_MAX_PAYLOAD];
    size_t len = chunk_payload(p, first, flags, steps, NULL, n);
    return cmd(RIG_MSG_TRAJ_CHUNK, p, len);
}

static int simple(uint8_t type) { return cmd(type, NULL, 0); }

static size_t count_type(uint8_t type) {
    size_t k = 0;
    for (size_t i = 0; i < nout; i++) k += out[i].type == type;
    return k;
}

static const msg *nth_of(uint8_t type, size_t nth) {
    for (size_t i = 0; i < nout; i++) {
        if (out[i].type == type && nth-- == 0) return &out[i];
    }
    return NULL;
}

static rig_msg_fault fault_of(size_t nth) {
    rig_msg_fault f;
    memset(&f, 0, sizeof f);
    const msg *m = nth_of(RIG_MSG_FAULT, nth);
    CHECK(m != NULL);
    if (m) rig_wire_get_fault(m->payload, m->len, &f);
    return f;
}

static rig_msg_state state_of(size_t nth) {
    rig_msg_state s;
    memset(&s, 0, sizeof s);
    const msg *m = nth_of(RIG_MSG_STATE, nth);
    CHECK(m != NULL);
    if (m) rig_wire_get_state(m->payload, m->len, &s);
    return s;
}

/* n ticks without a session: no telemetry (docs/rig-protocol.md, section 5). */
static void silent_ticks(int n) {
    for (int i = 0; i < n; i++) {
        tick();
        drain();
        for (size_t k = 0; k < nout; k++) CHECK(out[k].type != RIG_MSG_TELEMETRY);
    }
}

static void session(void) {
    boot();
    silent_ticks(1);
    CHECK_EQ(hello(), RIG_OK);
    CHECK_EQ(M.state, RIG_STATE_IDLE);
}

static void hexcmp(const uint8_t *got, size_t n_got, const uint8_t *want, size_t n_want) {
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

/* ---- framing --------------------------------------------------------------------------- */

static void test_crc_check_value(void) {
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

static void test_example_hello_wire(void) {
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

static void test_example_ack(void) {
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

static void test_example_telemetry(void) {
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

static void test_cobs_long_runs(void) {
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
static void test_259_byte_frame_accepted(void) {
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

static void test_overflow_junk_and_bit_flips_dropped(void) {
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

static void test_unknown_and_short(void) {
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

/* ---- seq rules (section 6, docs/rig-protocol.md) -------------------------------------------- */

static void test_seq_rules(void) {
    session();
    const uint16_t B = (uint16_t)(host_seq + 10);     /* newer than the HELLO's seq */
    const uint16_t S = (uint16_t)(B + 0x8000);        /* the START's, 2^15 away */
    int32_t pts[30];
    for (int i = 0; i < 30; i++) pts[i] = 0;
    uint8_t c[250];
    size_t len = chunk_payload(c, 0, 0, pts, NULL, 30);
    send_raw(RIG_MSG_TRAJ_CHUNK, RIG_FLAG_ACK_REQ, B, c, len);
    drain();
    CHECK_EQ(nout, 1);
    uint8_t first_reply[64];
    size_t first_len = out[0].len;
    memcpy(first_reply, out[0].payload, first_len);
    CHECK_EQ(ack_of(0).result, RIG_OK);
    CHECK_EQ(M.pt_count, 30);
    ticks(3); /* the sample moves on: the stored reply keeps its own */
    /* retransmission: answered with the stored reply, not executed again */
    send_raw(RIG_MSG_TRAJ_CHUNK, RIG_FLAG_ACK_REQ | RIG_FLAG_RETRY, B, c, len);
    drain();
    CHECK_EQ(nout, 1);
    CHECK_EQ(out[0].len, first_len);
    CHECK(memcmp(out[0].payload, first_reply, first_len) == 0);
    CHECK_EQ(M.pt_count, 30);
    CHECK_EQ(M.next_index, 30);
    /* an older seq: STALE, not executed, stored seq and reply unchanged */
    send_raw(RIG_MSG_START, RIG_FLAG_ACK_REQ, (uint16_t)(B - 1), NULL, 0);
    drain();
    CHECK_EQ(ack_of(0).result, RIG_STALE);
    CHECK_EQ(ack_of(0).acked_seq, (uint16_t)(B - 1));
    CHECK_EQ(M.state, RIG_STATE_IDLE);
    send_raw(RIG_MSG_START, RIG_FLAG_ACK_REQ, (uint16_t)(B - 0x7FFF), NULL, 0);
    drain();
    CHECK_EQ(ack_of(0).result, RIG_STALE);
    send_raw(RIG_MSG_TRAJ_CHUNK, RIG_FLAG_ACK_REQ, B, c, len);
    drain();
    CHECK(memcmp(out[0].payload, first_reply, first_len) == 0); /* still the stored one */
    /* exactly 2^15 away: executed */
    send_raw(RIG_MSG_START, RIG_FLAG_ACK_REQ, S, NULL, 0);
    drain();
    CHECK_EQ(ack_of(0).result, RIG_OK);
    CHECK_EQ(M.state, RIG_STATE_RUNNING);
    ticks(2);
    /* STOP with the stored seq: executed (a fresh ACK, STOPPING) */
    send_raw(RIG_MSG_STOP, RIG_FLAG_ACK_REQ, S, NULL, 0);
    drain();
    CHECK_EQ(ack_of(0).result, RIG_OK);
    CHECK_EQ(ack_of(0).state, RIG_STATE_STOPPING);
    CHECK_EQ(M.state, RIG_STATE_STOPPING);
    CHECK_EQ(count_type(RIG_MSG_STATE), 1);
    /* a STOP retransmitted with the same seq is executed again and answered afresh */
    send_raw(RIG_MSG_STOP, RIG_FLAG_ACK_REQ | RIG_FLAG_RETRY, S, NULL, 0);
    drain();
    CHECK_EQ(nout, 1);
    CHECK_EQ(ack_of(0).state, RIG_STATE_STOPPING);
    /* ESTOP with an old seq: executed; the stored seq is not re-based */
    send_raw(RIG_MSG_ESTOP, RIG_FLAG_ACK_REQ, (uint16_t)(S - 5), NULL, 0);
    drain();
    CHECK_EQ(ack_of(0).result, RIG_OK);
    CHECK_EQ(ack_of(0).state, RIG_STATE_ESTOP);
    CHECK_EQ(M.state, RIG_STATE_ESTOP);
    CHECK_EQ(M.last_seq, S);
    CHECK_EQ(count_type(RIG_MSG_FAULT), 1);
    /* an older CLEAR_FAULT is stale */
    send_raw(RIG_MSG_CLEAR_FAULT, RIG_FLAG_ACK_REQ, (uint16_t)(S - 4), NULL, 0);
    drain();
    CHECK_EQ(ack_of(0).result, RIG_STALE);
    CHECK_EQ(M.state, RIG_STATE_ESTOP);
    /* ESTOP repeated with the same seq: answered each time, FAULT only once (new bit) */
    send_raw(RIG_MSG_ESTOP, RIG_FLAG_ACK_REQ | RIG_FLAG_RETRY, (uint16_t)(S - 5), NULL, 0);
    drain();
    CHECK_EQ(nout, 1);
    /* HELLO always executed, and re-bases the stored seq even with an old seq */
    uint8_t p[RIG_LEN_HELLO];
    rig_msg_hello h = {1, 1, 7};
    rig_wire_put_hello(p, &h);
    send_raw(RIG_MSG_HELLO, RIG_FLAG_ACK_REQ, (uint16_t)(S - 100), p, sizeof p);
    drain();
    CHECK_EQ(ack_of(0).result, RIG_OK);
    CHECK_EQ(ack_of(0).state, RIG_STATE_ESTOP); /* HELLO in ESTOP keeps the state */
    CHECK_EQ(M.last_seq, (uint16_t)(S - 100));
    send_raw(RIG_MSG_CLEAR_FAULT, RIG_FLAG_ACK_REQ, (uint16_t)(S - 99), NULL, 0);
    drain();
    CHECK_EQ(ack_of(0).result, RIG_OK);
    CHECK_EQ(M.state, RIG_STATE_IDLE);
    /* HELLO with another major: VERSION_MISMATCH, still stored */
    h.proto_major = 2;
    rig_wire_put_hello(p, &h);
    send_raw(RIG_MSG_HELLO, RIG_FLAG_ACK_REQ, (uint16_t)(S + 1000), p, sizeof p);
    drain();
    CHECK_EQ(ack_of(0).result, RIG_VERSION_MISMATCH);
    CHECK_EQ(M.last_seq, (uint16_t)(S + 1000));
}

static void test_no_reply_without_ack_req(void) {
    session();
    int32_t pts[3] = {0, 0, 0};
    uint8_t c[64];
    size_t len = chunk_payload(c, 0, RIG_CHUNK_FINAL, pts, NULL, 3);
    send_raw(RIG_MSG_TRAJ_CHUNK, 0, 200, c, len);
    CHECK_EQ(drain(), 0);
    CHECK_EQ(M.pt_count, 3); /* executed all the same */
    send_raw(RIG_MSG_START, 0, 201, NULL, 0);
    drain();
    CHECK_EQ(count_type(RIG_MSG_ACK), 0);
    CHECK_EQ(count_type(RIG_MSG_STATE), 1); /* the state change is still reported */
    CHECK_EQ(M.state, RIG_STATE_RUNNING);
    send_raw(RIG_MSG_START, 0, 150, NULL, 0); /* stale */
    send_raw(0x80, 0, 202, NULL, 0);          /* unknown */
    send_raw(0x33, 0, 203, NULL, 0);          /* unknown */
    send_raw(RIG_MSG_CONFIG, 0, 204, c, 3);   /* short */
    send_raw(RIG_MSG_START, 0, 201, NULL, 0); /* retransmission */
    CHECK_EQ(drain(), 0);
}

/* ---- motion ------------------------------------------------------------------------------ */

static void test_run_of_n_points(void) {
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

static void test_chunk_rules(void) {
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

static void test_stop_ramp_q16(void) {
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

static void test_stop_at_standstill(void) {
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

static void test_underrun(void) {
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

/* ---- checks of section 8 ----------------------------------------------------------------- */

static void test_load_stuck_at_exactly_stuck_samples(void) {
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

static void test_travel_limit_lower_bound(void) {
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

static void test_rail_latches_saturated_and_force(void) {
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

static void test_force_limit_and_following_error(void) {
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

static void test_heartbeat_loss_at_rest(void) {
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

static void test_heartbeat_loss_running(void) {
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

static void test_estop_and_driver(void) {
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
 * FORCE_LIMIT halts holding position, the driver energised (docs/rig-protocol.md 8). */
static void test_board_faults_de_energise_and_limits_hold(void) {
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
static void test_the_first_point_waits_for_the_drivers_power(void) {
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

static void test_config_rules(void) {
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
static void test_config_rechecks_buffered_points(void) {
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

static void test_telemetry_only_in_a_session_and_tx_fifo(void) {
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

static void test_set_position_and_bye(void) {
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
static void test_store_and_read_calibration(void) {
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
