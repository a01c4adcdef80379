/* The rig MCU's portable core (rig_core.h): docs/rig-protocol.md v1.1 with the decisions of
 * docs/rig-protocol.md, behaving on the wire as hil/emulators/mcu_model.py (corrected) does.
 *
 * Structure: rig_rx() -> framing (rig_frame.c) -> handle_frame() (rig_rx.c): type and
 * length checks, the seq rules of section 6, then one command (rig_commands.c); its reply is
 * queued first and the FAULT and STATE frames it caused after it. rig_tick() (rig_tick.c):
 * heartbeat watchdog, motion (one hal_step), inputs (one hal_read), the checks of section 8
 * (rig_state.c), telemetry. Everything the MCU sends goes through rig_tx_frame() (rig_tx.c)
 * into a FIFO of whole frames. rig_core_internal.h declares what the files share; this file
 * holds boot and the CONFIG deceleration.
 *
 * Arithmetic rules: counts are int32 on the wire; differences and Q16 values are computed in
 * int64 so nothing overflows; wrapping u32 sums (offsets, time) are done in uint32_t. The
 * force check is single precision (the target's FPU). No heap, no libc but memcpy/memset,
 * no function pointers: dispatch is a switch on the (checked) type byte.
 *
 * Choices where the spec and the model are silent or disagree without a rule of docs/rig-protocol.md
 * (each is also commented where it is made):
 *  - ESTOP (command or stop input) sends a FAULT frame only when its bit is new (section 8);
 *    the model's estop() sends one for every ESTOP.
 *  - The stop input acts in every state, BOOT included (as the model's injected estop());
 *    the driver alarm latches DRIVER in every state but BOOT and keeps ESTOP as the state.
 *    CLEAR_FAULT's "present condition" list is section 8's (not the stop input or alarm).
 *  - All FAULT frames of a period's checks carry the period's state and precede its STATE
 *    frame (docs/rig-protocol-behaviour.md: "before the period's STATE").
 *  - A halting fault found after the period's hal_step calls hal_step_halt() and the count
 *    not emitted is taken off `steps` before the telemetry (the count actually output).
 *  - A controlled stop starts from the present step rate: vel_q16 is the last period's
 *    move while running and is zeroed by a halt, ESTOP, the end of a run or of a ramp (the
 *    model keeps its _last_move through those, so a STOP or underrun before the first
 *    period of a later run would ramp from the old run's speed).
 *  - A dropped frame (tx FIFO full) still uses its MCU seq, so the host sees the gap.
 *  - Every accepted HELLO restores the stored calibration (docs/rig-protocol.md).
 *  - `steps` count from the boot position (the core's own output); `enc` from the first
 *    reading after boot. hal_driver_enable(false) is called at the first tick (the flag
 *    DRIVER_ENABLED is clear from boot).
 */
#include "rig_core_internal.h"

/* docs/rig-protocol-behaviour.md (section 8): dv = round(decel * 1e-6 * 65536), from the f32 value
 * in double, once at CONFIG. The double operations are the model's, in its order: (double)decel is
 * exact, the product with the double nearest 1e-6 is correctly rounded (IEEE-754, as in Python),
 * and * 65536 is exact (a power of two), so the result is bit-identical to the model's before the
 * final rounding, which is Python's round() (half to even). For the default 5e6: 5e6 is exact in
 * binary32; 5e6 * 1e-6 rounds to exactly 5.0 in double (the error of the constant 1e-6, ~4.5e-23,
 * times 5e6 is ~2.3e-16, below half an ulp of 5.0, 4.4e-16); 5.0 * 65536 = 327680.0 exactly -> dv
 * = 327680 (5 steps per period per period = 1 m/s^2 at 1 ms). On the Cortex-M4F double is done in
 * software (libgcc), once per CONFIG. */
int64_t rig_stop_dv_q16(float decel_steps_s2) {
    double x = (double)decel_steps_s2 * 1e-6 * 65536.0;
    if (!(x > 0.0)) return 0;
    if (x >= 4611686018427387904.0) return 4611686018427387904LL; /* 2^62: a dead stop */
    int64_t i = (int64_t)x;
    double frac = x - (double)i; /* exact: x < 2^62 and x >= 2^53 is an integer */
    if (frac > 0.5 || (frac == 0.5 && (i & 1) != 0)) i += 1;
    return i;
}

/* ---- boot ------------------------------------------------------------------------------ */

static void default_config(rig_config *c, rig_calibration cal) {
    c->force_limit_n = 400.0f;
    c->steps_min = -50000;
    c->steps_max = 400000;
    c->enc_min = -20000;
    c->enc_max = 200000;
    c->following_error_counts = 1000;
    c->load_offset = cal.load_offset;
    c->load_gain_n = cal.load_gain_n;
    c->decel_steps_s2 = 5e6f;
    c->max_step_delta = 250;
    c->heartbeat_timeout_ms = 250;
    c->stuck_samples = 200;
}

void rig_boot(rig_mcu *m, uint32_t boot_id, rig_calibration stored) {
    memset(m, 0, sizeof *m);
    m->boot_id = boot_id;
    m->stored = stored;
    m->state = RIG_STATE_BOOT;
    default_config(&m->cfg, stored);
    m->stop_dv_q16 = rig_stop_dv_q16(m->cfg.decel_steps_s2);
    m->driver_applied = 0xFF; /* unknown: the first tick tells the driver (off) */
    m->stop_target = RIG_STATE_IDLE;
    rig_clear_trajectory(m);
}
