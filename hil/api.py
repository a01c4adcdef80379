"""The public API of the rig: run an experiment on the simulated or real rig, read a run.

`run_on_rig` is ``hil run`` called from Python (the same settings, checks, safety
and run directory: it goes through the command's own code, its report on stdout taken
as JSON); `read_run` reads a run directory back. Import both from `hil`; the
modules behind them are private by convention.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hil.host.recording import META_JSON, SAMPLES_CSV, SUMMARY_JSON, RecordingError, read_samples
from hil.host.run_settings import RUN_DEFAULTS
from toggle.params import ParameterError


@dataclass(frozen=True)
class Run:
    """A recorded run: its directory, settings, statistics and samples (SI).

    Attributes:
        dir: The run directory (``samples.csv``, ``meta.json``, ``summary.json``, the
            force plot).
        meta: Every setting that shaped the run (``meta.json``).
        summary: The statistics of seed 000's Tables 3-8 as ``{"mean", "three_sigma"}``
            and the link statistics (``summary.json``).
        time: Sample times, s.
        x_cmd: Commanded crosshead position, m.
        platen: Measured platen position, m.
        force: Measured input force (load cell), N.
        exit_code: The run's exit status as ``hil run`` gives it (0 done, 1 stopped early
            or link errors); None for a run read back.
    """

    dir: Path
    meta: dict[str, Any]
    summary: dict[str, Any]
    time: Any
    x_cmd: Any
    platen: Any
    force: Any
    exit_code: int | None = None

    @property
    def completed(self) -> bool:
        """Whether every cycle asked for went from open to the toggle and back."""
        return self.summary.get("cycles_complete", 0) >= self.meta.get("cycles", 1)


def read_run(run_dir: str | Path) -> Run:
    """Read a run directory that ``hil run`` (or `run_on_rig`) wrote.

    Args:
        run_dir: The run directory.

    Returns:
        Its settings, statistics and samples.

    Raises:
        RecordingError: A file missing or not what ``hil run`` writes.
    """
    run_dir = Path(run_dir)
    files = {}
    for name in (META_JSON, SUMMARY_JSON):
        try:
            files[name] = json.loads((run_dir / name).read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise RecordingError(f"cannot read {run_dir / name}: {exc}") from exc
    data = read_samples(run_dir / SAMPLES_CSV)
    return Run(run_dir, files[META_JSON], files[SUMMARY_JSON], data.t, data.x_cmd,
               data.platen, data.force)


def run_on_rig(profile: str | Path | None = None, *, real: bool = False,
               port: str | None = None, preset: str = "chang2021", speed: float | None = None,
               cycles: int = 3, delta_r8: float = 0.0, mu: float | None = None,
               x_contact: float | None = None, force_limit: float = 400.0,
               as_built: bool = True, out: str | Path | None = None,
               overwrite: bool = False, fmu: str | Path | None = None) -> Run:
    """Run a stroke on the simulated rig (the FMU) or on the real rig, and record it.

    Without ``profile`` or ``speed`` it runs the default job: the planned least-peak stroke
    of ``preset`` against its mold (``hil run``).

    Args:
        profile: A profile CSV (``Plan.export(path)`` or ``toggle plan --out``) to replay.
        real: Drive the real rig (or its emulator) on ``port`` instead of the FMU.
        port: The rig's serial port (with ``real``).
        preset: The clamp's preset (name or TOML path); a profile's own preset wins.
        speed: Constant crosshead speed of the paper's experiments, m/s (no mold).
        cycles: Closing-opening cycles to run.
        delta_r8: Error of the upper half's link r8, m (seed 000's experiments).
        mu: Pin friction coefficient; default the preset's.
        x_contact: Mold-contact crosshead position, m; default the planned mold.
        force_limit: The host's input-force limit, N (the run stops beyond it).
        as_built: The simulated chang2021 rig carries the prototype's as-built error.
        out: The run directory; default ``runs/<time>-<backend>``.
        overwrite: Replace an earlier run's files in ``out``.
        fmu: A built FMU to use instead of building or reusing ``build/``'s.

    Returns:
        The recorded run (`read_run` of its directory) with its exit code.

    Raises:
        ParameterError: Bad settings (the message names them as ``hil run`` options).
        OutputError: An earlier run in ``out`` without ``overwrite``.
        RunStoppedError: The rig did not answer or could not start.
    """
    from hil.cli import run as run_command
    from hil.cli.interrupts import SignalGuard
    from hil.host.run_settings import resolve_settings
    from toggle.files import allow_overwrite

    if port is not None and not real:
        raise ParameterError("port is the real rig's: give real=True too")
    values = {**RUN_DEFAULTS, "backend": "real" if real else "fmu", "port": port,
              "preset": preset, "profile": profile, "cycles": cycles, "speed": speed,
              "delta_r8": delta_r8, "mu": mu, "x_contact": x_contact,
              "force_limit": force_limit, "as_built": as_built, "out": out, "fmu": fmu}
    args = argparse.Namespace(config=None, json=True, quiet=True, force=overwrite, **values)
    allow_overwrite(overwrite)
    report = io.StringIO()
    try:
        settings = resolve_settings(args)
        guard = SignalGuard()
        with guard, contextlib.redirect_stdout(report):
            code = run_command.execute(settings, guard)
    finally:
        allow_overwrite(True)
    try:
        run_dir = json.loads(report.getvalue())["run_dir"]
    except (json.JSONDecodeError, KeyError) as exc:
        raise RecordingError(f"hil run gave no report: {report.getvalue()[:200]!r}") from exc
    run = read_run(run_dir)
    return Run(**{**run.__dict__, "exit_code": code})
