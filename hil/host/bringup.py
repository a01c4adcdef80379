"""Bring-up of a rig on day one: jog, tare, span, store the calibration, sensor check.

One implementation for the command line (``hil rig jog|tare|span|store|check``) and the
web panel. Every function takes an open :class:`~hil.link.serial_link.SerialLink` session and
returns a frozen result with ``to_dict()`` for JSON; every refusal raises
:class:`BringupError` with one sentence an operator can act on. Nothing here bypasses the
MCU's limits: moves are ordinary trajectories inside the CONFIG in force, and the board
refuses STORE_CALIBRATION unless it is IDLE (docs/bring-up.md, docs/rig-protocol.md 1.3).
The functions consume the link's telemetry queue while they run (``drain``,
``next_sample``, ``run_trajectory``), as a run does: one caller at a time per link, and a
live display meanwhile reads ``link.status`` or its own tap, not that queue.
"""

from __future__ import annotations

import dataclasses
import math
import statistics
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from hil.host.backends import RigSetup
from hil.host.homing import APPROACH_SPEED, ConstantSpeed, move_to
from hil.link import protocol as p
from hil.link.errors import RigError
from hil.link.serial_link import SerialLink
from toggle.kinematics import output_position
from toggle.params import load_preset

#: Standard gravity (ISO 80000-3), m/s^2: a calibration mass's force.
STANDARD_GRAVITY = 9.80665
#: The cell's nominal gain, N per ADC count (a +-500 N cell on +-5 000 000 counts).
NOMINAL_GAIN = 1e-4
#: A span whose gain is outside [nominal / GAIN_FACTOR, nominal * GAIN_FACTOR] is refused.
GAIN_FACTOR = 2.0
#: A span force below this many standard deviations of one reading is refused.
SPAN_MIN_SIGMAS = 20.0
#: The sensor check's move: distance (m) and speed (m/s), forward from where the table is.
CHECK_DISTANCE = 2e-3
CHECK_SPEED = 1e-3
#: Pass bounds of the sensor check: counts per step within this fraction of the model's;
#: lost steps within this fraction of the move (the nominal linkage's model error);
#: load-cell noise (1 sigma, N) below this.
COUNTS_TOLERANCE = 0.03
LOST_TOLERANCE = 0.03
NOISE_LIMIT_N = 1.0
#: Fastest jog, m/s (the protocol's default max_step_delta: 250 steps per ms).
JOG_MAX_SPEED = 50e-3


class BringupError(RigError):
    """A bring-up action refused or failed; the message says why and what to do."""


class _Result:
    """``to_dict()`` of a frozen result: its fields, nested results as dicts."""

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)  # type: ignore[call-overload]


@dataclass(frozen=True)
class JogResult(_Result):
    """A jog: table positions from step 0 (the home switch's edge), m; speed, m/s."""

    start: float
    target: float
    end: float
    speed: float


@dataclass(frozen=True)
class TareResult(_Result):
    """offset: mean raw reading at rest, ADC counts; noise: 1 sigma of one reading, N (with
    the gain in use); samples: how many readings."""

    offset: int
    noise: float
    samples: int


@dataclass(frozen=True)
class SpanResult(_Result):
    """gain: N per count from ``known_force`` (N) over the mean reading minus ``offset``;
    noise: 1 sigma of one reading, N (with the new gain)."""

    gain: float
    known_force: float
    offset: int
    mean_raw: float
    noise: float
    samples: int


@dataclass(frozen=True)
class StoredCalibration(_Result):
    """The calibration in the board's non-volatile memory, read back; cal_seq its record."""

    cal_seq: int
    offset: int
    gain: float


@dataclass(frozen=True)
class CheckItem(_Result):
    """One item of the sensor check: pass or fail with its figure and unit."""

    name: str
    passed: bool
    figure: float | None  # None: not measurable (the text says why)
    unit: str
    text: str


