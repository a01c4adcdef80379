"""One telemetry period of the MCU firmware, without any I/O: the heartbeat watchdog, the
trajectory's execution, the controlled stop in Q16 fixed point, and the checks of §8 on the
period's sensor readings (docs/rig-protocol-behaviour.md).
"""

from __future__ import annotations

import functools
import operator

from hil.emulators.mcu_core import BOARD_FAULTS, MOTION_STATES, McuCore
from hil.link import protocol as p


class McuMotion(McuCore):
    """The MCU's state (:class:`McuCore`) advanced one telemetry period at a time."""

    def tick(self, now: float) -> list[p.Message]:
        """Advance one period at ``now`` (s): watchdog, motion, sensors, checks; return the
        period's events and its telemetry, stamped in us since the MCU's boot."""
        if self._boot_time is None:
            self._boot_time = now
        self._last_tick = now
        silence_ms = round(1e3 * (now - self.last_host_rx))  # whole periods since the frame
        if self.session and silence_ms > self.cfg.heartbeat_timeout_ms:
            self._fault(p.Fault.HEARTBEAT_LOST, silence_ms, self.cfg.heartbeat_timeout_ms)
        before = self.steps
        if self.state != p.State.RUNNING:
            self._last_move = 0  # a stop from rest starts at rest, not at an old run's speed
        if self.state == p.State.RUNNING:
            self._run_step()
        elif self.state == p.State.STOPPING:
            self._decelerate()
        self._moved = self.steps != before
        prev_raw = self.load_raw
        self.enc, self.load_raw = self.sensors.read(self.steps, now)
        self._same_load = self._same_load + 1 if self.load_raw == prev_raw else 1
        if self.state in (p.State.IDLE, *MOTION_STATES):
            self._check_sensors(apply=True)
        bits, detail = self.board_faults
        self._board_present = bits & BOARD_FAULTS  # of the last reading, as the firmware
        if self._board_present and self.state != p.State.BOOT:  # in bit order
            self._faults([(f, detail, 0) for f in p.Fault if f & self._board_present])
        t_us = round((now - self._boot_time) * 1e6) & 0xFFFFFFFF
        if self.session:  # no host, no telemetry (docs/rig-protocol.md, section 5)
            self._out.append(self._telemetry(t_us))
        self.sample = (self.sample + 1) & 0xFFFFFFFF
        return self._drain()

    def _run_step(self) -> None:
        if self.points:
            steps, self.expected_enc = self.points.popleft()
            self._last_move = steps - self.steps
            self.steps = steps
            self.exec_index += 1
        elif self.final_received:
            self._last_move = 0
            self.expected_enc = p.NO_CHECK
            self._set_state(p.State.IDLE, p.Reason.RUN_COMPLETE)
        else:
            self._fault(p.Fault.BUFFER_UNDERRUN, self.exec_index, self.next_index)

    def _decelerate(self) -> None:
        """One period of a controlled stop, in Q16 fixed point (1/65536 step), so that every
        implementation of the protocol rounds alike; the first period at zero speed is the
        standstill, also for a stop begun at rest."""
        dv = self._stop_dv(self.cfg)
        speed = max(abs(self._speed_q16) - dv, 0)
        self._speed_q16 = speed if self._speed_q16 >= 0 else -speed
        pos = self._pos_q16 + self._speed_q16
        target = (pos + 32768) >> 16  # round half up
        if not self.cfg.steps_min <= target <= self.cfg.steps_max:
            self._speed_q16 = 0
            bound = self.cfg.steps_min if target < self.cfg.steps_min else self.cfg.steps_max
            self._fault(p.Fault.TRAVEL_LIMIT, target, bound)
            return
        self._pos_q16, self.steps = pos, target
        if self._speed_q16 == 0:
            self._set_state(self._stop_target, p.Reason.STOP_COMPLETE)

    def _stop_dv(self, cfg: p.Config) -> int:
        """A controlled stop's speed decrement per period, in 1/65536 step per period."""
        return round(cfg.decel_steps_s2 * self.hw.period**2 * 65536)

    def _check_sensors(self, *, apply: bool) -> p.Fault:
        """Evaluate the limits on the present readings; latch every failing one when
        ``apply`` (in bit order, each new bit with its FAULT frame)."""
        cfg = self.cfg
        force = (self.load_raw - cfg.load_offset) * cfg.load_gain_n
        steps_bound = cfg.steps_min if self.steps < cfg.steps_min else cfg.steps_max
        enc_bound = cfg.enc_min if self.enc < cfg.enc_min else cfg.enc_max
        checks = [
            (p.Fault.FORCE_LIMIT, abs(force) > cfg.force_limit_n,
             round(force), round(cfg.force_limit_n)),
            (p.Fault.TRAVEL_LIMIT, not cfg.steps_min <= self.steps <= cfg.steps_max,
             self.steps, steps_bound),
            (p.Fault.TRAVEL_LIMIT, not cfg.enc_min <= self.enc <= cfg.enc_max,
             self.enc, enc_bound),
        ]
        if self.state == p.State.RUNNING:
            error = self.enc - self.expected_enc
            checks.append((p.Fault.FOLLOWING_ERROR,
                           self.expected_enc != p.NO_CHECK
                           and abs(error) > cfg.following_error_counts,
                           error, cfg.following_error_counts))
        checks.append((p.Fault.LOAD_SATURATED,
                       self.load_raw <= self.hw.adc_min or self.load_raw >= self.hw.adc_max,
                       self.load_raw, self.hw.adc_max))
        if self.state == p.State.RUNNING:
            checks.append((p.Fault.LOAD_STUCK, self._same_load >= cfg.stuck_samples,
                           self._same_load, cfg.stuck_samples))
        failing: list[tuple[p.Fault, int, int]] = []
        for fault, active, value, limit in checks:
            if active and not any(f == fault for f, _, _ in failing):
                failing.append((fault, value, limit))
        if apply:
            self._faults(failing)
        return functools.reduce(operator.or_, (f for f, _, _ in failing), p.Fault.NONE)
