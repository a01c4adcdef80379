"""The rig as the MCU sees it, without any I/O: its constants (:class:`RigHardware`, reported
to the host in HELLO_REPLY), its mechanics (a :class:`RigPhysics` callback, so the same
firmware runs any plant) and its sensors (:class:`Sensors`: encoder quantisation, load-cell
amplifier noise and ADC, injected sensor faults). :mod:`hil.emulators.mcu_model` runs the
firmware on them.
"""

from __future__ import annotations

import random
from dataclasses import dataclass
from typing import Protocol


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
