/* Fuzzer of the core's receive path (rig_rx) on the fake HAL, standalone (gcc has no
 * libFuzzer; clang is not installed here). Build it with -fsanitize=address,undefined
 * -fno-sanitize-recover=all (firmware/Makefile, target fuzz).
 *
 *   fuzz_rx [FRAMES [SEED]]     defaults 1000000 and 1; deterministic for a seed
 *
 * Each iteration sends one "frame" to rig_rx, split into random pieces: a valid frame of
 * any host type (fields chosen from the MCU's present state often enough to reach every
 * state: sessions, trajectories, runs, stops, faults), the same mutated in its body (bit
 * flips, truncation, extension, a changed point count, header bytes) with the CRC
 * recomputed so it passes the cheap check, a valid frame corrupted on the wire, or random
 * bytes. rig_tick runs between frames (0-3 periods, the fake HAL's inputs changing now and
 * then: stuck or railed load cell, stop input, driver alarm, encoder jumps).
 *
 * Invariants checked after every frame and tick: state in 0..5; buffer level and ring
 * indices within capacity; the tx FIFO's pending count within its size; every byte the
 * MCU sends decodes into whole frames with a good CRC, flags 0, a known MCU type and that
 * type's exact payload length, with sane field values; MCU seq accounts for every frame
 * sent or dropped; exactly one ACK per intact command frame with ACK_REQ (HEARTBEAT: none)
 * and none for a frame without it; telemetry samples strictly increasing with the boot id;
 * one hal_step, hal_read and watchdog kick per tick, in order; the core's step count the
 * fake's. Prints "fuzz: N frames, F failures" and exits 1 on a failure (after 20 reports).
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fake_hal.h"
#include "rig_core.h"
#include "rig_frame.h"
#include "rig_wire.h"

static rig_mcu M;
static uint64_t rng_state;
static unsigned long failures;
static unsigned long iteration;

/* xorshift64*: deterministic, no libc rand() */
static uint32_t rnd(void) {
    rng_state ^= rng_state >> 12;
    rng_state ^= rng_state << 25;
    rng_state ^= rng_state >> 27;
    return (uint32_t)((rng_state * 2685821657736338717ULL) >> 32);
}

static uint32_t below(uint32_t n) { return n ? rnd() % n : 0; }
static int chance(unsigned percent) { return below(100) < percent; }

#define FAIL(...)                                                               \
    do {                                                                        \
        failures++;                                                             \
        if (failures <= 20) {                                                   \
            fprintf(stderr, "fuzz: iteration %lu: ", iteration);                \
            fprintf(stderr, __VA_ARGS__);                                       \
            fprintf(stderr, "\n");                                              \
        }                                                                       \
    } while (0)

/* ---- what the MCU sends ---------------------------------------------------------------- */

static uint32_t frames_seen, replies_seen, boot_id;
static unsigned fault_bits_seen, results_seen;
static uint32_t last_sample;
static int have_sample;
static uint32_t dropped_at_boot;

static size_t layout_len(uint8_t type) {
    switch (type) {
    case RIG_MSG_ACK: return RIG_LEN_ACK;
    case RIG_MSG_HELLO_REPLY: return RIG_LEN_HELLO_REPLY;
    case RIG_MSG_TELEMETRY: return RIG_LEN_TELEMETRY;
    case RIG_MSG_FAULT: return RIG_LEN_FAULT;
    case RIG_MSG_STATE: return RIG_LEN_STATE;
    case RIG_MSG_CALIBRATION: return RIG_LEN_CALIBRATION;
    default: return 0;
    }
}

