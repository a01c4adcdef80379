"""One plant interface, two back-ends: the FMU (simulated rig) and the real rig.

Lifecycle: ``configure`` (what to run) -> ``activate`` (build/instantiate the
FMU, or open the port, handshake and reference the rig) -> ``run`` a
:class:`~hil.host.samples.Trajectory` and stream :class:`~hil.host.samples.Sample` s ->
``stop`` (after a run that ended early: bring the plant to a standstill and return
the samples taken on the way) -> ``deactivate`` (free the FMU, or end the session
and close the port). Use a back-end as a context manager: every exit path, Ctrl-C
and errors included, deactivates it. Both back-ends apply the same host-side
safety (force limit, travel limits, speed limit), move to the trajectory's start at
a safe speed first (not recorded), and report positions in the same frame: the
input position x in the model's frame, the platen relative to its position at the
open position (where the encoder is zeroed).
"""

from __future__ import annotations

import hashlib
import math
import shutil
import tempfile
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING

import numpy as np
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import fmi2Discard

from controllers.limits import DriveLimits, drive_limits
from hil.host.experiment import stroke_positions
from hil.host.homing import APPROACH_SPEED, START_TOLERANCE
from hil.host.samples import Sample, Status, Trajectory, TrajectoryError
from toggle.elastics import clamp_stroke
from toggle.kinematics import output_position
from toggle.params import dynamics_parameters, load_preset, preset_file
from toggle.rig_tables import rig_dynamics, rig_errors

if TYPE_CHECKING:
    from hil.link import protocol as p
    from hil.link.serial_link import SerialLink

#: Margin of the soft travel limits beyond the stroke, m.
TRAVEL_MARGIN = 1e-3
#: Fastest input speed a trajectory may command on the rig, m/s (its max_step_delta per
#: period).
MAX_SPEED = 50e-3


def simulated_speed_limit(preset: str) -> float:
    """Fastest input speed (m/s) on the simulated rig of ``preset``: the rig's
    :data:`MAX_SPEED`, or the preset's drive limit where that is faster (a larger clamp,
    such as lin2003_sm55, whose planned stroke runs at 400 mm/s)."""
    return max(MAX_SPEED, drive_limits(load_preset(preset)).velocity)


class RunStoppedError(RuntimeError):
    """The plant stopped the run: a safety limit, a rejected step or a rig fault."""


@dataclass(frozen=True)
class RigSetup:
    """What a run needs to know about the clamp, SI units.

    delta_r8: length error of link 8 (upper half), m (simulated back-end and
    emulator only: on the real rig it is set with the adjustable link; they add it to
    the rig's as-built errors, :attr:`errors`, unless as_built is False);
    force_limit: host-side stop on |input force|, N (on the real rig within its +-500 N cell).
    """

    preset: str = "chang2021"
    delta_r8: float = 0.0
    mu: float | None = None
    x_contact: float | None = None
    force_limit: float = 400.0
    period: float = 1e-3
    as_built: bool = True

    def __post_init__(self) -> None:
        if not (math.isfinite(self.delta_r8) and abs(self.delta_r8) < 5e-3):
            raise ValueError(f"delta_r8 must be an error below 5 mm, got {self.delta_r8!r} m")
        if not (math.isfinite(self.force_limit) and self.force_limit > 0):
            raise ValueError(f"force_limit must be > 0 N, got {self.force_limit!r}")
        if not (math.isfinite(self.period) and self.period > 0):
            raise ValueError(f"period must be > 0 s, got {self.period!r}")

    @property
    def errors(self) -> dict[str, float]:
        """The simulated rig's dimensional errors (seed 000's names, m): the preset's rig as
        built (unless ``as_built`` is False) plus delta_r8 (:func:`toggle.rig_tables.rig_errors`,
        as the rig tables)."""
        return rig_errors(self.preset, self.delta_r8, None if self.as_built else {})

    @property
    def dynamics(self) -> dict[str, float]:
        """The simulated rig's [dynamics] beyond its preset (its platen's friction, SI),
        unless ``as_built`` is False (:func:`toggle.rig_tables.rig_dynamics`)."""
        return rig_dynamics(self.preset, None if self.as_built else {})

    @property
    def planned_mold(self) -> float | None:
        """Crosshead position (m) of the mold that ``hil run``'s default job plans for and
        the simulated rig clamps: the plan's contact position (the preset's final tie-bar
        force held by this rig, :attr:`errors`); None when the preset has no mold."""
        from controllers.plans import plan_config

        return plan_config(self.preset, mu=self.mu, errors=self.errors).x_contact

    @property
    def stroke(self) -> tuple[float, float]:
        """(x_open, x_toggle) of the nominal mechanism, m: the open position the preset gives
        (the machine's, as the planner's) or the kinematic one."""
        return clamp_stroke(load_preset(self.preset))

    @property
    def limits(self) -> DriveLimits:
        """The preset's drive limits (:func:`controllers.limits.drive_limits`): every move
        of a run, recorded or not, keeps to the acceleration and jerk the planner obeys."""
        return drive_limits(load_preset(self.preset))

    @property
    def travel_limits(self) -> tuple[float, float]:
        x_open, x_tp = self.stroke
        return x_open - TRAVEL_MARGIN, x_tp + TRAVEL_MARGIN


