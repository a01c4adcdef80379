"""Firmware logic of the rig's MCU, as specified in docs/rig-protocol.md, without any I/O.

:class:`McuModel` holds the state machine, the trajectory buffer, the safety checks and
the sensor model (encoder quantisation, load-cell amplifier noise and ADC). It is driven
by :meth:`McuModel.handle` (one decoded host frame) and :meth:`McuModel.tick` (one
telemetry period) and returns the messages the MCU sends. The mechanics come from a
:class:`RigPhysics` callback, so the same firmware runs any plant.

The model is in layers, each a module: the rig's constants, mechanics and sensors
(:mod:`hil.emulators.rig_hardware`), the firmware's state and replies
(:mod:`hil.emulators.mcu_core`), one telemetry period (:mod:`hil.emulators.mcu_motion`),
and here the host's commands and :class:`ModelMcu`, the byte-level MCU of the emulator.
This module is the entry: the rig's names are imported from here.
"""

from __future__ import annotations

import dataclasses
import math
import random
from collections.abc import Callable, Iterable

from hil.emulators.mcu_core import MOTION_STATES
from hil.emulators.mcu_motion import McuMotion
from hil.emulators.rig_hardware import RigHardware, RigPhysics, Sensors
from hil.link import protocol as p

__all__ = ["McuModel", "ModelMcu", "RigHardware", "RigPhysics", "Sensors"]


class McuModel(McuMotion):
    """The MCU's firmware: sessions, commands, trajectory execution, safety, telemetry."""

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
