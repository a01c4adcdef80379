"""One plant interface, two back-ends: the FMU (simulated rig) and the real rig.

Lifecycle: ``configure`` (what to run) -> ``activate`` (build/instantiate the
FMU, or open the port and handshake) -> ``run`` a :class:`~hil.samples.Trajectory`
and stream :class:`~hil.samples.Sample` s -> ``deactivate`` (free the FMU, or
stop the rig and close the port). Use a back-end as a context manager: every
exit path, Ctrl-C and errors included, deactivates it. Both back-ends apply
the same host-side safety (force limit, travel limits) and report positions in
the same frame: the input position x in the model's frame, the platen relative
to its position at the open position (where the encoder is zeroed).
"""

from __future__ import annotations

import math
import shutil
import tempfile
from abc import ABC, abstractmethod
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType

import numpy as np

from hil.samples import Sample, Status, Trajectory, TrajectoryError
from toggle.kinematics import output_position, stroke_limits
from toggle.params import load_preset

#: Margin of the soft travel limits beyond the stroke, m.
TRAVEL_MARGIN = 1e-3


class RunStoppedError(RuntimeError):
    """The plant stopped the run: a safety limit, a rejected step or a rig fault."""


@dataclass(frozen=True)
class RigSetup:
    """What a run needs to know about the clamp, SI units.

    delta_r8: length error of link 8 (upper half), m (simulated back-end and
    emulator only: on the real rig it is set with the adjustable link);
    force_limit: host-side stop on |input force|, N (below the +-500 N cell).
    """

    preset: str = "chang2021"
    delta_r8: float = 0.0
    mu: float | None = None
    x_contact: float | None = None
    force_limit: float = 400.0
    period: float = 1e-3

    def __post_init__(self) -> None:
        if not (math.isfinite(self.delta_r8) and abs(self.delta_r8) < 5e-3):
            raise ValueError(f"delta_r8 must be an error below 5 mm, got {self.delta_r8!r} m")
        if not (math.isfinite(self.force_limit) and self.force_limit > 0):
            raise ValueError(f"force_limit must be > 0 N, got {self.force_limit!r}")
        if not (math.isfinite(self.period) and self.period > 0):
            raise ValueError(f"period must be > 0 s, got {self.period!r}")

    @property
    def stroke(self) -> tuple[float, float]:
        """(x_open, x_toggle) of the nominal mechanism, m."""
        return stroke_limits(load_preset(self.preset).lower)

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

    def configure(self, setup: RigSetup) -> None:
        if self.active:
            raise RunStoppedError("configure a plant before activating it")
        self.setup = setup

    def activate(self) -> None:
        if self.setup is None:
            raise RunStoppedError("configure the plant before activating it")
        self._activate()
        self.active = True

    def run(self, trajectory: Trajectory) -> Iterator[Sample]:
        """Execute a trajectory; yield one sample per period. Raises :class:`RunStoppedError`."""
        if not self.active:
            raise RunStoppedError("activate the plant before running a trajectory")
        lo, hi = self.setup.travel_limits
        if trajectory.x_cmd.min() < lo or trajectory.x_cmd.max() > hi:
            raise TrajectoryError(
                f"trajectory leaves the soft travel limits [{lo:.6g}, {hi:.6g}] m "
                f"(it spans [{trajectory.x_cmd.min():.6g}, {trajectory.x_cmd.max():.6g}] m)"
            )
        for sample in self._run(trajectory):
            if abs(sample.force) > self.setup.force_limit:
                yield Sample(sample.t, sample.x_cmd, sample.platen, sample.force, Status.FAULT)
                raise RunStoppedError(
                    f"force limit: |{sample.force:.1f}| N > {self.setup.force_limit:g} N "
                    f"at x = {sample.x_cmd:.6g} m, t = {sample.t:.3f} s"
                )
            yield sample

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
    def _deactivate(self) -> None: ...


def default_fmu_path() -> Path:
    """build/ToggleClamp.fmu of the project checkout (or the current folder)."""
    from toggle.fmu_build import PACKAGE_DIR

    root = PACKAGE_DIR.parent
    base = root if (root / "pyproject.toml").is_file() else Path.cwd()
    return base / "build" / "ToggleClamp.fmu"


def ensure_fmu(path: Path | None = None) -> Path:
    """The FMU at ``path``, built first if it is missing or older than the model sources."""
    from toggle.fmu_build import DEFAULT_SLAVE, PACKAGE_DIR, build_fmu

    path = Path(path) if path is not None else default_fmu_path()
    sources = [*PACKAGE_DIR.rglob("*.py"), *PACKAGE_DIR.rglob("*.toml"), DEFAULT_SLAVE]
    newest = max(p.stat().st_mtime for p in sources if p.is_file())
    if not path.is_file() or path.stat().st_mtime < newest:
        built = build_fmu(path.parent)
        if built != path:
            shutil.move(built, path)
    return path