@dataclass(frozen=True)
class SensorReport(_Result):
    """The sensor check's items, in the order checked."""

    items: list[CheckItem] = field(default_factory=list)

    @property
    def passed(self) -> bool:
        return all(item.passed for item in self.items)

    def to_dict(self) -> dict[str, Any]:
        return {**super().to_dict(), "passed": self.passed}

    def item(self, name: str) -> CheckItem:
        """The item called ``name``."""
        return next(i for i in self.items if i.name == name)


def span_from_mass(mass_kg: float) -> float:
    """The force (N) of a calibration mass hung on the cell, at standard gravity."""
    if not (isinstance(mass_kg, (int, float)) and math.isfinite(mass_kg) and mass_kg > 0):
        raise BringupError(f"a calibration mass must be a positive number of kg, not "
                           f"{mass_kg!r}")
    return float(mass_kg) * STANDARD_GRAVITY


# --- helpers ------------------------------------------------------------------------------


def _fresh(link: SerialLink, what: str) -> p.Telemetry:
    """A sample taken after every command sent so far was executed (the MCU answers a
    command before its next period)."""
    link.drain()
    try:
        return link.next_sample()
    except RigError as exc:
        raise BringupError(f"{what}: {exc}") from exc


def _idle(link: SerialLink, what: str) -> p.Telemetry:
    """A fresh sample, refusing unless the rig is IDLE without a latched fault."""
    st = _fresh(link, what)
    if st.faults:
        raise BringupError(f"{what}: the rig has latched faults ({p.Fault(st.faults)!r}); "
                           f"check the rig and clear them (hil rig clear)")
    if st.state != p.State.IDLE:
        raise BringupError(f"{what}: the rig is {p.State(st.state).name}, not IDLE")
    return st


def _referenced(st: p.Telemetry, what: str) -> None:
    if not st.flags & p.TelemetryFlag.REFERENCED:
        raise BringupError(f"{what}: the rig is not homed (counts unreferenced since its "
                           f"boot); run hil rig home first")


def _at_rest(link: SerialLink, samples: int, what: str) -> list[int]:
    """``samples`` raw load readings of consecutive periods with the table at rest."""
    if not (isinstance(samples, int) and 10 <= samples <= 60_000):
        raise BringupError(f"{what}: samples must be a whole number in 10..60000, not "
                           f"{samples!r}")
    _idle(link, what)
    readings: list[int] = []
    while len(readings) < samples:
        tel = link.next_sample()
        if tel.flags & (p.TelemetryFlag.MOVING | p.TelemetryFlag.LOAD_SATURATED) or tel.faults:
            raise BringupError(f"{what}: the table moved, the cell saturated or a fault "
                               f"latched while sampling (sample {tel.sample}); keep the "
                               f"rig at rest and try again")
        readings.append(tel.load_raw)
    return readings


# --- the actions --------------------------------------------------------------------------


def jog(link: SerialLink, *, to: float | None = None, by: float | None = None,
        speed: float | None = None, setup: RigSetup | None = None) -> JogResult:
    """Move the table to ``to`` or by ``by`` (m, from step 0: the home switch's edge) at
    ``speed`` (m/s, default 5 mm/s), jerk-limited; refused unless homed, IDLE without
    faults, and the target inside the rig's travel limits and the CONFIG in force."""
    if (to is None) == (by is None):
        raise BringupError("jog: give exactly one of to= (a position) or by= (a distance)")
    for name, value in (("to", to), ("by", by), ("speed", speed)):
        if value is not None and not (isinstance(value, (int, float)) and math.isfinite(value)):
            raise BringupError(f"jog: {name} must be a finite number of m (m/s), not "
                               f"{value!r}")
    speed = APPROACH_SPEED if speed is None else float(speed)
    if not 0 < speed <= JOG_MAX_SPEED:
        raise BringupError(f"jog: speed {speed * 1e3:g} mm/s is outside (0, "
                           f"{JOG_MAX_SPEED * 1e3:g}] mm/s")
    _referenced(_idle(link, "jog"), "jog")
    setup = setup or RigSetup()
    sc = link.scaling
    start = sc.x(link.status.steps)
    target = float(to) if to is not None else start + float(by)  # type: ignore[arg-type]
    x_open, _ = setup.stroke
    lo, hi = (x - x_open for x in setup.travel_limits)
    cfg = link.config
    lo, hi = max(lo, sc.x(cfg.steps_min)), min(hi, sc.x(cfg.steps_max))
    if not lo <= target <= hi:
        raise BringupError(f"jog: {target * 1e3:.3f} mm is outside the travel limits "
                           f"[{lo * 1e3:.3f}, {hi * 1e3:.3f}] mm")
    try:
        move_to(link, target, 0.0, setup.limits, speed=speed)
    except RigError as exc:
        raise BringupError(f"jog: {exc}") from exc
    return JogResult(start, target, sc.x(link.status.steps), speed)


