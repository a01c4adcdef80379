/* The core's transmitter (rig_core_internal.h): a FIFO of whole frames that the board drains
 * with rig_tx_take(), and the FAULT and STATE frames a command causes, held until its reply
 * is queued (the reply comes first, as in hil/emulators/mcu_model.py). */
#include "rig_core_internal.h"

/* ---- transmit -------------------------------------------------------------------------- */

size_t rig_tx_pending(const rig_mcu *m) { return (size_t)(m->tx_head - m->tx_tail); }

size_t rig_tx_take(rig_mcu *m, uint8_t *out, size_t max) {
    size_t n = rig_tx_pending(m);
    if (n > max) n = max;
    for (size_t i = 0; i < n; i++) {
        out[i] = m->tx_fifo[(m->tx_tail + (uint32_t)i) & (RIG_TX_FIFO_BYTES - 1u)];
    }
    m->tx_tail += (uint32_t)n;
    return n;
}

/* One MCU frame: flags 0, the MCU's own seq. The seq counts every frame built, also one
 * dropped for lack of FIFO room (the host then sees the gap; our choice, the spec only says
 * the seq counts every frame the MCU sends). A frame that does not fit is dropped whole. */
void rig_tx_frame(rig_mcu *m, uint8_t type, const uint8_t *payload, size_t len) {
    uint8_t wire[RIG_FRAME_HEADER + RIG_MAX_REPLY + RIG_FRAME_CRC + 4];
    size_t n = rig_frame_build(type, 0, m->tx_seq, payload, len, wire, sizeof wire);
    m->tx_seq++;
    size_t room = RIG_TX_FIFO_BYTES - rig_tx_pending(m);
    if (n == 0 || n > room) {
        m->stats.tx_dropped++;
        return;
    }
    for (size_t i = 0; i < n; i++) {
        m->tx_fifo[(m->tx_head + (uint32_t)i) & (RIG_TX_FIFO_BYTES - 1u)] = wire[i];
    }
    m->tx_head += (uint32_t)n;
}

/* A FAULT or STATE frame: sent at once, or held while a command is executed (its reply
 * goes first). */
void rig_emit_event(rig_mcu *m, uint8_t type, const uint8_t *payload, size_t len) {
    if (m->events_deferred && m->event_count < RIG_EVENT_SLOTS && len <= RIG_EVENT_MAX) {
        rig_event *e = &m->events[m->event_count++];
        e->type = type;
        e->len = (uint8_t)len;
        memcpy(e->payload, payload, len);
        return;
    }
    rig_tx_frame(m, type, payload, len);
}

void rig_flush_events(rig_mcu *m) {
    for (uint8_t i = 0; i < m->event_count; i++) {
        rig_tx_frame(m, m->events[i].type, m->events[i].payload, m->events[i].len);
    }
    m->event_count = 0;
    m->events_deferred = 0;
}