class FmuPlant(Plant):
    """The simulated rig: ToggleClamp.fmu stepped through fmpy at the trajectory's period."""

    name = "fmu"

    def __init__(self, fmu_path: Path | None = None) -> None:
        super().__init__()
        self.fmu_path = fmu_path
        self._slave = None
        self._dir: str | None = None
        self.log: list[str] = []

    def _activate(self) -> None:
        from fmpy import extract

        from toggle.fmu_host import start_slave

        s = self.setup
        x_open = s.stroke[0]
        self._dir = extract(str(ensure_fmu(self.fmu_path)), tempfile.mkdtemp(prefix="toggle_hil_"))
        start = {"preset": s.preset, "delta_r8": s.delta_r8, "x_cmd": x_open}
        if s.mu is not None:
            start["mu"] = s.mu
        if s.x_contact is not None:
            start["x_contact"] = s.x_contact
        self._slave, self._refs = start_slave(
            Path(self._dir), "hil", start, log=lambda status, msg: self.log.append(msg)
        )
        if any("initialisation failed" in m for m in self.log):
            raise RunStoppedError(f"the FMU rejected the setup: {self.log[-1]}")
        self._out = [self._refs[n] for n in ("platen_position", "input_force")]
        self._zero = self._slave.getReal([self._out[0]])[0]

    def _run(self, trajectory: Trajectory) -> Iterator[Sample]:
        from fmpy.fmi2 import fmi2Discard

        slave, x_ref, h = self._slave, self._refs["x_cmd"], trajectory.period
        t0 = getattr(self, "_time", 0.0)
        for i, (t, x) in enumerate(zip(trajectory.time, trajectory.x_cmd)):
            slave.setReal([x_ref], [float(x)])
            status = slave.fmi2DoStep(slave.component, t0 + i * h, h, 1)
            if status == fmi2Discard:
                raise RunStoppedError(f"the FMU rejected the step at t = {t:.3f} s: "
                                 f"{self.log[-1] if self.log else 'no message'}")
            platen, force = slave.getReal(self._out)
            yield Sample(float(t), float(x), platen - self._zero, force)
        self._time = t0 + len(trajectory) * h

    def _deactivate(self) -> None:
        from toggle.fmu_host import release_native_runtime

        try:
            if self._slave is not None:
                self._slave.terminate()
                self._slave.freeInstance()
        finally:
            self._slave = None
            if self._dir is not None:
                release_native_runtime(Path(self._dir))
                shutil.rmtree(self._dir, ignore_errors=True)
                self._dir = None


class RigPlant(Plant):
    """The real rig (or its emulator) over a serial URL: stepper, encoder, load cell.

    The MCU executes the trajectory; the host streams it in chunks and
    supervises: its watchdog, the MCU's faults and the force limit all end in
    a stop command and a closed port (:class:`hil.serial_link.SerialLink`).
    """

    name = "rig"

    def __init__(self, port: str, *, realtime: bool = True,
                 telemetry_timeout: float | None = None) -> None:
        super().__init__()
        self.port = port
        self.realtime = realtime
        self.telemetry_timeout = telemetry_timeout
        self._link = None

    def _activate(self) -> None:
        from hil import protocol as p
        from hil.serial_link import RigError, SerialLink

        s = self.setup
        self._x0, _ = s.stroke
        nominal = load_preset(s.preset)
        self._L0 = float(output_position(self._x0, nominal.lower))
        self._nominal = nominal
        self._link = SerialLink(self.port, realtime=self.realtime,
                                telemetry_timeout=self.telemetry_timeout)
        try:
            self._link.open()
            sc = self._link.scaling
            lo, hi = s.travel_limits
            self._link.configure(p.Config(
                force_limit_n=s.force_limit,
                steps_min=sc.steps(lo, self._x0), steps_max=sc.steps(hi, self._x0),
            ))
        except RigError as exc:
            self._link.close()
            raise RunStoppedError(f"rig at {self.port}: {exc}") from exc

    def _run(self, trajectory: Trajectory) -> Iterator[Sample]:
        from hil import protocol as p
        from hil.serial_link import RigError, RigFaultError

        link, sc, x0 = self._link, self._link.scaling, self._x0
        x = trajectory.x_cmd
        expected = np.asarray(output_position(x, self._nominal.lower)) - self._L0
        points = [(sc.steps(float(xi), x0), sc.counts(float(li))) for xi, li in zip(x, expected)]
        first = None
        try:
            for tel in link.run_trajectory(points):
                first = tel.sample if first is None else first
                status = Status.FAULT if tel.faults else (
                    Status.OK if tel.state == p.State.RUNNING else Status.STOPPING)
                yield Sample((tel.sample - first) * sc.period, sc.x(tel.steps, x0),
                             sc.platen(tel.enc), sc.force(tel.load_raw), status)
        except RigFaultError as exc:
            raise RunStoppedError(f"rig fault: {exc}") from exc
        except RigError as exc:
            raise RunStoppedError(f"rig link: {exc}") from exc

    def _deactivate(self) -> None:
        if self._link is not None:
            self._link.close()  # sends STOP and BYE, closes the port, never raises
            self._link = None