def tare(link: SerialLink, samples: int = 500) -> TareResult:
    """The cell's offset: the mean raw reading of ``samples`` periods at rest, with no load
    on the cell; its noise (1 sigma of one reading) in N with the gain in use."""
    raw = _at_rest(link, samples, "tare")
    noise = statistics.stdev(raw) * link.scaling.load_gain_n
    return TareResult(round(statistics.fmean(raw)), noise, len(raw))


def span(link: SerialLink, known_force: float, samples: int = 500, *,
         offset: int | None = None, nominal_gain: float = NOMINAL_GAIN) -> SpanResult:
    """The cell's gain from ``known_force`` (N, positive as the table pushing) on the cell
    at rest: force / (mean raw - offset); ``offset`` defaults to the calibration in use
    (pass a fresh tare's). Refused when the force is within the noise, or the gain is
    negative or beyond a factor GAIN_FACTOR of ``nominal_gain``."""
    if not (isinstance(known_force, (int, float)) and math.isfinite(known_force)
            and known_force != 0):
        raise BringupError(f"span: the known force must be a non-zero number of N, not "
                           f"{known_force!r}")
    offset = link.scaling.load_offset if offset is None else int(offset)
    raw = _at_rest(link, samples, "span")
    mean, sigma = statistics.fmean(raw), statistics.stdev(raw)
    signal = mean - offset
    if abs(signal) < SPAN_MIN_SIGMAS * max(sigma, 1.0):
        raise BringupError(
            f"span: {known_force:g} N moved the reading by {signal:.0f} counts, within "
            f"{SPAN_MIN_SIGMAS:g} x its noise ({sigma:.0f} counts): use a larger force, or "
            f"check that it hangs on the cell")
    gain = known_force / signal
    if gain < 0:
        raise BringupError(
            f"span: the reading went the other way ({signal:+.0f} counts for "
            f"{known_force:+g} N): check the cell's wiring or the force's sign")
    if not nominal_gain / GAIN_FACTOR <= gain <= nominal_gain * GAIN_FACTOR:
        raise BringupError(
            f"span: gain {gain:.4g} N/count is implausible for this cell (nominal "
            f"{nominal_gain:.4g}, accepted within a factor {GAIN_FACTOR:g}): check the force, "
            f"the cell and its amplifier")
    return SpanResult(gain, float(known_force), offset, mean, sigma * gain, len(raw))