static void check_mcu_frame(const rig_frame *f) {
    size_t want = layout_len(f->type);
    if (want == 0) {
        FAIL("MCU frame of unknown type 0x%02x", f->type);
        return;
    }
    if (f->payload_len != want) FAIL("MCU type 0x%02x with %u bytes", f->type, f->payload_len);
    if (f->flags != 0) FAIL("MCU frame with flags 0x%02x", f->flags);
    const uint8_t *p = rig_frame_payload(f);
    switch (f->type) {
    case RIG_MSG_ACK:
    case RIG_MSG_HELLO_REPLY:
    case RIG_MSG_CALIBRATION: {
        rig_msg_ack a;
        rig_wire_get_ack(p, f->payload_len, &a);
        if (a.result > RIG_NVM_ERROR) FAIL("ACK result %u", a.result);
        if (f->type == RIG_MSG_CALIBRATION) {
            rig_msg_calibration c;
            rig_wire_get_calibration(p, f->payload_len, &c);
            if (c.cal_seq != M.stored.seq || c.load_offset != M.stored.load_offset)
                FAIL("CALIBRATION seq %u offset %d, stored %u %d", c.cal_seq, c.load_offset,
                     M.stored.seq, M.stored.load_offset);
            if (c.cal_seq != 0 && (c.cal_seq != fake.nvm.seq || !(c.load_gain_n > 0.0f)))
                FAIL("CALIBRATION seq %u not the NVM's %u", c.cal_seq, fake.nvm.seq);
        }
        if (a.state > RIG_STATE_ESTOP) FAIL("ACK state %u", a.state);
        if (a.buf_level + a.buf_free != RIG_BUFFER_CAPACITY) FAIL("ACK buffer sum");
        if (a.result <= RIG_NVM_ERROR) results_seen |= 1u << a.result;
        replies_seen++;
        break;
    }
    case RIG_MSG_TELEMETRY: {
        rig_msg_telemetry t;
        rig_wire_get_telemetry(p, f->payload_len, &t);
        if (t.state > RIG_STATE_ESTOP) FAIL("telemetry state %u", t.state);
        if (t.buf_level > RIG_BUFFER_CAPACITY) FAIL("telemetry buf_level %u", t.buf_level);
        if (t.faults & ~0x03FFu) FAIL("telemetry faults 0x%04x", t.faults);
        fault_bits_seen |= t.faults;
        if (t.flags & ~0x7Fu) FAIL("telemetry flags 0x%02x", t.flags);
        if (t.boot_id != boot_id) FAIL("telemetry boot id");
        if (have_sample && t.sample <= last_sample) FAIL("sample %u after %u", t.sample, last_sample);
        last_sample = t.sample;
        have_sample = 1;
        break;
    }
    case RIG_MSG_FAULT: {
        rig_msg_fault x;
        rig_wire_get_fault(p, f->payload_len, &x);
        if (x.fault == 0 || (x.fault & (x.fault - 1u)) != 0 || x.fault > 0x0200u) {
            FAIL("FAULT bit 0x%04x", x.fault);
        }
        if (x.state > RIG_STATE_ESTOP) FAIL("FAULT state %u", x.state);
        break;
    }
    case RIG_MSG_STATE: {
        rig_msg_state s;
        rig_wire_get_state(p, f->payload_len, &s);
        if (s.old_state > RIG_STATE_ESTOP || s.new_state > RIG_STATE_ESTOP || s.reason > 4) {
            FAIL("STATE %u -> %u reason %u", s.old_state, s.new_state, s.reason);
        }
        break;
    }
    default:
        break;
    }
}

/* Take what the MCU queued (all of it, or now and then only part: the FIFO may fill and
 * drop whole frames) and check it frame by frame. */
static uint8_t tx_partial[RIG_TX_FIFO_BYTES + RIG_FRAME_MAX_WIRE];
static size_t tx_partial_len;

static void drain(int all) {
    size_t pending = rig_tx_pending(&M);
    if (pending > RIG_TX_FIFO_BYTES) FAIL("tx pending %zu", pending);
    if (M.tx_head - M.tx_tail != pending) FAIL("tx indices");
    size_t want = all ? pending : below((uint32_t)pending + 1u);
    size_t got = rig_tx_take(&M, tx_partial + tx_partial_len, want);
    if (got != want) FAIL("tx_take gave %zu of %zu", got, want);
    tx_partial_len += got;
    size_t start = 0;
    for (size_t i = 0; i < tx_partial_len; i++) {
        if (tx_partial[i] != 0) continue;
        rig_frame f;
        if (rig_frame_decode(tx_partial + start, i - start, &f) != RIG_RX_FRAME) {
            FAIL("MCU frame does not decode (%zu bytes)", i - start);
        } else {
            check_mcu_frame(&f);
        }
        frames_seen++;
        start = i + 1;
    }
    memmove(tx_partial, tx_partial + start, tx_partial_len - start);
    tx_partial_len -= start;
    if (tx_partial_len > RIG_FRAME_MAX_WIRE) FAIL("MCU frame without delimiter");
    if (all && rig_tx_pending(&M) == 0) {
        if (tx_partial_len != 0) FAIL("FIFO ends inside a frame");
        /* every seq was used by a frame seen or a frame dropped */
        uint32_t used = frames_seen + (M.stats.tx_dropped - dropped_at_boot);
        if ((uint16_t)used != M.tx_seq) FAIL("MCU seq %u, frames %u", M.tx_seq, used);
    }
}