class Plant(ABC):
    """A clamp that executes trajectories and streams samples."""

    name = "plant"

    def __init__(self) -> None:
        self.setup: RigSetup | None = None
        self.active = False
        self.approach = 0.0  # distance of the last unrecorded move to a start, m

    def configure(self, setup: RigSetup) -> None:
        if self.active:
            raise RunStoppedError("configure a plant before activating it")
        self.setup = setup

    def activate(self) -> None:
        if self.setup is None:
            raise RunStoppedError("configure the plant before activating it")
        self._activate()
        self.active = True

    def speed_limit(self) -> float:
        """Fastest input speed this plant takes, m/s: the rig's :data:`MAX_SPEED`."""
        return MAX_SPEED

    def check(self, trajectory: Trajectory) -> None:
        """Refuse a trajectory outside the travel limits or faster than :meth:`speed_limit`."""
        lo, hi = self.setup.travel_limits
        if trajectory.x_cmd.min() < lo or trajectory.x_cmd.max() > hi:
            raise TrajectoryError(
                f"trajectory leaves the soft travel limits [{lo:.6g}, {hi:.6g}] m "
                f"(it spans [{trajectory.x_cmd.min():.6g}, {trajectory.x_cmd.max():.6g}] m)"
            )
        speed = np.abs(np.diff(trajectory.x_cmd)) / trajectory.period
        limit = self.speed_limit()
        if speed.size and speed.max() > limit:
            i = int(np.argmax(speed))
            raise TrajectoryError(
                f"trajectory commands {speed[i] * 1e3:.4g} mm/s at t = {trajectory.time[i]:.3f} s "
                f"(x {trajectory.x_cmd[i]:.6g} -> {trajectory.x_cmd[i + 1]:.6g} m in one "
                f"period); the {self.name} plant's limit is {limit * 1e3:g} mm/s"
            )

    def run(self, trajectory: Trajectory,
            check: Callable[[], None] = lambda: None) -> Iterator[Sample]:
        """Move to the trajectory's start (unrecorded), execute it, yield one sample per
        period. Raises :class:`RunStoppedError`; then call :meth:`stop`. ``check`` is
        called during the unrecorded move and may raise to abandon it (Ctrl-C)."""
        if not self.active:
            raise RunStoppedError("activate the plant before running a trajectory")
        self.check(trajectory)
        self.approach = self._move_to(float(trajectory.x_cmd[0]), check)
        for sample in self._run(trajectory):
            if abs(sample.force) > self.setup.force_limit:
                yield Sample(sample.t, sample.x_cmd, sample.platen, sample.force, Status.FAULT,
                             sample.index)
                raise RunStoppedError(
                    f"host force limit (--force-limit): |{sample.force:.1f}| N > "
                    f"{self.setup.force_limit:g} N at x = {sample.x_cmd:.6g} m, "
                    f"t = {sample.t:.3f} s"
                )
            yield sample

    def stop(self) -> list[Sample]:
        """After a run ended early: stop, and return the samples taken until the standstill.

        Never raises. The simulated rig stops at once (nothing to return).
        """
        return []

    def describe(self) -> dict[str, object]:
        """What identifies this back-end in a run's metadata (JSON-ready)."""
        return {"backend": self.name, "approach_m": self.approach}

    def link_report(self) -> dict[str, object]:
        """Statistics of the link to the plant (JSON-ready); none for the simulated rig."""
        return {}

    def deactivate(self) -> None:
        if self.active:
            self.active = False
            self._deactivate()

    def __enter__(self) -> Plant:
        self.activate()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.deactivate()

    @abstractmethod
    def _activate(self) -> None: ...

    @abstractmethod
    def _run(self, trajectory: Trajectory) -> Iterator[Sample]: ...

    @abstractmethod
    def _move_to(self, x: float, check: Callable[[], None]) -> float:
        """Move, unrecorded, to input position ``x`` (m) at APPROACH_SPEED; the distance."""

    @abstractmethod
    def _deactivate(self) -> None: ...


