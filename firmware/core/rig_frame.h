/* Framing of the rig protocol (docs/rig-protocol.md section 2), shared by the MCU core and
 * its tests: CRC-16/CCITT-FALSE, COBS, and the receiver's frame accumulator.
 *
 * Why a module of its own: the framing is the only code that touches raw untrusted bytes
 * before any length is known, so it is kept small, bounded and separately testable. No
 * heap; every buffer has a fixed size and every write is bounds-checked.
 */
#ifndef RIG_FRAME_H
#define RIG_FRAME_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#define RIG_FRAME_HEADER 4u        /* type u8, flags u8, seq u16 */
#define RIG_FRAME_CRC 2u           /* little-endian CRC-16 after the payload */
#define RIG_FRAME_MAX_PAYLOAD 250u
#define RIG_FRAME_MAX_BODY 256u    /* header + payload + crc */
#define RIG_FRAME_MIN_BODY 6u      /* header + crc */
#define RIG_FRAME_MAX_ENCODED 258u /* COBS of the largest body, without the delimiter */
#define RIG_FRAME_MAX_WIRE 259u    /* with the delimiter */

#define RIG_FLAG_ACK_REQ 0x01u
#define RIG_FLAG_RETRY 0x02u

/* CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, xorout 0); "123456789" gives
 * 0x29B1. crc: 0xFFFF to start, or the value returned for the preceding bytes. */
uint16_t rig_crc16(uint16_t crc, const uint8_t *data, size_t n);

/* COBS-encode n bytes into out (no delimiter appended). Returns the encoded length, or 0
 * when out_cap is too small (nothing useful is left in out then). Encoded length is at most
 * n + n / 254 + 1. */
size_t rig_cobs_encode(const uint8_t *in, size_t n, uint8_t *out, size_t out_cap);

/* COBS-decode n bytes (no delimiter) into out. Returns false on invalid COBS (a zero byte,
 * a code running past the end) or when the result would exceed out_cap. */
bool rig_cobs_decode(const uint8_t *in, size_t n, uint8_t *out, size_t out_cap,
                     size_t *out_len);

/* One decoded frame: the body with the CRC checked; payload = body + 4. */
typedef struct {
    uint8_t body[RIG_FRAME_MAX_BODY];
    uint16_t body_len;    /* header + payload + crc, 6..256 */
    uint8_t type, flags;
    uint16_t seq;
    uint16_t payload_len; /* body_len - 6 */
} rig_frame;

static inline const uint8_t *rig_frame_payload(const rig_frame *f) {
    return f->body + RIG_FRAME_HEADER;
}

/* The receiver: accumulates bytes up to a delimiter (section 2, receiver rules). */
typedef struct {
    uint8_t buf[RIG_FRAME_MAX_ENCODED];
    uint16_t len;
    uint8_t overflow; /* more than 258 bytes without a delimiter: discard to the next one */
} rig_frame_rx;

typedef enum {
    RIG_RX_NONE = 0,  /* byte stored (or an empty frame ignored, or inside a discard) */
    RIG_RX_FRAME,     /* *out holds a frame with a good CRC */
    RIG_RX_BAD,       /* invalid COBS, body shorter than 6 or longer than 256, bad CRC */
    RIG_RX_OVERFLOW   /* the delimiter ending an over-long run: the run was discarded */
} rig_rx_event;

void rig_frame_rx_reset(rig_frame_rx *rx);

/* Feed one byte. Only when it is a delimiter can the result be other than RIG_RX_NONE. */
rig_rx_event rig_frame_rx_byte(rig_frame_rx *rx, uint8_t byte, rig_frame *out);

/* Decode the COBS bytes between two delimiters into *out (used by the accumulator and by
 * the tests' and fuzzer's checks of what the MCU sends). */
rig_rx_event rig_frame_decode(const uint8_t *enc, size_t n, rig_frame *out);

/* Build a whole wire frame: COBS(header | payload | crc) then 0x00. Returns its length, or
 * 0 when payload_len > 250 or out_cap is too small. */
size_t rig_frame_build(uint8_t type, uint8_t flags, uint16_t seq, const uint8_t *payload,
                       size_t payload_len, uint8_t *out, size_t out_cap);

#endif