/* ---- invariants of the MCU ----------------------------------------------------------- */

static uint32_t ticks_since_boot;

static void check_mcu(void) {
    if (M.state > RIG_STATE_ESTOP) FAIL("state %u", M.state);
    if (M.pt_count > RIG_BUFFER_CAPACITY) FAIL("buffer level %u", M.pt_count);
    if (M.pt_head >= RIG_BUFFER_CAPACITY) FAIL("ring head %u", M.pt_head);
    if (M.faults & ~0x03FFu) FAIL("faults 0x%04x", M.faults);
    if (M.event_count != 0 || M.events_deferred) FAIL("events left deferred");
    if (M.rx.len > RIG_FRAME_MAX_ENCODED) FAIL("rx length %u", M.rx.len);
    if (M.hw_steps != fake.hw_steps) FAIL("core hw_steps %d, fake %d", M.hw_steps, fake.hw_steps);
    if ((uint32_t)M.steps != (uint32_t)M.hw_steps + (uint32_t)M.steps_offset) FAIL("steps sum");
    if ((M.state == RIG_STATE_FAULT || M.state == RIG_STATE_ESTOP) && M.faults == 0) {
        /* FAULT/ESTOP always has a bit latched */
        FAIL("state %u without a fault bit", M.state);
    }
    if (M.state == RIG_STATE_ESTOP && M.driver_enabled) FAIL("driver enabled in ESTOP");
    if (fake.steps_calls != ticks_since_boot || fake.read_calls != ticks_since_boot ||
        fake.kicks != ticks_since_boot || fake.order_errors != 0) {
        FAIL("HAL calls: step %u read %u kick %u ticks %u order errors %u", fake.steps_calls,
             fake.read_calls, fake.kicks, ticks_since_boot, fake.order_errors);
    }
    if (fake.last_delta > 65535 || fake.last_delta < -65535) FAIL("step delta %d", fake.last_delta);
}

/* ---- the host's frames ----------------------------------------------------------------- */

static uint16_t host_seq;
static uint32_t t_now;

static unsigned long total_ok, total_bad, total_overflows, total_dropped;

static void add_stats(void) {
    total_ok += M.stats.frames_ok;
    total_bad += M.stats.frames_bad;
    total_overflows += M.stats.rx_overflows;
    total_dropped += M.stats.tx_dropped;
}

static void do_boot(void) {
    add_stats();
    fake_hal_reset();
    fake.enc_div = 5; /* 1 um of platen per 5 steps of table, roughly the linkage */
    boot_id = rnd() | 1u;
    rig_calibration cal = {(int32_t)(below(4000)), 1e-4f, 0u};
    rig_boot(&M, boot_id, cal);
    frames_seen = 0;
    have_sample = 0;
    tx_partial_len = 0;
    dropped_at_boot = 0; /* rig_boot zeroes the stats */
    ticks_since_boot = 0;
    t_now = rnd();
}

static void do_tick(void) {
    /* inputs change now and then; conditions that would keep the MCU in FAULT are brief */
    if (below(1000) < 3) {
        fake.load_base = chance(50) ? (int32_t)RIG_ADC_MAX : (int32_t)RIG_ADC_MIN;
    } else if (chance(5)) {
        fake.load_base = 1500 + (int32_t)below(200001) - 100000; /* +-10 N */
    }
    if (chance(2)) fake.load_stuck = !fake.load_stuck;
    fake.stop_input = below(1000) < 2;
    fake.driver_alarm = below(1000) < 2;
    if (chance(2)) fake.enc_base = 1234 + (int32_t)below(4001) - 2000;
    if (chance(2)) fake.home_switch = !fake.home_switch;
    if (chance(5)) fake.halt_return = (int32_t)below(4);
    rig_tick(&M, t_now);
    ticks_since_boot++;
    t_now += below(1000) < 2 ? rnd() % 400000u : 1000u; /* now and then a long silence */
}