def default_fmu_path(preset: str = "chang2021") -> Path:
    """The FMU of ``preset`` in the build folder (:func:`fmu_src.build.build_folder`, the
    one ``toggle build-fmu`` writes): build/ToggleClamp.fmu where it is built for this
    shipped preset (the one toggle build-fmu wrote last) or where there is none yet and the
    preset is chang2021; else build/<preset>/ToggleClamp.fmu; for a preset file,
    build/presets/<its stem>-<hash of its bytes>/ToggleClamp.fmu: one FMU per preset, and a
    new one when the file is edited (its FMU bundles the file as it was)."""
    from fmu_src.build import build_folder, fmu_preset

    base = build_folder()
    path = preset_file(preset)
    if path is not None:
        digest = hashlib.sha256(path.read_bytes()).hexdigest()[:12]
        return base / "presets" / f"{path.stem}-{digest}" / "ToggleClamp.fmu"
    current = base / "ToggleClamp.fmu"
    if (fmu_preset(current) == preset if current.is_file() else preset == "chang2021"):
        return current
    return base / preset / "ToggleClamp.fmu"


def ensure_fmu(path: Path | None = None, preset: str = "chang2021",
               notify: Callable[[str], None] = lambda _msg: None) -> Path:
    """The FMU of ``preset`` at ``path``, built first if it is missing or older than the
    model sources (``notify`` is told so, before and after the build)."""
    from fmu_src.build import FMU_SRC_DIR, PACKAGE_DIR, build_fmu
    from fmu_src.guard_build import GUARD_FILES

    path = Path(path) if path is not None else default_fmu_path(preset)
    sources = [*PACKAGE_DIR.rglob("*.py"), *PACKAGE_DIR.rglob("*.toml"),
               *FMU_SRC_DIR.glob("*.py"), *GUARD_FILES]
    newest = max(p.stat().st_mtime for p in sources if p.is_file())
    if not path.is_file() or path.stat().st_mtime < newest:
        why = "missing" if not path.is_file() else "older than the model"
        notify(f"building the FMU {path} of {preset} ({why})")
        built = build_fmu(path.parent, preset=preset)
        if built != path:
            shutil.move(built, path)
        notify(f"built the FMU {path}")
    return path


