"""The MCU firmware's state, without any I/O: boot, session, stored calibration, trajectory
buffer, faults and the state machine, and the replies built from them.

:class:`McuCore` is the base of the firmware model (docs/rig-protocol.md):
:class:`hil.emulators.mcu_motion.McuMotion` adds the telemetry period,
:class:`hil.emulators.mcu_model.McuModel` the host's commands.
"""

from __future__ import annotations

import dataclasses
import random
import secrets
from collections import deque

from hil.emulators.rig_hardware import RigHardware, RigPhysics, Sensors
from hil.link import protocol as p

# faults that halt stepping at once; the others (underrun, heartbeat) decelerate first
HALTING_FAULTS = (
    p.Fault.FORCE_LIMIT | p.Fault.TRAVEL_LIMIT | p.Fault.FOLLOWING_ERROR
    | p.Fault.LOAD_SATURATED | p.Fault.LOAD_STUCK | p.Fault.DRIVER | p.Fault.INTERNAL
)
#: The board's own faults (firmware/board/nucleo_inputs.c): its sensing, timing or wiring can
#: no longer be trusted, so the driver is de-energised at once (stop category 0). The other
#: halts hold position: a stepper without current could be back-driven by the clamp.
BOARD_FAULTS = (p.Fault.INTERNAL | p.Fault.OVERTRAVEL | p.Fault.LOAD_ADC | p.Fault.CLOCK
                | p.Fault.STOP_CHAIN)
HALTING_FAULTS |= BOARD_FAULTS
MOTION_STATES = (p.State.RUNNING, p.State.STOPPING)


