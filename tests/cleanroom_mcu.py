"""The clean-room MCU of the clamp test rig, the firmware logic without I/O: bytes in,
frames out, one ``tick`` per period (tests/cleanroom_rig.py says how it was written and
which readings of docs/rig-protocol.md it takes). Its state, the helpers the commands
(:mod:`cleanroom_commands`) share, and the period: step output, sensor reading, safety
checks, FAULT/STATE and TELEMETRY."""

from __future__ import annotations

import math
import os
import random
import struct
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from cleanroom_commands import Commands, Config, Run
from cleanroom_wire import (
    ACK_FMT,
    ADC_MAX,
    ADC_MIN,
    BOOT,
    BUFFER_CAPACITY,
    ENC_NM,
    ESTOP,
    F_BOARD,
    F_FOLLOWING,
    F_FORCE,
    F_HEARTBEAT,
    F_SATURATED,
    F_STUCK,
    F_TRAVEL,
    F_UNDERRUN,
    FAULT,
    FAULT_FMT,
    FAULT_MSG,
    FL_DRIVER,
    FL_FINAL,
    FL_HOME,
    FL_MOVING,
    FL_REFERENCED,
    FL_SATURATED,
    FL_SESSION,
    IDLE,
    NO_CHECK,
    PERIOD_S,
    PERIOD_US,
    R_COMMAND,
    R_FAULT,
    R_RUN_COMPLETE,
    R_STOP_COMPLETE,
    RUNNING,
    STATE_FMT,
    STATE_MSG,
    STATE_NAMES,
    STEP_NM,
    STOPPING,
    STORED_LOAD_GAIN,
    STORED_LOAD_OFFSET,
    TELEMETRY,
    TELEMETRY_FMT,
    frame,
)