class FmuPlant(Plant):
    """The simulated rig: ToggleClamp.fmu stepped through fmpy at the trajectory's period."""

    name = "fmu"

    def speed_limit(self) -> float:
        """The rig's :data:`MAX_SPEED`, or the simulated clamp's drive limit if faster."""
        return simulated_speed_limit(self.setup.preset)

    def __init__(self, fmu_path: Path | None = None,
                 notify: Callable[[str], None] = lambda _msg: None) -> None:
        super().__init__()
        self.fmu_path = fmu_path
        self._notify = notify
        self._slave = None
        self._dir: str | None = None
        self.log: list[str] = []

    def _activate(self) -> None:
        from fmpy import extract

        from fmu_src.host import start_slave

        s = self.setup
        x_open = s.stroke[0]
        path = (ensure_fmu(preset=s.preset, notify=self._notify) if self.fmu_path is None
                else Path(self.fmu_path))
        if not path.is_file():
            raise RunStoppedError(f"no FMU at {path}")
        self._dir = extract(str(path), tempfile.mkdtemp(prefix="toggle_hil_"))
        # the rig's stepper is a position source, as the emulator's physics (ideal drive);
        # the FMU's default is the preset's drive lag (docs/fmu.md)
        start = {"preset": load_preset(s.preset).name, "x_cmd": x_open, "drive_bandwidth": 0.0,
                 **{f"delta_{name}": delta for name, delta in s.errors.items()},
                 **dynamics_parameters(s.dynamics)}
        if s.mu is not None:
            start["mu"] = s.mu
        if s.x_contact is not None:
            start["x_contact"] = s.x_contact
        try:
            self._slave, self._refs = start_slave(
                Path(self._dir), "hil", start, log=lambda status, msg: self.log.append(msg)
            )
        except FMICallException as exc:  # fmi2Error from a strict FMU (the native one)
            raise RunStoppedError(f"the FMU rejected the setup: "
                                  f"{self.log[-1] if self.log else exc}") from exc
        if any("initialisation failed" in m for m in self.log):
            raise RunStoppedError(f"the FMU rejected the setup: {self.log[-1]}")
        self._out = [self._refs[n] for n in ("platen_position", "input_force")]
        self._zero = self._slave.getReal([self._out[0]])[0]
        self._x, self._time = x_open, 0.0

    def describe(self) -> dict[str, object]:
        """The simulated rig also records its dimensional errors (as built plus delta_r8)
        and its [dynamics] beyond the preset's (SI)."""
        info = super().describe()
        if self.setup is not None:
            info["dimensional_errors_m"] = self.setup.errors
            info["dynamics_beyond_preset"] = self.setup.dynamics
        return info

    def _step(self, x: float, h: float) -> tuple[float, float]:
        """Command ``x`` (m) for one step of ``h`` s; (platen from its zero m, force N)."""
        slave = self._slave
        slave.setReal([self._refs["x_cmd"]], [x])
        try:
            status = slave.fmi2DoStep(slave.component, self._time, h, 1)
        except FMICallException:
            status = fmi2Discard
        if status == fmi2Discard:
            raise RunStoppedError(f"the FMU rejected the step at x = {x:.6g} m: "
                                  f"{self.log[-1] if self.log else 'no message'}")
        self._time += h
        self._x = x
        platen, force = slave.getReal(self._out)
        return platen - self._zero, force

    def _run(self, trajectory: Trajectory) -> Iterator[Sample]:
        for i, (t, x) in enumerate(zip(trajectory.time, trajectory.x_cmd)):
            platen, force = self._step(float(x), trajectory.period)
            yield Sample(float(t), float(x), platen, force, Status.OK, i)

    def _move_to(self, x: float, check: Callable[[], None]) -> float:
        if abs(x - self._x) <= START_TOLERANCE:
            return 0.0
        start, h = self._x, self.setup.period
        for xi in stroke_positions(start, x, APPROACH_SPEED, h, self.setup.limits)[1:]:
            check()
            force = self._step(float(xi), h)[1]
            if abs(force) > self.setup.force_limit:
                raise RunStoppedError(f"host force limit (--force-limit): |{force:.1f}| N "
                                      f"during the move to the start x = {x:.6g} m")
        return abs(x - start)

    def _deactivate(self) -> None:
        try:
            if self._slave is not None:
                self._slave.terminate()
                self._slave.freeInstance()
        finally:
            self._slave = None
            if self._dir is not None:
                shutil.rmtree(self._dir, ignore_errors=True)
                self._dir = None


