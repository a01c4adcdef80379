/* The core's unit tests (core_test.h): the seq rules of section 6 and replies only on ACK_REQ. */
#include "core_test.h"

/* ---- seq rules (section 6, docs/rig-protocol-behaviour.md) ---------------------------------- */

void test_seq_rules(void) {
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

void test_no_reply_without_ack_req(void) {
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