def store_calibration(link: SerialLink, offset: int, gain: float) -> StoredCalibration:
    """Write (offset, gain) to the board's non-volatile memory, read it back, and use it
    for the rest of the session; refused with the board's reason."""
    info = link.info or p.HelloReply()
    if not (isinstance(offset, int) and info.adc_min < offset < info.adc_max):
        raise BringupError(f"store: the offset must be a whole number of ADC counts inside "
                           f"the ADC's range, not {offset!r}")
    if not (isinstance(gain, (int, float)) and math.isfinite(gain) and gain > 0):
        raise BringupError(f"store: the gain must be a positive number of N/count, not "
                           f"{gain!r}")
    _idle(link, "store")
    reply = link.command(p.StoreCalibration(offset, float(gain)), check=False)
    if reply.result != p.Result.OK:
        why = {p.Result.NVM_ERROR: "the board's memory did not verify the record (the "
                                   "previous calibration stays)",
               p.Result.NO_SESSION: "no session"}.get(p.Result(reply.result), "")
        raise BringupError(f"store: the board refused: {p.Result(reply.result).name} {why}"
                           f"".rstrip())
    back = read_calibration(link)
    want = p.StoreCalibration.unpack(p.StoreCalibration(offset, float(gain)).pack())
    if (back.offset, back.gain) != (want.load_offset, want.load_gain_n):
        raise BringupError(f"store: the board reads back {back.offset} counts, "
                           f"{back.gain:.6g} N/count, not what was written")
    link.scaling = dataclasses.replace(link.scaling, load_offset=back.offset,
                                       load_gain_n=back.gain)
    return back


def read_calibration(link: SerialLink) -> StoredCalibration:
    """The calibration stored on the board (READ_CALIBRATION, protocol 1.3)."""
    reply = link.command(p.ReadCalibration())
    if not isinstance(reply, p.CalibrationReply):
        raise BringupError(f"the board answered READ_CALIBRATION with "
                           f"{type(reply).__name__}: is it older than protocol 1.3?")
    return StoredCalibration(reply.cal_seq, reply.load_offset, reply.load_gain_n)


def sensor_check(link: SerialLink, *, setup: RigSetup | None = None,
                 distance: float = CHECK_DISTANCE, speed: float = CHECK_SPEED) -> SensorReport:
    """A slow move forward by ``distance`` and back, with the readings judged against the
    nominal linkage (toggle/kinematics.py): the encoder's direction and counts per step,
    lost steps, the cell's noise at rest, the home switch, the overtravel switches and the
    stop chain. Refused unless homed and IDLE without faults."""
    _referenced(_idle(link, "sensor check"), "sensor check")
    setup = setup or RigSetup()
    sc = link.scaling
    rest = _at_rest(link, 200, "sensor check")
    start = link.status
    moves = _constant_moves(start.steps, round(distance / sc.step_m), speed * sc.period / sc.step_m)
    try:
        run = list(link.run_trajectory(moves))
        link.finish_run()
    except RigError as exc:
        raise BringupError(f"sensor check: the move failed: {exc}") from exc
    far = max(tel.steps for tel in run)
    forward = [tel for tel in run if tel.steps == far][-1]  # the far end, after the hold
    x_open, _ = setup.stroke
    nominal = load_preset(setup.preset).lower
    platen = lambda steps: float(output_position(x_open + sc.x(steps), nominal))  # noqa: E731
    d_steps = forward.steps - start.steps
    d_enc = forward.enc - start.enc
    expected_enc = (platen(forward.steps) - platen(start.steps)) / sc.enc_m
    items = [_direction(d_enc, expected_enc),
             _counts_per_step(d_enc, expected_enc, d_steps),
             _lost_steps(d_enc, d_steps, start.steps, platen, sc.enc_m, sc.step_m),
             _noise(rest, sc.load_gain_n),
             _home_switch(run, start),
             _faults_item("overtravel switches", p.Fault.OVERTRAVEL, run,
                          "closed (neither end tripped)", "an overtravel switch is open"),
             _stop_chain(run)]
    return SensorReport(items)


def _constant_moves(start: int, steps: int, per_period: float) -> list[tuple[int, int]]:
    """Forward by ``steps`` at ``per_period`` steps a period, a 50 ms hold, and back."""
    count = max(1, math.ceil(steps / per_period))
    out = list(ConstantSpeed(start, steps / count, count))
    out += [out[-1]] * 50
    back = ConstantSpeed(out[-1][0], -steps / count, count)
    return out + list(back)