static uint32_t rand_f32_bits(void) {
    switch (below(6)) {
    case 0: return 0x7FC00000u;               /* NaN */
    case 1: return 0x7F800000u | (rnd() & 0x80000000u); /* +-inf */
    case 2: return 0;                          /* 0 */
    default: return rnd();
    }
}

static float f32_of(uint32_t bits) {
    float f;
    memcpy(&f, &bits, sizeof f);
    return f;
}

static int32_t clamp_i32(int64_t v) {
    return v > INT32_MAX ? INT32_MAX : v < INT32_MIN ? INT32_MIN : (int32_t)v;
}

static int32_t rand_i32_near(int32_t v, uint32_t spread) {
    return (int32_t)((uint32_t)v + below(2 * spread + 1) - spread);
}

/* A plausible payload for a host type, from the MCU's state; returns its length. */
static size_t make_payload(uint8_t type, uint8_t *p) {
    switch (type) {
    case RIG_MSG_HELLO: {
        rig_msg_hello h = {chance(95) ? 1 : (uint8_t)rnd(), (uint8_t)below(3), rnd()};
        return rig_wire_put_hello(p, &h);
    }
    case RIG_MSG_HEARTBEAT:
        rig_put_u32(p, rnd());
        return 4;
    case RIG_MSG_CONFIG: {
        rig_msg_config c;
        c.force_limit_n = chance(80) ? (float)(below(600) + 1) : f32_of(rand_f32_bits());
        c.steps_min = clamp_i32((int64_t)M.steps - below(200000) + (chance(5) ? 10 : 0));
        c.steps_max = clamp_i32((int64_t)M.steps + below(400000));
        c.enc_min = clamp_i32((int64_t)M.enc - below(100000));
        c.enc_max = clamp_i32((int64_t)M.enc + below(300000));
        c.following_error_counts = chance(90) ? (int32_t)below(3000) + 1 : (int32_t)rnd();
        c.load_offset = (int32_t)below(3000);
        c.load_gain_n = chance(50) ? 0.0f : (chance(80) ? 1e-4f : f32_of(rand_f32_bits()));
        c.decel_steps_s2 = chance(80) ? (float)(below(10000000) + 1) : f32_of(rand_f32_bits());
        c.max_step_delta = (uint16_t)(chance(80) ? below(400) + 1 : rnd());
        c.heartbeat_timeout_ms = (uint16_t)(chance(80) ? below(300) + 1 : rnd());
        c.stuck_samples = (uint16_t)(chance(80) ? below(300) + 1 : rnd());
        return rig_wire_put_config(p, &c);
    }
    case RIG_MSG_TRAJ_CHUNK: {
        unsigned n = 1 + below(30);
        uint32_t first = chance(70) ? M.next_index : (chance(50) ? 0 : below(M.next_index + 40));
        int32_t prev = M.steps;
        if (M.pt_count > 0) {
            uint32_t last = (M.pt_head + M.pt_count - 1u) & (RIG_BUFFER_CAPACITY - 1u);
            prev = M.points[last].steps;
        }
        uint32_t span = chance(90) ? M.cfg.max_step_delta : 70000u;
        rig_put_u32(p, first);
        p[4] = (uint8_t)(chance(15) ? RIG_CHUNK_FINAL : (chance(3) ? rnd() : 0));
        p[5] = (uint8_t)n;
        for (unsigned k = 0; k < n; k++) {
            prev = rand_i32_near(prev, span);
            rig_put_i32(p + 6 + 8 * k, prev);
            rig_put_i32(p + 10 + 8 * k,
                        chance(70) ? RIG_NO_CHECK : rand_i32_near(M.enc, 1500));
        }
        return 6 + 8 * (size_t)n;
    }
    case RIG_MSG_SET_POSITION:
        rig_put_i32(p, rand_i32_near(0, chance(90) ? 1000 : 0x7FFFFFFF));
        rig_put_i32(p + 4, rand_i32_near(0, 1000));
        return 8;
    case RIG_MSG_STORE_CALIBRATION: { /* 1.3: plausible, at the ADC's rails, or any bits */
        static const int32_t edges[] = {-8388608, -8388607, 8388606, 8388607, INT32_MIN};
        rig_msg_store_calibration c = {
            chance(80) ? rand_i32_near(1500, 100000) : edges[below(5)],
            chance(70) ? 1e-4f * (float)(below(200) + 1) / 100.0f : f32_of(rand_f32_bits())};
        fake.nvm_fail = chance(10); /* a write that does not verify */
        return rig_wire_put_store_calibration(p, &c);
    }
    default:
        return 0; /* START, STOP, ESTOP, CLEAR_FAULT, BYE, unknown types */
    }
}