class McuCore:
    """The MCU's state: sessions, calibration, trajectory buffer, faults, state changes."""

    def __init__(self, physics: RigPhysics, hw: RigHardware, rng: random.Random) -> None:
        self.hw, self.rng = hw, rng
        self.sensors = Sensors(physics, hw, rng)
        self._out: list[p.Message] = []  # events and telemetry not yet returned
        self.steps = 0
        self.enc, self.load_raw = self.sensors.read(0, 0.0)
        self.nvm: tuple[int, int, float] | None = None  # (cal_seq, offset, gain): survives boot
        self.boot()

    # --- lifecycle ------------------------------------------------------------------------

    def boot(self) -> None:
        """Power-on or reset: new boot id, no session, counts restart at zero, unreferenced.

        The boot id comes from the OS's entropy (a firmware's hardware RNG), not from the
        seeded fault generator, so every emulator start and every reset gets a new one.
        """
        self.sensors.rezero(self.steps, self.enc, 0, 0)
        self.steps, self.enc = 0, 0
        previous = getattr(self, "boot_id", 0)
        self.boot_id = previous
        while self.boot_id in (0, previous):
            self.boot_id = secrets.randbits(32)
        self.referenced = False
        self.state = p.State.BOOT
        self.session = False
        self.faults = p.Fault.NONE
        self.cfg = self._stored_calibration(p.Config())
        self.sample = 0
        self._boot_time: float | None = None  # the first tick's time: t_us = 0
        self._last_tick: float | None = None  # the MCU's clock: the last period's time
        self.last_seq: int | None = None
        self.last_reply: p.Message | None = None
        self.last_host_rx = 0.0
        self.driver_enabled = False
        self.board_faults = (0, 0)  # (bits, detail) a board's own checks report: injected
        self._board_present = 0  # those of the last reading
        self._clear_trajectory()
        self._last_move = 0  # steps of the last period's move: a controlled stop's speed
        self._speed_q16 = 0  # a controlled stop's speed and position, in 1/65536 step
        self._pos_q16 = 0
        self._stop_target = p.State.IDLE
        self._same_load = 0  # consecutive samples with a bit-identical load reading
        self._moved = False  # steps changed in this period (telemetry flag MOVING)

    @property
    def stored(self) -> tuple[int, int, float]:
        """(cal_seq, offset, gain) in non-volatile memory; (0, defaults) when none is."""
        return self.nvm or (0, self.hw.load_offset, self.hw.load_gain_n)

    def _stored_calibration(self, cfg: p.Config) -> p.Config:
        """``cfg`` with the load-cell calibration kept in the MCU's non-volatile memory."""
        _, offset, gain = self.stored
        return dataclasses.replace(cfg, load_offset=offset, load_gain_n=gain)

    def _end_session(self) -> None:
        """A session ends (BYE, link loss) or a new one opens: a CONFIG calibration
        override was for that session only; the limits stay until the next CONFIG."""
        self.session = False
        self.cfg = self._stored_calibration(self.cfg)

    def _clear_trajectory(self) -> None:
        self.points: deque[tuple[int, int]] = deque()
        self.next_index = 0  # index the next chunk must start at
        self.exec_index = 0  # points executed so far
        self.final_received = False
        self.accepting = True  # False once a stop or fault discarded the trajectory
        self.expected_enc = p.NO_CHECK

    def estop(self) -> None:
        """Halt stepping now and disable the driver."""
        self._speed_q16 = 0
        self.driver_enabled = False
        self._discard_buffer()
        if not self.faults & p.Fault.ESTOP:  # one FAULT frame per latching, not per repeat
            self._latch(p.Fault.ESTOP, 0, 0)
        if self.state != p.State.ESTOP:
            self._set_state(p.State.ESTOP, p.Reason.FAULT)

    def link_lost(self) -> None:
        """The host vanished (USB detach, or DTR dropped): controlled stop, end the session."""
        self._end_session()
        if self.state == p.State.RUNNING:
            self._begin_stop(p.State.IDLE, p.Reason.LINK_LOST)
    # --- faults and state -----------------------------------------------------------------

    def _fault(self, fault: p.Fault, value: int, limit: int) -> None:
        self._faults([(fault, value, limit)])

    def _faults(self, found: list[tuple[p.Fault, int, int]]) -> None:
        """Latch the new bits of a period (one FAULT frame each, in the order found), then
        react once to all of them: a halt if any halts, else a controlled stop."""
        fault = p.Fault.NONE
        for bit, value, limit in found:
            if not bit & self.faults:
                self._latch(bit, value, limit)
                fault |= bit
        if not fault:
            return
        if fault & p.Fault.FOLLOWING_ERROR:
            self.referenced = False  # the encoder may have missed counts: re-home
        if fault & BOARD_FAULTS:
            self.driver_enabled = False
        if fault & HALTING_FAULTS:
            self._speed_q16 = 0
            self._discard_buffer()
            if self.state != p.State.FAULT:
                self._set_state(p.State.FAULT, p.Reason.FAULT)
        elif self.state == p.State.RUNNING:
            self._begin_stop(p.State.FAULT, p.Reason.FAULT)
        elif self.state == p.State.STOPPING:
            self._stop_target = p.State.FAULT
        elif self.state == p.State.IDLE:
            self._set_state(p.State.FAULT, p.Reason.FAULT)

    def _latch(self, fault: p.Fault, value: int, limit: int) -> None:
        self.faults |= fault
        clip = lambda v: max(min(int(v), 2**31 - 1), -(2**31))  # noqa: E731
        self._emit(p.FaultReport(fault, self.sample, self.state, clip(value), clip(limit)))

    def _begin_stop(self, target: p.State, reason: p.Reason) -> None:
        self._discard_buffer()
        self._stop_target = target
        self._pos_q16, self._speed_q16 = self.steps << 16, self._last_move << 16
        self._set_state(p.State.STOPPING, reason)

    def _discard_buffer(self) -> None:
        self.points.clear()
        self.accepting = False
        self.final_received = False
        self.expected_enc = p.NO_CHECK

    def _set_state(self, new: p.State, reason: p.Reason) -> None:
        old, self.state = self.state, new
        self._emit(p.StateChange(old, new, reason, self.exec_index, self.sample))

    def _emit(self, msg: p.Message) -> None:
        self._out.append(msg)

    def _drain(self) -> list[p.Message]:
        out, self._out = self._out, []
        return out

    # --- replies --------------------------------------------------------------------------

    def _free(self) -> int:
        return self.hw.buffer_capacity - len(self.points)

    def _ack(self, seq: int, result: p.Result) -> p.Ack:
        return p.Ack(seq, result, self.state, self.sample, len(self.points), self._free())

    def _telemetry(self, t_us: int) -> p.Telemetry:
        flags = p.TelemetryFlag.NONE
        if self._moved:
            flags |= p.TelemetryFlag.MOVING
        if self.final_received:
            flags |= p.TelemetryFlag.FINAL_RECEIVED
        if not self.hw.adc_min < self.load_raw < self.hw.adc_max:
            flags |= p.TelemetryFlag.LOAD_SATURATED
        if self.session:
            flags |= p.TelemetryFlag.SESSION
        if self.driver_enabled:
            flags |= p.TelemetryFlag.DRIVER_ENABLED
        if self.sensors.home_switch(self.steps):
            flags |= p.TelemetryFlag.HOME_SWITCH
        if self.referenced:
            flags |= p.TelemetryFlag.REFERENCED
        return p.Telemetry(
            self.boot_id, self.sample, t_us & 0xFFFFFFFF, self.steps, self.enc, self.load_raw,
            self.exec_index, len(self.points), int(self.faults), self.state, int(flags),
        )