def _direction(d_enc: int, expected: float) -> CheckItem:
    ok = d_enc * expected > 0
    text = ("counts with the steps" if ok else
            "REVERSED: the encoder counts against the steps (swap its A and B channels)"
            if d_enc * expected < 0 else "no counts: the encoder does not count")
    return CheckItem("encoder direction", ok, float(d_enc), "counts", text)


def _counts_per_step(d_enc: int, expected: float, d_steps: int) -> CheckItem:
    measured, want = d_enc / d_steps, expected / d_steps
    ok = abs(measured - want) <= COUNTS_TOLERANCE * abs(want)
    return CheckItem("encoder counts per step", ok, measured, "counts/step",
                     f"model {want:.4f} counts/step (within {COUNTS_TOLERANCE:.0%})")


def _lost_steps(d_enc: int, d_steps: int, start: int, platen: Any, enc_m: float,
                step_m: float) -> CheckItem:
    """The steps the table did not take: the commanded move minus the move the encoder
    saw, inverted through the nominal linkage (bisection on the monotonic L(x))."""
    if d_enc * d_steps <= 0:
        return CheckItem("lost steps", False, None, "steps",
                         "not measurable while the encoder counts backwards or not at all")
    target = platen(start) + d_enc * enc_m
    lo, hi = start, start + 2 * d_steps
    for _ in range(40):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if platen(round(mid)) < target else (lo, mid)
    taken = (lo + hi) / 2 - start
    lost = d_steps - taken
    ok = abs(lost) <= LOST_TOLERANCE * d_steps
    return CheckItem("lost steps", ok, float(round(lost)), "steps",
                     f"of {d_steps} commanded ({lost / d_steps:.1%}; accepted within "
                     f"{LOST_TOLERANCE:.0%}, the model's error)")


def _noise(raw: Sequence[int], gain: float) -> CheckItem:
    sigma = statistics.stdev(raw) * gain
    return CheckItem("load-cell noise", sigma < NOISE_LIMIT_N, sigma, "N",
                     f"1 sigma of one reading at rest (below {NOISE_LIMIT_N:g} N)")


def _home_switch(run: Sequence[p.Telemetry], start: p.Telemetry) -> CheckItem:
    """After homing the table is at the switch's edge: it must stay inactive forward."""
    active = sum(1 for tel in run if tel.steps > start.steps + 100
                 and tel.flags & p.TelemetryFlag.HOME_SWITCH)
    return CheckItem("home switch", active == 0, float(active), "samples",
                     "inactive away from home" if active == 0 else
                     "active away from home: check its wiring and position")


def _faults_item(name: str, bit: p.Fault, run: Sequence[p.Telemetry], good: str,
                 bad: str) -> CheckItem:
    hits = sum(1 for tel in run if tel.faults & bit)
    return CheckItem(name, hits == 0, float(hits), "samples", good if hits == 0 else bad)


def _stop_chain(run: Sequence[p.Telemetry]) -> CheckItem:
    """The driver was enabled through the move and the board saw no STOP_CHAIN fault."""
    enabled = sum(1 for tel in run if tel.flags & p.TelemetryFlag.DRIVER_ENABLED)
    broken = any(tel.faults & (p.Fault.STOP_CHAIN | p.Fault.ESTOP) for tel in run)
    ok = enabled > 0 and not broken
    return CheckItem("stop chain", ok, float(enabled), "samples enabled",
                     "closed: the driver enabled through the move" if ok else
                     "open or stuck: the driver was not enabled, or STOP_CHAIN/ESTOP latched")


__all__ = [
    "BringupError", "CheckItem", "JogResult", "SensorReport", "SpanResult",
    "StoredCalibration", "TareResult", "jog", "read_calibration", "sensor_check", "span",
    "span_from_mass", "store_calibration", "tare",
]