/* Half the time the type a host would send in the present state, so runs, stops and
 * recoveries happen; otherwise any type. */
static uint8_t directed_type(void) {
    switch (M.state) {
    case RIG_STATE_BOOT: return RIG_MSG_HELLO;
    case RIG_STATE_IDLE:
        if (chance(5)) return RIG_MSG_CONFIG;
        if (M.pt_count > 0 && (M.final_received || chance(30))) return RIG_MSG_START;
        return RIG_MSG_TRAJ_CHUNK;
    case RIG_STATE_RUNNING:
        if (chance(3)) return RIG_MSG_STOP;
        return chance(70) ? RIG_MSG_TRAJ_CHUNK : RIG_MSG_HEARTBEAT;
    case RIG_STATE_STOPPING: return RIG_MSG_HEARTBEAT;
    default: return chance(80) ? RIG_MSG_CLEAR_FAULT : RIG_MSG_HELLO;
    }
}

static uint8_t pick_type(void) {
    if (chance(50)) return directed_type();
    static const uint8_t weighted[] = {
        RIG_MSG_HELLO, RIG_MSG_HELLO, RIG_MSG_HEARTBEAT, RIG_MSG_HEARTBEAT, RIG_MSG_CONFIG,
        RIG_MSG_CONFIG, RIG_MSG_TRAJ_CHUNK, RIG_MSG_TRAJ_CHUNK, RIG_MSG_TRAJ_CHUNK,
        RIG_MSG_TRAJ_CHUNK, RIG_MSG_TRAJ_CHUNK, RIG_MSG_START, RIG_MSG_START, RIG_MSG_STOP,
        RIG_MSG_CLEAR_FAULT, RIG_MSG_CLEAR_FAULT, RIG_MSG_SET_POSITION, RIG_MSG_BYE,
        RIG_MSG_STORE_CALIBRATION, RIG_MSG_READ_CALIBRATION};
    if (chance(1)) return RIG_MSG_ESTOP;
    if (chance(2)) return (uint8_t)rnd(); /* anything, MCU types and unknown ones included */
    return weighted[below(sizeof weighted)];
}

static uint16_t pick_seq(void) {
    uint32_t r = below(100);
    if (r < 85) return ++host_seq;
    if (r < 92) return host_seq; /* a retransmission */
    if (r < 97) return (uint16_t)(host_seq - below(40000));
    return (uint16_t)rnd();
}

/* Feed bytes in random pieces. */
static void feed(const uint8_t *b, size_t n) {
    size_t i = 0;
    while (i < n) {
        size_t k = chance(70) ? n - i : 1 + below((uint32_t)(n - i));
        rig_rx(&M, b + i, k);
        i += k;
    }
}

