/* The UART receive ring both boards share: the RX interrupt pushes bytes, the main loop
 * takes them a slice at a time for rig_rx() (so a pending tick waits for one slice at
 * most). Single producer (the ISR), single consumer (the main loop); indices run freely
 * and are masked, so head - tail is the fill level. */
#ifndef RX_RING_H
#define RX_RING_H

#include <stddef.h>
#include <stdint.h>

#define RX_RING_BYTES 1024u /* power of two */
#define RX_SLICE 64u        /* bytes handed to rig_rx per loop pass */

typedef struct {
    volatile uint8_t data[RX_RING_BYTES];
    volatile uint32_t head; /* written by the ISR */
    uint32_t tail;          /* written by the main loop */
} rx_ring;

/* From the ISR: store a byte; 0 when the ring is full (the byte is lost). */
static inline int rx_ring_push(rx_ring *r, uint8_t byte) {
    if (r->head - r->tail >= RX_RING_BYTES) return 0;
    r->data[r->head & (RX_RING_BYTES - 1u)] = byte;
    r->head = r->head + 1u;
    return 1;
}

/* From the main loop: move up to RX_SLICE bytes to buf; how many. */
static inline size_t rx_ring_take(rx_ring *r, uint8_t buf[RX_SLICE]) {
    uint32_t head = r->head;
    size_t n = 0;
    while (r->tail != head && n < RX_SLICE) {
        buf[n++] = r->data[r->tail & (RX_RING_BYTES - 1u)];
        r->tail++;
    }
    return n;
}

static inline int rx_ring_empty(const rx_ring *r) { return r->head == r->tail; }

#endif