class RigPlant(Plant):
    """The real rig (or its emulator) over a serial URL: stepper, encoder, load cell.

    The MCU executes the trajectory and enforces the hard limits; the host streams it in
    chunks and supervises. At activation a fault latched before this session refuses the
    run (``hil rig clear`` is the operator's decision), an unreferenced rig is homed, and
    the MCU gets the run's limits. Every run starts with a move to its first point.
    """

    name = "rig"

    def __init__(self, port: str, *, realtime: bool = True,
                 telemetry_timeout: float | None = None,
                 ack_timeout: float | None = None,
                 heartbeat_ms: float | None = None,
                 notify: Callable[[str], None] | None = None,
                 session: SerialLink | None = None) -> None:
        """``session``: an open session to run on (the panel's, which outlives the run:
        deactivation stops the rig but does not close it); None opens one at activation."""
        super().__init__()
        self.port = port
        self._session = session
        # None: measured from the link when the session opens (hil.link.timing), within
        # bounds; the protocol's 20 ms, 100 ms and 250 ms on a rig's idle link
        self.ack_timeout = ack_timeout
        self.heartbeat_ms = heartbeat_ms
        self.realtime = realtime
        self.telemetry_timeout = telemetry_timeout
        self.notify = notify or (lambda _msg: None)
        self._link = None
        self.homed_distance: float | None = None

    @property
    def link(self) -> SerialLink | None:
        """The open session (None before activation and after deactivation)."""
        return self._link

    def _activate(self) -> None:
        from hil.host.homing import home
        from hil.link import protocol as p
        from hil.link.errors import RigError
        from hil.link.serial_link import SerialLink

        s = self.setup
        self._x0, _ = s.stroke
        nominal = load_preset(s.preset)
        self._L0 = float(output_position(self._x0, nominal.lower))
        self._nominal = nominal
        self._link = link = self._session or SerialLink(
            self.port, realtime=self.realtime, telemetry_timeout=self.telemetry_timeout,
            point_period_us=round(s.period * 1e6), ack_timeout=self.ack_timeout,
            heartbeat_timeout_ms=None if self.heartbeat_ms is None else round(self.heartbeat_ms))
        try:
            self._open(link)
            if link.timing is not None and not link.timing.is_nominal:
                self.notify(f"the link is slower than a rig's ({link.timing.text()}): ACK "
                            f"timeout {link.ack_timeout * 1e3:.0f} ms, telemetry watchdog "
                            f"{link.telemetry_timeout * 1e3:.0f} ms, the MCU's heartbeat "
                            f"timeout {link.heartbeat_timeout_ms} ms "
                            f"(docs/rig-protocol-behaviour.md, section 7)")
            latched = link.status.faults if self._session else link.faults_at_open
            if latched:
                raise RunStoppedError(
                    f"the rig at {self.port} has a latched fault from an earlier session: "
                    f"{fault_names(latched)} (state "
                    f"{p.State(link.status.state).name}); check the rig, then clear it with "
                    f"`hil rig clear --port {self.port}`")
            if not link.status.flags & p.TelemetryFlag.REFERENCED:
                self.notify("the rig is not referenced (power-on or reset): homing at "
                            "its home switch")
                self.homed_distance = home(link)
            sc = link.scaling
            lo, hi = s.travel_limits
            link.configure(link.config_for(force_limit_n=s.force_limit,
                                           steps_min=sc.steps(lo, self._x0),
                                           steps_max=sc.steps(hi, self._x0)))
        except RigError as exc:
            self._release()
            raise RunStoppedError(f"rig at {self.port}: {exc}") from exc
        except BaseException:
            self._release()
            raise

    def _open(self, link: SerialLink) -> None:
        if self._session is None:
            link.open()

    def _release(self) -> None:
        """End this back-end's use of the session: close its own; a given one is stopped
        (never raises) and left open."""
        if self._link is None:
            return
        if self._session is None:
            self._link.close()  # STOP, standstill, BYE, closed port; never raises
        else:
            self._link.stop_quietly()
        self._link = None

    def _move_to(self, x: float, check: Callable[[], None]) -> float:
        from hil.host.homing import move_to
        from hil.link.errors import RigError

        try:
            distance = move_to(self._link, x, self._x0, self.setup.limits, check=check)
        except RigError as exc:
            raise RunStoppedError(f"rig fault while moving to the start x = {x:.6g} m: "
                                  f"{exc}") from exc
        if distance:
            self.notify(f"moved the rig {distance * 1e3:.3f} mm to the start x = "
                        f"{x * 1e3:.3f} mm at {APPROACH_SPEED * 1e3:g} mm/s")
        return distance

    def _sample(self, tel: p.Telemetry, total: int) -> Sample:
        from hil.link import protocol as p
        from hil.link.telemetry_watch import sample_distance

        sc, x0 = self._link.scaling, self._x0
        if tel.faults:
            status = Status.FAULT
        elif tel.state == p.State.RUNNING or (tel.state == p.State.IDLE
                                               and tel.exec_index >= total):
            status = Status.OK
        else:
            status = Status.STOPPING
        return Sample(sample_distance(tel.sample, self._first) * sc.period, sc.x(tel.steps, x0),
                      sc.platen(tel.enc), sc.force(tel.load_raw), status, tel.sample)

    def _run(self, trajectory: Trajectory) -> Iterator[Sample]:
        from hil.link.errors import RigError, RigFaultError

        link, sc, x0 = self._link, self._link.scaling, self._x0
        x = trajectory.x_cmd
        expected = np.asarray(output_position(x, self._nominal.lower)) - self._L0
        points = [(sc.steps(float(xi), x0), sc.counts(float(li))) for xi, li in zip(x, expected)]
        self._first, self._total = None, len(points)
        try:
            for tel in link.run_trajectory(points):
                self._first = tel.sample if self._first is None else self._first
                yield self._sample(tel, len(points))
        except RigFaultError as exc:
            raise RunStoppedError(f"rig fault: {exc}") from exc
        except RigError as exc:
            raise RunStoppedError(f"rig link: {exc}") from exc

    def stop(self) -> list[Sample]:
        if self._link is None:
            return []
        from hil.link import protocol as p

        self._link.stop_quietly()
        rest = self._link.finish_run()
        if rest and self._first is None:
            self._first = rest[0].sample
        status = rest[-1] if rest else self._link.status
        if status is None or status.state in (p.State.RUNNING, p.State.STOPPING):
            self.notify("the rig did not report a standstill after the stop")
        return [self._sample(tel, self._total) for tel in rest]

    def describe(self) -> dict[str, object]:
        info = {**super().describe(), "port": self.port}
        link = self._link
        if link is not None and link.info is not None:
            i = link.info
            info.update(protocol=f"{i.proto_major}.{i.proto_minor}",
                        firmware=f"{i.fw_version >> 8}.{i.fw_version & 0xFF}",
                        boot_id=f"{i.boot_id:#010x}", telemetry_hz=i.telemetry_hz,
                        homed_distance=self.homed_distance,
                        watchdog_s=link.telemetry_timeout, ack_timeout_s=link.ack_timeout,
                        mcu_heartbeat_timeout_s=link.config.heartbeat_timeout_ms * 1e-3,
                        link_timing=None if link.timing is None else link.timing.describe())
        return info

    def link_report(self) -> dict[str, object]:
        """Link statistics of the session (JSON-ready; empty before activation)."""
        return {} if self._link is None else link_report(self._link)

    def _deactivate(self) -> None:
        self._release()


def link_report(link: SerialLink) -> dict[str, object]:
    """Statistics of an open session with the rig (JSON-ready): errors, losses,
    retransmissions, telemetry arrival gaps."""
    st, dec = link.stats, link.decoder.stats
    return {
        "bad_frames": dec.rejected, "crc_errors": dec.crc_errors,
        "bad_messages": st.bad_messages, "lost_samples": st.lost_samples,
        "duplicate_samples": st.duplicates, "retransmissions": st.retransmissions,
        "late_attempts": st.late_attempts, "queue_dropped": st.queue_dropped,
        "arrival_gap_p99_s": st.gap_percentile(0.99),
        "arrival_gap_p999_s": st.gap_percentile(0.999),
        "arrival_gap_max_s": st.max_arrival_gap,
        "mcu_clock_excess_max_s": st.max_clock_excess,
    }


def fault_names(faults: int) -> str:
    """'FORCE_LIMIT | ESTOP' for a fault bit set."""
    from hil.link import protocol as p

    return " | ".join(f.name for f in p.Fault if f and f & faults) or "none"