static void one_frame(void) {
    uint8_t payload[300], wire[400];
    uint8_t type = pick_type();
    uint8_t flags = (uint8_t)(chance(85) ? RIG_FLAG_ACK_REQ : (chance(50) ? 0 : rnd()));
    uint16_t seq = pick_seq();
    size_t len = make_payload(type, payload);
    uint32_t kind = below(100);
    int intact = 1; /* the frame arrives as a valid frame (CRC good) */
    if (kind >= 50 && kind < 85) {
        /* body mutations, CRC recomputed by rig_frame_build */
        unsigned muts = 1 + below(3);
        for (unsigned k = 0; k < muts; k++) {
            switch (below(6)) {
            case 0: /* bit flip */
                if (len) payload[below((uint32_t)len)] ^= (uint8_t)(1u << below(8));
                break;
            case 1: /* truncate */
                len = below((uint32_t)len + 1u);
                break;
            case 2: /* extend */
            {
                size_t add = below(40);
                for (size_t i = 0; i < add && len < 250; i++) payload[len++] = (uint8_t)rnd();
                break;
            }
            case 3: /* a chunk's point count */
                if (len > 5) payload[5] = (uint8_t)(chance(50) ? below(40) : rnd());
                break;
            case 4: /* header */
                if (chance(50)) type = (uint8_t)(type ^ (1u << below(8)));
                else flags = (uint8_t)rnd();
                break;
            default: /* a byte */
                if (len) payload[below((uint32_t)len)] = (uint8_t)rnd();
                break;
            }
        }
    }
    size_t n = rig_frame_build(type, flags, seq, payload, len, wire, sizeof wire);
    if (n == 0) FAIL("rig_frame_build refused a %zu-byte payload", len);
    if (kind >= 85 && kind < 95) {
        /* wire corruption: CRC not recomputed */
        intact = 0;
        switch (below(4)) {
        case 0:
            wire[below((uint32_t)n)] ^= (uint8_t)(1u << below(8));
            break;
        case 1:
            n = below((uint32_t)n);
            break;
        case 2:
            wire[below((uint32_t)n)] = (uint8_t)rnd();
            break;
        default: { /* a run of junk in front */
            size_t j = below(40);
            memmove(wire + j, wire, n);
            for (size_t i = 0; i < j; i++) wire[i] = (uint8_t)(1 + below(255));
            n += j;
            break;
        }
        }
    } else if (kind >= 95) {
        intact = 0;
        n = below(sizeof wire);
        for (size_t i = 0; i < n; i++) wire[i] = chance(10) ? 0 : (uint8_t)rnd();
        if (chance(2)) { /* an over-long run */
            uint8_t junk[300];
            memset(junk, 0x5A, sizeof junk);
            rig_rx(&M, junk, sizeof junk);
        }
    }
    int resync = chance(90);
    if (resync) {
        uint8_t zero = 0;
        rig_rx(&M, &zero, 1);
    }
    uint32_t replies_before = replies_seen, dropped_before = M.stats.tx_dropped;
    uint32_t ok_before = M.stats.frames_ok;
    drain(1);
    replies_before = replies_seen;
    feed(wire, n);
    check_mcu();
    int full = chance(95);
    drain(full);
    if (intact && resync && full && M.stats.tx_dropped == dropped_before) {
        uint32_t want = ((flags & RIG_FLAG_ACK_REQ) && type != RIG_MSG_HEARTBEAT) ? 1u : 0u;
        if (M.stats.frames_ok != ok_before + 1u) FAIL("an intact frame was not accepted");
        if (replies_seen - replies_before != want) {
            FAIL("type 0x%02x flags 0x%02x: %u replies, expected %u", type, flags,
                 replies_seen - replies_before, want);
        }
    }
}

int main(int argc, char **argv) {
    unsigned long frames = argc > 1 ? strtoul(argv[1], NULL, 10) : 1000000ul;
    unsigned long seed = argc > 2 ? strtoul(argv[2], NULL, 10) : 1ul;
    rng_state = 0x9E3779B97F4A7C15ULL ^ ((uint64_t)seed * 0xD1B54A32D192ED03ULL);
    if (rng_state == 0) rng_state = 1;
    host_seq = (uint16_t)rnd();
    do_boot();
    unsigned long states[6] = {0}, stuck_for = 0;
    for (iteration = 0; iteration < frames; iteration++) {
        /* a reset now and then, and when a fault condition stays (travel after a drift) */
        if (iteration % 200000 == 199999 || stuck_for > 300) {
            do_boot();
            stuck_for = 0;
        }
        one_frame();
        unsigned t = below(1000) == 0 ? 120 : below(4); /* now and then the FIFO fills */
        for (unsigned k = 0; k < t; k++) {
            do_tick();
            check_mcu();
            if (t < 100) drain(chance(97));
        }
        states[M.state]++;
        stuck_for = (M.state == RIG_STATE_FAULT || M.state == RIG_STATE_ESTOP) ? stuck_for + 1 : 0;
        if (failures > 20) break;
    }
    drain(1);
    add_stats();
    fprintf(stderr,
            "fuzz: iterations in BOOT %lu IDLE %lu RUNNING %lu STOPPING %lu FAULT %lu ESTOP %lu; "
            "frames ok %lu bad %lu, overflows %lu, tx dropped %lu; fault bits seen 0x%03x, "
            "results seen 0x%04x\n",
            states[0], states[1], states[2], states[3], states[4], states[5], total_ok,
            total_bad, total_overflows, total_dropped, fault_bits_seen, results_seen);
    printf("fuzz: %lu frames, %lu failures\n", iteration, failures);
    return failures ? EXIT_FAILURE : EXIT_SUCCESS;
}
