/* The core's receive path (rig_core.h: rig_rx, rig_link_lost): every byte through the
 * framing (rig_frame.c), and each good frame through section 2's type and length rules and
 * section 6's seq rules (with docs/rig-protocol-behaviour.md) to one command (rig_commands.c). */
#include "rig_core_internal.h"

/* Minimal payload length of a host type; -1: unknown type. TRAJ_CHUNK is checked whole
 * by chunk_length_ok. */
static int min_payload(uint8_t type) {
    switch (type) {
    case RIG_MSG_HELLO: return (int)RIG_LEN_HELLO;
    case RIG_MSG_HEARTBEAT: return (int)RIG_LEN_HEARTBEAT;
    case RIG_MSG_CONFIG: return (int)RIG_LEN_CONFIG;
    case RIG_MSG_TRAJ_CHUNK: return (int)RIG_LEN_CHUNK_HEAD;
    case RIG_MSG_START:
    case RIG_MSG_STOP:
    case RIG_MSG_ESTOP:
    case RIG_MSG_CLEAR_FAULT:
    case RIG_MSG_BYE: return 0;
    case RIG_MSG_SET_POSITION: return (int)RIG_LEN_SET_POSITION;
    case RIG_MSG_STORE_CALIBRATION: return (int)RIG_LEN_STORE_CALIBRATION;
    case RIG_MSG_READ_CALIBRATION: return 0;
    default: return -1;
    }
}

static bool chunk_length_ok(const uint8_t *p, size_t len) {
    rig_msg_chunk_head h;
    if (!rig_wire_get_chunk_head(p, len, &h)) return false;
    if (h.n == 0 || h.n > RIG_MAX_CHUNK_POINTS) return false;
    return len >= RIG_LEN_CHUNK_HEAD + (size_t)h.n * RIG_LEN_POINT;
}

static bool seq_newer(uint16_t seq, uint16_t last) {
    uint16_t d = (uint16_t)(seq - last);
    return d != 0 && d < 0x8000u;
}

static bool seq_stale(uint16_t seq, uint16_t last) { return seq_newer(last, seq); }

static void send_reply(rig_mcu *m, const rig_reply *r) {
    rig_tx_frame(m, r->type, r->payload, r->len);
}

/* One valid host frame (good CRC): section 2's type/length rules, section 6's seq rules
 * with docs/rig-protocol-behaviour.md, then the command. */
static void handle_frame(rig_mcu *m, const rig_frame *f) {
    bool ack_req = (f->flags & RIG_FLAG_ACK_REQ) != 0;
    rig_reply r;
    /* any valid host frame feeds the watchdog (docs/rig-protocol-behaviour.md) */
    m->last_rx_us = m->t_us;
    int need = f->type >= 0x80u ? -1 : min_payload(f->type);
    if (need < 0) { /* unknown, or an MCU->host type: an unknown command */
        if (ack_req) {
            rig_reply_ack(m, &r, f->seq, RIG_UNKNOWN_TYPE);
            send_reply(m, &r);
        }
        return;
    }
    if (f->type == RIG_MSG_HEARTBEAT) return; /* never answered, whatever its length */
    bool len_ok = f->type == RIG_MSG_TRAJ_CHUNK
                      ? chunk_length_ok(rig_frame_payload(f), f->payload_len)
                      : f->payload_len >= (size_t)need;
    if (!len_ok) {
        if (ack_req) {
            rig_reply_ack(m, &r, f->seq, RIG_BAD_LENGTH);
            send_reply(m, &r);
        }
        return;
    }
    bool store;
    bool is_stop = f->type == RIG_MSG_STOP || f->type == RIG_MSG_ESTOP;
    m->events_deferred = 1;
    m->event_count = 0;
    if (f->type == RIG_MSG_HELLO) {
        rig_execute(m, f, &r);
        store = true; /* a new host starts at a random seq, whatever the answer */
    } else if (is_stop) {
        /* always executed, also with the stored seq (docs/rig-protocol-behaviour.md); stored
         * only when newer, so an old seq does not re-base the order */
        rig_execute(m, f, &r);
        store = !m->have_last_seq || seq_newer(f->seq, m->last_seq);
    } else if (m->have_last_seq && f->seq == m->last_seq) {
        /* a retransmission: the stored reply again, not executed again */
        r.type = m->last_reply_type;
        r.len = m->last_reply_len;
        memcpy(r.payload, m->last_reply, sizeof r.payload);
        store = false;
    } else if (m->have_last_seq && seq_stale(f->seq, m->last_seq)) {
        rig_reply_ack(m, &r, f->seq, RIG_STALE);
        store = false;
    } else {
        rig_execute(m, f, &r);
        store = true;
    }
    if (store) {
        m->have_last_seq = 1;
        m->last_seq = f->seq;
        m->last_reply_type = r.type;
        m->last_reply_len = r.len;
        memcpy(m->last_reply, r.payload, sizeof m->last_reply);
    }
    if (ack_req) send_reply(m, &r);
    rig_flush_events(m);
}

void rig_rx(rig_mcu *m, const uint8_t *data, size_t n) {
    if (m == NULL || data == NULL) return;
    for (size_t i = 0; i < n; i++) {
        switch (rig_frame_rx_byte(&m->rx, data[i], &m->frame)) {
        case RIG_RX_FRAME:
            m->stats.frames_ok++;
            handle_frame(m, &m->frame);
            break;
        case RIG_RX_BAD:
            m->stats.frames_bad++;
            break;
        case RIG_RX_OVERFLOW:
            m->stats.rx_overflows++;
            break;
        case RIG_RX_NONE:
        default:
            break;
        }
    }
}

void rig_link_lost(rig_mcu *m) {
    m->session = 0;
    rig_restore_calibration(m); /* docs/rig-protocol.md */
    if (m->state == RIG_STATE_RUNNING) rig_begin_stop(m, RIG_STATE_IDLE, RIG_REASON_LINK_LOST);
}