@dataclass
class Mcu(Commands):
    """The MCU of the rig: protocol, state machine, trajectory, safety checks.

    physics(x_m, t_s) -> (platen_m, force_N) is called once per period with the
    commanded table position; x_open is the table position at power-on (step 0).
    """

    physics: Callable[[float, float], tuple[float, float]]
    x_open: float
    noise_n: float = 0.2
    future: bool = False  # act as the next minor version would (section 10, item 2)
    seed: int | None = None
    out: list[bytes] = field(default_factory=list)
    runs: list[Run] = field(default_factory=list)
    log: deque[tuple[Any, ...]] = field(default_factory=lambda: deque(maxlen=4000))
    stats: dict[str, int] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.rng = random.Random(self.seed)
        self.boot_id = int.from_bytes(os.urandom(4), "little") or 1
        self.sample = 0  # index of the next telemetry sample
        self.state = BOOT
        self.session = False
        self.faults = 0
        self.cfg = Config()
        self.nvm: dict[str, Any] = {"seq": 0, "offset": STORED_LOAD_OFFSET,
                                    "gain": STORED_LOAD_GAIN}  # non-volatile: 1.3
        self.load_offset, self.load_gain = self.nvm["offset"], self.nvm["gain"]
        self.pos = 0.0  # table position in steps since power-on (float for the stop ramp)
        self.rate = 0.0  # steps per period of the present period
        self.steps_off = 0  # reported steps = round(pos) + steps_off
        self.enc_off = 0  # reported enc = encoder counts since power-on + enc_off
        self.referenced = False
        self.platen0: float | None = None
        self.enc_raw = 0  # encoder counts since power-on, last reading
        self.load_raw = STORED_LOAD_OFFSET
        self.stuck_count = 0
        # trajectory
        self.points: deque[tuple[int, int]] = deque()
        self.next_index = 0
        self.exec_index = 0
        self.final = False
        self.discarded = False
        self.last_point: int | None = None
        # command bookkeeping
        self.mseq = 0
        self.last_seq: int | None = None
        self.last_reply: tuple[int, bytes] | None = None
        self.last_rx = 0.0
        self.rx = bytearray()
        self.rx_skip = False
        self.run: Run | None = None

    # -- helpers -----------------------------------------------------------------------

    def _count(self, key: str) -> None:
        self.stats[key] = self.stats.get(key, 0) + 1

    def _send(self, msg_type: int, payload: bytes) -> None:
        if self.future:
            payload += b"\x5a\xa5\x00\x01"  # a later minor version's appended fields
        self.out.append(frame(msg_type, 0, self.mseq, payload))
        self.mseq = (self.mseq + 1) & 0xFFFF

    @property
    def steps(self) -> int:
        """Present step count (commanded table position), as reported."""
        return round(self.pos) + self.steps_off

    @property
    def enc(self) -> int:
        """Present encoder count, as reported."""
        return self.enc_raw + self.enc_off

    @property
    def force(self) -> float:
        """Force from the last reading with the calibration in use, N."""
        return (self.load_raw - self.load_offset) * self.load_gain

    def _set_state(self, new: int, reason: int) -> None:
        if new != self.state:
            self.log.append((self.sample, "state", STATE_NAMES[self.state], STATE_NAMES[new],
                             reason))
            self._send(STATE_MSG, STATE_FMT.pack(self.state, new, reason,
                                                 self.exec_index, self.sample))
            self.state = new

    def _latch(self, bit: int, value: float, limit: float) -> bool:
        """Latch a fault bit; sends FAULT if it is new. True if it was new."""
        if self.faults & bit:
            return False
        self.faults |= bit
        self.log.append((self.sample, "fault", bit, value, limit))
        self._send(FAULT_MSG, FAULT_FMT.pack(bit, self.sample, self.state,
                                             _i32(value), _i32(limit)))
        return True

    def _discard(self) -> None:
        self.points.clear()
        self.discarded = True

    def _halt(self, to: int = FAULT) -> None:
        self.rate = 0.0
        self._discard()
        self._set_state(to, R_FAULT if to == FAULT else R_COMMAND)

    def _controlled_stop(self, reason: int) -> None:
        self._discard()
        self._set_state(STOPPING, reason)

    def _ack(self, seq: int, result: int) -> bytes:
        level = len(self.points)
        return ACK_FMT.pack(seq, result, self.state, self.sample, level,
                            BUFFER_CAPACITY - level)

    def _conditions_present(self) -> int:
        """Fault bits whose condition holds on the last readings."""
        bits = 0
        if abs(self.force) > self.cfg.force_limit_n:
            bits |= F_FORCE
        if not (self.cfg.steps_min <= self.steps <= self.cfg.steps_max
                and self.cfg.enc_min <= self.enc <= self.cfg.enc_max):
            bits |= F_TRAVEL
        if not ADC_MIN < self.load_raw < ADC_MAX:
            bits |= F_SATURATED
        return bits

    # -- the period --------------------------------------------------------------------

    def tick(self, now: float) -> None:
        """One period: step output, sensor reading, checks, FAULT/STATE, TELEMETRY."""
        executed: tuple[int, int] | None = None
        underrun = False
        if self.state == RUNNING:
            if self.points:
                executed = self.points.popleft()
                target = executed[0] - self.steps_off
                self.rate = target - self.pos
                self.pos = float(target)
                self.exec_index += 1
            elif not self.final:
                underrun = True
        if self.state == STOPPING or underrun:
            self._ramp()
        elif executed is None:
            self.rate = 0.0
        # sensors, latched together after the step output of this period
        t_s = self.sample * PERIOD_S
        platen, force = self.physics(self.x_open + round(self.pos) * STEP_NM * 1e-9, t_s)
        if self.platen0 is None:
            self.platen0 = platen
        self.enc_raw = round((platen - self.platen0) * 1e9 / ENC_NM)
        noise = self.rng.gauss(0.0, self.noise_n) if self.noise_n > 0 else 0.0
        raw = round(STORED_LOAD_OFFSET + (force + noise) / STORED_LOAD_GAIN)
        raw = min(max(raw, ADC_MIN), ADC_MAX)
        self.stuck_count = self.stuck_count + 1 if raw == self.load_raw else 1
        self.load_raw = raw
        self._checks(executed, underrun, now)
        if self.state == RUNNING and not self.points and self.final:
            self._set_state(IDLE, R_RUN_COMPLETE)
        if self.state == STOPPING and self.rate == 0.0:
            if self.faults:
                self._set_state(FAULT, R_FAULT)
            else:
                self._set_state(IDLE, R_STOP_COMPLETE)
        self._telemetry()
        if self.run is not None and self.state not in (RUNNING, STOPPING):
            self.run.end_sample, self.run.end_state = self.sample, self.state
            self.run.exec_index, self.run.faults = self.exec_index, self.faults
            self.run.points = self.next_index
            self.runs.append(self.run)
            self.run = None
        self.sample += 1

    def _ramp(self) -> None:
        dv = self.cfg.decel_steps_s2 * PERIOD_S * PERIOD_S
        speed = max(abs(self.rate) - dv, 0.0)
        self.rate = math.copysign(speed, self.rate) if speed > 0 else 0.0
        self.pos += self.rate

    def _checks(self, executed: tuple[int, int] | None, underrun: bool, now: float) -> None:
        cfg, st = self.cfg, self.state
        halt = False
        if st in (IDLE, RUNNING, STOPPING):
            force = self.force
            if abs(force) > cfg.force_limit_n:
                self._latch(F_FORCE, force, cfg.force_limit_n)
                halt = True
            if not cfg.steps_min <= self.steps <= cfg.steps_max:
                lim = cfg.steps_min if self.steps < cfg.steps_min else cfg.steps_max
                self._latch(F_TRAVEL, self.steps, lim)
                halt = True
            elif not cfg.enc_min <= self.enc <= cfg.enc_max:
                lim = cfg.enc_min if self.enc < cfg.enc_min else cfg.enc_max
                self._latch(F_TRAVEL, self.enc, lim)
                halt = True
            if not ADC_MIN < self.load_raw < ADC_MAX:
                self._latch(F_SATURATED, self.load_raw,
                            ADC_MIN if self.load_raw <= ADC_MIN else ADC_MAX)
                halt = True
        if st == RUNNING:
            if executed is not None and executed[1] != NO_CHECK:
                err = self.enc - executed[1]
                if abs(err) > cfg.following_error_counts:
                    self._latch(F_FOLLOWING, err, cfg.following_error_counts)
                    self.referenced = False  # counts may be lost (doc revision of 10.6)
                    halt = True
            if self.stuck_count >= cfg.stuck_samples:
                self._latch(F_STUCK, self.stuck_count, cfg.stuck_samples)
                halt = True
        if halt:
            self._halt()
            return
        if underrun and self.state == RUNNING:
            self._latch(F_UNDERRUN, self.exec_index, self.next_index)
            self._controlled_stop(R_FAULT)
        if self.session:
            silent_ms = (now - self.last_rx) * 1e3
            if silent_ms > cfg.heartbeat_timeout_ms and not self.faults & F_HEARTBEAT:
                self._latch(F_HEARTBEAT, silent_ms, cfg.heartbeat_timeout_ms)
                if self.state == RUNNING:
                    self._controlled_stop(R_FAULT)
                elif self.state == IDLE:
                    self._discard()
                    self._set_state(FAULT, R_FAULT)

    def _telemetry(self) -> None:
        flags = FL_SESSION if self.session else 0
        if self.rate != 0.0:
            flags |= FL_MOVING
        if self.final:
            flags |= FL_FINAL
        if not ADC_MIN < self.load_raw < ADC_MAX:
            flags |= FL_SATURATED
        if self.state != ESTOP and not self.faults & F_BOARD:  # section 8: the board's faults
            flags |= FL_DRIVER  # de-energise (this rig raises none of them)
        if round(self.pos) <= 0:  # switch at x_open, active at or behind it
            flags |= FL_HOME
        if self.referenced:
            flags |= FL_REFERENCED
        if self.future:
            flags |= 0x80
            if self.sample % 100 == 50:
                self._send(0x85, struct.pack("<I", self.sample))  # a type this host lacks
        t_us = (self.sample * PERIOD_US) & 0xFFFFFFFF
        self._send(TELEMETRY, TELEMETRY_FMT.pack(
            self.boot_id, self.sample & 0xFFFFFFFF, t_us, self.steps, self.enc, self.load_raw,
            self.exec_index, len(self.points), self.faults, self.state, flags))


def _i32(v: float) -> int:
    return max(-(2**31), min(2**31 - 1, round(v)))
