"""Firmware logic of the rig's MCU, as specified in docs/rig-protocol.md, without any I/O.

:class:`McuModel` holds the state machine, the trajectory buffer, the safety checks and
the sensor model (encoder quantisation, load-cell amplifier noise and ADC). It is driven
by :meth:`McuModel.handle` (one decoded host frame) and :meth:`McuModel.tick` (one
telemetry period) and returns the messages the MCU sends. The mechanics come from a
:class:`RigPhysics` callback, so the same firmware runs any plant.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import operator
import random
import secrets
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Protocol

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


class RigPhysics(Protocol):
    """Mechanics of the rig, plugged into the emulator.

    Called once per telemetry period with the commanded input-link position ``x`` (m,
    the ball-screw table, already quantised to whole steps) and the emulator time ``t``
    (s, monotonic from the emulator's start). Returns the true platen position (m) and
    the true force between the table and the input link (N, positive when the table
    pushes). Sensor effects (encoder quantisation, load-cell noise) are added by the MCU
    model, not here.
    """

    def __call__(self, x: float, t: float) -> tuple[float, float]: ...


@dataclass(frozen=True)
class RigHardware:
    """Constants of the emulated rig, reported to the host in HELLO_REPLY."""

    telemetry_hz: int = 1000
    buffer_capacity: int = 2048
    step_nm: int = 200  # 25 000 steps/rev on a 5 mm lead
    enc_nm: int = 1000  # 1 um optical encoder
    load_offset: int = 1500  # ADC counts at zero force: the firmware's default calibration
    load_gain_n: float = 1e-4  # N per ADC count: +-500 N -> +-5 000 000 counts (default)
    adc_min: int = -8_388_608  # 24-bit ADC rails
    adc_max: int = 8_388_607
    load_noise_n: float = 0.2  # rms noise of the load cell and amplifier
    x_origin: float = 0.0  # input position (m) at step count 0 at power-on
    home_x: float | None = None  # reference switch active at x <= home_x (default x_origin)
    fw_version: int = 0x0103
    # the emulated rig's own cell and drive, for bring-up (None: as the default calibration)
    cell_offset: int | None = None  # the cell's true ADC counts at zero force
    cell_gain_n: float | None = None  # the cell's true N per ADC count
    encoder_sign: int = 1  # -1: the encoder counts against the steps (wired reversed)
    drop_steps: tuple[int, int] = (0, 1)  # (n, d): n of every d step pulses are lost

    def __post_init__(self) -> None:
        n, d = self.drop_steps
        if self.encoder_sign not in (1, -1) or not 0 <= n < d:
            raise ValueError(f"encoder_sign must be +-1 and drop_steps (n, d) 0 <= n < d, "
                             f"not {self.encoder_sign}, {self.drop_steps}")

    @property
    def cell(self) -> tuple[int, float]:
        """The cell's true (offset, gain): what tare and span recover."""
        return (self.load_offset if self.cell_offset is None else self.cell_offset,
                self.load_gain_n if self.cell_gain_n is None else self.cell_gain_n)

    @property
    def period(self) -> float:
        """Telemetry (and trajectory point) period, s."""
        return 1.0 / self.telemetry_hz


class Sensors:
    """Encoder and load cell: quantisation, noise, ADC rails and injected sensor faults."""

    def __init__(self, physics: RigPhysics, hw: RigHardware, rng: random.Random) -> None:
        self.physics, self.hw, self.rng = physics, hw, rng
        self.x_origin = hw.x_origin
        self.enc_offset = 0
        self.platen_zero = physics(hw.x_origin, 0.0)[0]
        self.load_stuck = False
        self.enc_stuck = False
        self.spike_n = 0.0
        self.spike_samples = 0
        self._last: tuple[int, int] | None = None
        self.force = 0.0
        self.lost = 0  # step pulses the drive lost since the last rezero (signed)
        self._commanded = 0  # the step count of the last reading
        self._drop_acc = 0

    def x(self, steps: int) -> float:
        """Input position (m) of a step count: where the table is (lost steps included)."""
        return self.x_origin + (steps - self.lost) * self.hw.step_nm / 1e9

    def _lose_steps(self, steps: int) -> None:
        """The drive loses n of every d pulses (RigHardware.drop_steps), counted exactly as
        firmware/sim/sim_rig.c counts them."""
        n, d = self.hw.drop_steps
        delta, self._commanded = steps - self._commanded, steps
        self._drop_acc += abs(delta) * n
        lost, self._drop_acc = divmod(self._drop_acc, d)
        self.lost += lost if delta >= 0 else -lost

    def home_switch(self, steps: int) -> bool:
        """The reference switch: active while the table is at or behind the open position."""
        home = self.hw.x_origin if self.hw.home_x is None else self.hw.home_x
        return self.x(steps) <= home + 1e-12

    def read(self, steps: int, t: float) -> tuple[int, int]:
        """Encoder counts and load-cell raw counts at ``steps`` and time ``t``."""
        self._lose_steps(steps)
        platen, force = self.physics(self.x(steps), t)
        self.force = force  # the true force of the last reading (sim_rig_status.input_force)
        if self.spike_samples > 0:
            force += self.spike_n
            self.spike_samples -= 1
        counts = round((platen - self.platen_zero) / (self.hw.enc_nm / 1e9))
        enc = self.hw.encoder_sign * counts + self.enc_offset
        noisy = force + self.rng.gauss(0.0, self.hw.load_noise_n)
        offset, gain = self.hw.cell
        raw = round(offset + noisy / gain)
        raw = min(max(raw, self.hw.adc_min), self.hw.adc_max)
        if self._last is not None:
            enc = self._last[0] if self.enc_stuck else enc
            raw = self._last[1] if self.load_stuck else raw
        self._last = (enc, raw)
        return enc, raw

    def rezero(self, steps: int, enc_now: int, steps_new: int, enc_new: int) -> None:
        """Redefine counts so that the present position reads (steps_new, enc_new)."""
        self.x_origin = self.x(steps) - steps_new * self.hw.step_nm / 1e9
        self.lost, self._commanded = 0, steps_new
        self.enc_offset += enc_new - enc_now


class McuModel:
    """The MCU's firmware: sessions, commands, trajectory execution, safety, telemetry."""

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

    # --- host frames ----------------------------------------------------------------------

    def handle(self, frame: p.Frame, now: float) -> list[p.Message]:
        """Execute one valid host frame received at ``now``; return the replies. The
        heartbeat watchdog times it by the MCU's clock: the last period's time."""
        self.last_host_rx = now if self._last_tick is None else self._last_tick
        ack_req = bool(frame.flags & p.FLAG_ACK_REQ)  # without it nothing is answered
        if frame.msg_type >= 0x80:  # an MCU -> host type is no command
            replies = [self._ack(frame.seq, p.Result.UNKNOWN_TYPE)] if ack_req else []
            return replies + self._drain()
        try:
            msg = p.parse_message(frame)
        except p.MessageError:
            known = frame.msg_type in p.MESSAGES
            result = p.Result.BAD_LENGTH if known else p.Result.UNKNOWN_TYPE
            return ([self._ack(frame.seq, result)] if ack_req else []) + self._drain()
        if isinstance(msg, p.Heartbeat):
            return self._drain()
        last = self.last_seq
        if isinstance(msg, p.Hello):
            reply = self._execute(msg, frame.seq)
            store = True  # a new host starts at a random seq, whatever the answer
        elif isinstance(msg, (p.EStop, p.Stop)):
            # always executed, a retransmission too (a stop must never be lost to the seq
            # order); an older seq does not re-base the order
            reply = self._execute(msg, frame.seq)
            store = last is None or p.seq_newer(frame.seq, last)
        elif last is not None and frame.seq == last:
            reply, store = self.last_reply, False  # a retransmission: answer, do not redo
        elif last is not None and p.seq_stale(frame.seq, last):
            reply, store = self._ack(frame.seq, p.Result.STALE), False
        else:
            reply, store = self._execute(msg, frame.seq), True
        if store:
            self.last_seq, self.last_reply = frame.seq, reply
        replies = [reply] if reply is not None and ack_req else []
        return replies + self._drain()

    def _execute(self, msg: p.Message, seq: int) -> p.Message:
        if isinstance(msg, p.Hello):
            return self._hello(msg, seq)
        if isinstance(msg, p.EStop):
            self.estop()
            return self._ack(seq, p.Result.OK)
        if not self.session and not isinstance(msg, p.Stop):
            return self._ack(seq, p.Result.NO_SESSION)
        handler: Callable[[p.Message], p.Result] = self._handlers[type(msg)]
        result = handler(self, msg)
        if isinstance(msg, (p.StoreCalibration, p.ReadCalibration)):
            return p.CalibrationReply(*dataclasses.astuple(self._ack(seq, result)), *self.stored)
        return self._ack(seq, result)

    def _hello(self, msg: p.Hello, seq: int) -> p.HelloReply:
        if self.state in MOTION_STATES:
            result = p.Result.BAD_STATE
        elif msg.proto_major != p.PROTO_MAJOR:
            result = p.Result.VERSION_MISMATCH
        else:
            result = p.Result.OK
            self._end_session()  # a new session starts from the stored calibration
            self.session = True
            if self.state == p.State.BOOT:
                self._set_state(p.State.IDLE, p.Reason.COMMAND)
        hw = self.hw
        return p.HelloReply(
            seq, result, self.state, self.sample, len(self.points), self._free(),
            p.PROTO_MAJOR, p.PROTO_MINOR, hw.fw_version, self.boot_id, msg.host_nonce,
            hw.telemetry_hz, round(1e6 * hw.period), p.MAX_CHUNK_POINTS, hw.buffer_capacity,
            hw.step_nm, hw.enc_nm, self.cfg.load_offset, self.cfg.load_gain_n,
            hw.adc_min, hw.adc_max, p.MAX_STEP_DELTA,
        )

    def _config(self, msg: p.Config) -> p.Result:
        if self.state != p.State.IDLE:
            return p.Result.BAD_STATE
        valid = (
            msg.force_limit_n > 0 and msg.steps_min < msg.steps_max and msg.enc_min < msg.enc_max
            and msg.following_error_counts > 0 and msg.load_gain_n >= 0 and msg.decel_steps_s2 > 0
            and 0 < msg.max_step_delta <= p.MAX_STEP_DELTA
            and msg.heartbeat_timeout_ms > 0 and msg.stuck_samples > 0
            and all(math.isfinite(v) for v in (msg.force_limit_n, msg.load_gain_n,
                                                msg.decel_steps_s2))
        )
        # a deceleration below half a Q16 step per period^2 (~7.6 steps/s^2) never stops
        valid = valid and self._stop_dv(msg) > 0
        if not valid:
            return p.Result.BAD_VALUE
        if not (msg.steps_min <= self.steps <= msg.steps_max
                and msg.enc_min <= self.enc <= msg.enc_max):
            return p.Result.OUT_OF_LIMITS  # limits that exclude the present position
        # 1.2: the buffered points must obey the new limits too (rule 7 of TRAJ_CHUNK), or
        # the CONFIG is refused and nothing changes
        refused = self._points_refused(msg, self.steps, self.points)
        if refused != p.Result.OK:
            return refused
        if msg.load_gain_n == 0:  # keep the stored calibration
            msg = dataclasses.replace(msg, load_offset=self.cfg.load_offset,
                                      load_gain_n=self.cfg.load_gain_n)
        self.cfg = msg
        return p.Result.OK

    def _chunk(self, msg: p.TrajChunk) -> p.Result:
        if msg.first_index == 0 and self.state == p.State.IDLE:
            self._clear_trajectory()  # index 0 starts a new trajectory
        if self.state not in (p.State.IDLE, p.State.RUNNING) or not self.accepting:
            return p.Result.BAD_STATE
        if msg.first_index + len(msg.points) <= self.next_index:
            return p.Result.OK  # already have these points (a late duplicate)
        if msg.first_index != self.next_index:
            return p.Result.SEQUENCE_GAP
        if self.final_received:
            return p.Result.BAD_STATE
        if len(msg.points) > self._free():
            return p.Result.NO_SPACE
        prev = self.points[-1][0] if self.points else self.steps
        refused = self._points_refused(self.cfg, prev, msg.points)
        if refused != p.Result.OK:
            return refused
        self.points.extend(msg.points)
        self.next_index += len(msg.points)
        self.final_received = msg.final
        return p.Result.OK

    @staticmethod
    def _points_refused(cfg: p.Config, prev: int,
                        points: Iterable[tuple[int, int]]) -> p.Result:
        """Rule 7 of TRAJ_CHUNK under ``cfg``, from step count ``prev``: OUT_OF_LIMITS for a
        point outside [steps_min, steps_max], BAD_VALUE for a jump above max_step_delta,
        the first failure in order; OK when every point passes."""
        for steps, _ in points:
            if not cfg.steps_min <= steps <= cfg.steps_max:
                return p.Result.OUT_OF_LIMITS
            if abs(steps - prev) > cfg.max_step_delta:
                return p.Result.BAD_VALUE
            prev = steps
        return p.Result.OK

    def _start(self, _msg: p.Start) -> p.Result:
        if self.faults:
            return p.Result.FAULT_ACTIVE
        if self.state != p.State.IDLE:
            return p.Result.BAD_STATE
        if not self.points:
            return p.Result.EMPTY
        self.driver_enabled = True
        self._same_load = 0  # the run's first sample counts 1
        self._set_state(p.State.RUNNING, p.Reason.COMMAND)
        return p.Result.OK

    def _stop(self, _msg: p.Stop) -> p.Result:
        if self.state == p.State.RUNNING:
            self._begin_stop(p.State.IDLE, p.Reason.COMMAND)
        if self.state in (p.State.IDLE, p.State.STOPPING):
            self._discard_buffer()
        return p.Result.OK

    def _clear_fault(self, _msg: p.ClearFault) -> p.Result:
        if self.state not in (p.State.FAULT, p.State.ESTOP):
            return p.Result.OK
        present = self._check_sensors(apply=False)
        if present or self._board_present:
            return p.Result.FAULT_ACTIVE
        self.faults = p.Fault.NONE
        self._clear_trajectory()
        self._set_state(p.State.IDLE, p.Reason.COMMAND)
        return p.Result.OK

    def _set_position(self, msg: p.SetPosition) -> p.Result:
        if self.state != p.State.IDLE:
            return p.Result.BAD_STATE
        self.sensors.rezero(self.steps, self.enc, msg.steps, msg.enc)
        self.steps, self.enc = msg.steps, msg.enc
        self.referenced = True
        self._clear_trajectory()
        return p.Result.OK

    def _bye(self, _msg: p.Bye) -> p.Result:
        if self.state in MOTION_STATES:
            return p.Result.BAD_STATE
        self._end_session()
        if self.state == p.State.IDLE:
            self._set_state(p.State.BOOT, p.Reason.COMMAND)
        return p.Result.OK

    def _store_calibration(self, msg: p.StoreCalibration) -> p.Result:
        """1.3: the calibration to non-volatile memory (record cal_seq + 1) and into use."""
        if self.state != p.State.IDLE:
            return p.Result.BAD_STATE
        if not (math.isfinite(msg.load_gain_n) and msg.load_gain_n > 0
                and self.hw.adc_min < msg.load_offset < self.hw.adc_max):
            return p.Result.BAD_VALUE
        self.nvm = (self.stored[0] + 1, msg.load_offset, msg.load_gain_n)
        self.cfg = self._stored_calibration(self.cfg)
        return p.Result.OK

    def _read_calibration(self, _msg: p.ReadCalibration) -> p.Result:
        return p.Result.OK

    _handlers = {
        p.Config: _config, p.TrajChunk: _chunk, p.Start: _start, p.Stop: _stop,
        p.ClearFault: _clear_fault, p.SetPosition: _set_position, p.Bye: _bye,
        p.StoreCalibration: _store_calibration, p.ReadCalibration: _read_calibration,
    }

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

    # --- one telemetry period -------------------------------------------------------------

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


class ModelMcu:
    """:class:`McuModel` behind the byte-level MCU interface of the rig emulator.

    The interface :class:`hil.emulators.firmware.FirmwareMcu` (the C firmware) also has:
    :meth:`receive` host bytes and :meth:`tick` once per period return the wire frames the
    MCU sent (each ending in ``b"\\x00"``, its header seq counting every frame), plus the
    rig's fault inputs. Attributes not defined here are the model's (``mcu.steps``).
    """

    def __init__(self, physics: RigPhysics, hw: RigHardware, seed: int) -> None:
        self.model = McuModel(physics, hw, random.Random(seed))
        self._decoder = p.FrameDecoder()
        self._seq = 0

    def __getattr__(self, name: str) -> object:
        return getattr(self.model, name)

    def _wire(self, messages: list[p.Message]) -> list[bytes]:
        out = []
        for msg in messages:
            out.append(p.encode_message(msg, self._seq))
            self._seq = (self._seq + 1) & 0xFFFF
        return out

    def receive(self, data: bytes, now: float) -> list[bytes]:
        """Feed bytes from the host received at ``now`` (s); the frames the MCU sent."""
        out: list[bytes] = []
        for frame in self._decoder.feed(data):
            out += self._wire(self.model.handle(frame, now))
        return out

    def tick(self, now: float) -> list[bytes]:
        """One period at ``now`` (s): its FAULT/STATE frames, then its TELEMETRY."""
        return self._wire(self.model.tick(now))

    def reset(self) -> None:
        """MCU reset: new boot id, no session, counts at 0."""
        self.model.boot()

    def link_lost(self) -> None:
        """The host vanished (USB detach, DTR dropped): controlled stop, session ended."""
        self.model.link_lost()

    def press_stop(self) -> None:
        """The operator's stop button: ESTOP."""
        self.model.estop()

    def board_fault(self, bits: int, detail: int = 0) -> None:
        """What a board's own checks report from the next reading on (0: none)."""
        self.model.board_faults = (bits, detail)

    def force_spike(self, newtons: float, samples: int) -> None:
        """Add ``newtons`` to the next ``samples`` load-cell readings."""
        self.model.sensors.spike_n, self.model.sensors.spike_samples = newtons, samples

    def stick_load(self, on: bool) -> None:
        """Freeze (True) or free the load-cell reading."""
        self.model.sensors.load_stuck = on

    def stick_encoder(self, on: bool) -> None:
        """Freeze (True) or free the encoder reading."""
        self.model.sensors.enc_stuck = on
