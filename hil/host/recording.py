"""A run directory: every sample in a CSV as it arrives, the paper's statistics, force plots.

Layout of a run directory::

    meta.json          what was run (written at the start, completed at the end)
    samples.csv        one row per sample, units in the header, flushed in chunks
    summary.json       statistics over cycles (Chang, Lee & Hsu 2021, Tables 3-8), SI
    force_curves.png   averaged input force against x, forward and backward (Figs 14-16)

The summary is computed from the CSV alone (plus meta.json), so a run that died can be
summarised afterwards with :func:`summarize_run`.

Statistics, each ``{"mean", "three_sigma"}`` over the complete cycles (three_sigma is 3
sample standard deviations, None with a single cycle), following section 5.1:

* stroke_initial Si: platen position at x_open where the forward stroke starts, relative
  to the platen zero (meta ``platen_zero``; by default the run's first sample, taken at
  rest at x_open -- the theoretical Si is then 0);
* stroke_final Sf: platen position at the toggle sample, relative to the same zero;
* stroke S = Sf - Si (the platen's travel in the cycle; Table 3: 45.394 - (-0.011) = 45.405);
* stroke_error dS = S - stroke_theory (the nominal stroke, 45.003 mm for chang2021);
* force_forward_max / force_forward_rms: max and RMS of the force over the forward stroke;
* force_backward_min / force_backward_rms: min and RMS over the backward stroke;
* force_toggle F_TP: the force as the encoder passes the toggle in motion, read as the
  prototype's rig read it (:class:`toggle.rig_tables.RigReading`): the force sampled
  :data:`toggle.rig_tables.F_TP_LATENCY` before the first forward sample whose platen
  reading is within the encoder's resolution of the platen at the toggle sample.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import time
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields, replace
from datetime import datetime
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from hil.host.experiment import DEFAULT_END_TOL, Cycle, segment_cycles
from hil.host.samples import Sample, TrajectoryError
from toggle.elastics import clamp_stroke
from toggle.json_text import json_text
from toggle.kinematics import output_position
from toggle.params import Mechanism
from toggle.rig_calibration import load_paper_tables
from toggle.rig_tables import F_TP_LATENCY, TOGGLE_BAND

CSV_COLUMNS = ("time [s]", "x_cmd [m]", "platen [m]", "force [N]", "status", "sample")
#: The header of run directories written before the sample column existed (still read).
LEGACY_COLUMNS = CSV_COLUMNS[:-1]
SAMPLES_CSV = "samples.csv"
META_JSON = "meta.json"
SUMMARY_JSON = "summary.json"
FORCE_PNG = "force_curves.png"
#: Every file a run directory holds (``hil run --out`` refuses them without ``--force``).
RUN_FILES = (META_JSON, SAMPLES_CSV, SUMMARY_JSON, FORCE_PNG)
STATISTICS = (
    "stroke_initial", "stroke_final", "stroke", "stroke_error",
    "force_forward_max", "force_forward_rms", "force_backward_min", "force_backward_rms",
    "force_toggle",
)
NOT_CLOSED = "the recording was not closed (the process died); summary recomputed from the CSV"

if TYPE_CHECKING:
    from collections.abc import Callable

    from hil.host.backends import Plant
    from hil.host.samples import Trajectory


class RecordingError(ValueError):
    """A run directory or sample that cannot be recorded or summarised."""


@dataclass(frozen=True)
class RunMeta:
    """What a run did, SI units. ``speed`` is None for a planned profile."""

    backend: str
    preset: str
    cycles: int
    delta_r8: float
    period: float
    x_open: float
    x_toggle: float
    stroke_theory: float
    speed: float | None = None
    profile: str | None = None
    platen_zero: float | None = None
    aborted: bool = False
    abort_reason: str | None = None
    started: str | None = None
    finished: str | None = None
    #: every setting that shaped the run (SI): preset, mold position, mu, limits, watchdogs,
    #: the profile file and its SHA-256, the duration guard
    settings: dict[str, Any] = field(default_factory=dict)
    #: the back-end: FMU, or the rig's port, protocol and firmware versions and boot id
    plant: dict[str, Any] = field(default_factory=dict)
    #: link statistics of a rig session (bad frames, lost and duplicate samples, ...)
    link: dict[str, Any] = field(default_factory=dict)
    extra: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def for_experiment(cls, nominal: Mechanism, **kw: Any) -> RunMeta:
        """Meta with x_open (the machine's open position where the preset gives one,
        :func:`toggle.elastics.clamp_stroke`), x_toggle and the theoretical stroke between
        them of the nominal mechanism."""
        x_open, x_toggle = clamp_stroke(nominal)
        kw.setdefault("preset", nominal.name)
        travel = output_position(x_toggle, nominal.lower) - output_position(x_open, nominal.lower)
        return cls(x_open=x_open, x_toggle=x_toggle, stroke_theory=float(travel), **kw)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> RunMeta:
        known = {f.name for f in fields(cls)}
        unknown = set(data) - known
        if unknown:
            raise RecordingError(f"unknown run metadata {sorted(unknown)}")
        try:
            return cls(**data)
        except TypeError as exc:
            raise RecordingError(f"incomplete run metadata: {exc}") from exc


class RunData(NamedTuple):
    """The numeric columns of a samples CSV."""

    t: np.ndarray
    x_cmd: np.ndarray
    platen: np.ndarray
    force: np.ndarray


class ForceCurves(NamedTuple):
    """Averaged input force (N) on a grid of input positions x (m); NaN where no sample fell."""

    x: np.ndarray
    forward: np.ndarray
    backward: np.ndarray


def default_run_dir(backend: str, root: str | Path = "runs") -> Path:
    """``root/<YYYYmmdd-HHMMSS>-<backend>``, with a numeric suffix if that exists."""
    base = Path(root) / f"{datetime.now():%Y%m%d-%H%M%S}-{backend}"
    path, n = base, 1
    while path.exists():
        n += 1
        path = base.with_name(f"{base.name}-{n}")
    return path


def _now() -> str:
    return datetime.now().astimezone().isoformat(timespec="seconds")


def _write_json(path: Path, payload: Any) -> None:
    """Write JSON through a temporary file, so a crash never leaves half a file."""
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json_text(payload) + "\n", encoding="utf-8")
    tmp.replace(path)


class RunRecorder:
    """Records one run; use as a context manager around the back-end's sample loop.

    Samples are buffered and written every ``flush_every`` samples or ``flush_interval``
    seconds, whichever comes first, and on close. Leaving the ``with`` block by an
    exception (Ctrl-C included) marks the run aborted with the reason, then writes the
    summary and plot of what was measured, and lets the exception propagate.
    A directory that holds a run is refused unless ``overwrite`` (``hil run --force``): then
    the earlier run's files are removed first, so none of them is mixed into the new run.
    """

    def __init__(self, meta: RunMeta, out_dir: str | Path | None = None, *,
                 flush_every: int = 250, flush_interval: float = 0.5, plot: bool = True,
                 overwrite: bool = False) -> None:
        if flush_every < 1 or not flush_interval > 0:
            raise RecordingError("flush_every must be >= 1 and flush_interval > 0")
        self.dir = Path(out_dir) if out_dir is not None else default_run_dir(meta.backend)
        self.csv_path = self.dir / SAMPLES_CSV
        if self.csv_path.exists() and not overwrite:
            raise RecordingError(f"{self.dir} already holds a run; choose another --out "
                                 "or give --force")
        for name in RUN_FILES if overwrite else ():
            with contextlib.suppress(FileNotFoundError):
                (self.dir / name).unlink()
        self.meta = replace(meta, started=meta.started or _now())
        self.summary: dict[str, Any] | None = None
        self._flush_every, self._flush_interval, self._plot = flush_every, flush_interval, plot
        self._buffer: list[str] = []
        self._last_flush = time.monotonic()
        self.count = 0
        try:
            self.dir.mkdir(parents=True, exist_ok=True)
            _write_json(self.dir / META_JSON, asdict(self.meta))
            self._file = self.csv_path.open("w", encoding="utf-8", newline="")
        except OSError as exc:
            raise RecordingError(f"run directory {self.dir}: cannot write there "
                                 f"({exc.strerror or exc})") from exc
        self._file.write(",".join(CSV_COLUMNS) + "\n")
        self._file.flush()

    def append(self, s: Sample) -> None:
        """Buffer one sample; flush the chunk when it is full or old enough."""
        if self._file.closed:
            raise RecordingError("the recorder is closed")
        values = (s.t, s.x_cmd, s.platen, s.force)
        if not all(math.isfinite(v) for v in values):
            raise RecordingError(f"non-finite sample {s}")
        self._buffer.append(f"{s.t:.6f},{s.x_cmd:.9f},{s.platen:.9f},{s.force:.5f},"
                            f"{getattr(s.status, 'value', s.status)},{s.index}\n")
        self.count += 1
        if (len(self._buffer) >= self._flush_every
                or time.monotonic() - self._last_flush >= self._flush_interval):
            self.flush()

    def flush(self) -> None:
        """Write the buffered samples to the CSV and hand them to the OS."""
        if self._buffer:
            self._file.write("".join(self._buffer))
            self._buffer.clear()
        self._file.flush()
        self._last_flush = time.monotonic()

    def abort(self, reason: str) -> None:
        """Mark the run aborted (the first reason given is kept)."""
        if not self.meta.aborted:
            self.meta = replace(self.meta, aborted=True, abort_reason=reason)

    def annotate(self, **fields_: Any) -> None:
        """Complete the metadata (plant identity, link statistics) before closing."""
        self.meta = replace(self.meta, **fields_)

    def close(self) -> dict[str, Any]:
        """Flush and close the CSV, complete meta.json, write summary.json and the plot."""
        if self.summary is not None:
            return self.summary
        self.flush()
        self._file.close()
        self.meta = replace(self.meta, finished=_now())
        _write_json(self.dir / META_JSON, asdict(self.meta))
        self.summary = summarize_run(self.dir, plot=self._plot)
        return self.summary

    def __enter__(self) -> RunRecorder:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if exc is not None:
            if isinstance(exc, KeyboardInterrupt):
                reason = "interrupted by the user"
            elif isinstance(exc, Exception):
                reason = f"{type(exc).__name__}: {exc}"
            else:  # hil.cli.interrupts.Interrupted: 'interrupted by SIGTERM'
                reason = str(exc) or type(exc).__name__
            self.abort(reason)
        self.close()


def read_samples(csv_path: str | Path) -> RunData:
    """The numeric columns of a samples CSV; an unfinished last line (a crash) is dropped."""
    path = Path(csv_path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise RecordingError(f"cannot read {path}: {exc}") from exc
    header = raw.split(b"\n", 1)[0].decode("utf-8", "replace").strip()
    if header not in (",".join(CSV_COLUMNS), ",".join(LEGACY_COLUMNS)):
        raise RecordingError(f"{path} is not a samples CSV (header {header!r})")
    rows = raw.count(b"\n") - 1
    if rows <= 0:
        return RunData(*(np.empty(0) for _ in range(4)))
    table = np.loadtxt(io.BytesIO(raw), delimiter=",", skiprows=1, usecols=(0, 1, 2, 3),
                       max_rows=rows, ndmin=2)
    return RunData(*table.T)


def _stat(values: list[float]) -> dict[str, float | None]:
    a = np.asarray(values, dtype=float)
    return {"mean": float(a.mean()),
            "three_sigma": float(3 * a.std(ddof=1)) if a.size > 1 else None}


def cycle_statistics(data: RunData, cycles: list[Cycle], stroke_theory: float,
                     platen_zero: float) -> dict[str, dict[str, float | None]]:
    """The nine statistics of Tables 3-8 over ``cycles`` (see the module docstring)."""
    per: dict[str, list[float]] = {k: [] for k in STATISTICS}
    for c in cycles:
        si = data.platen[c.start] - platen_zero
        sf = data.platen[c.toggle] - platen_zero
        fwd, bwd = data.force[c.forward], data.force[c.backward]
        reached = c.start + int(np.argmax(data.platen[c.forward]
                                          >= data.platen[c.toggle] - TOGGLE_BAND))
        passing = c.start + int(np.searchsorted(data.t[c.start:reached + 1],
                                                data.t[reached] - F_TP_LATENCY))
        for key, value in zip(STATISTICS, (
            si, sf, sf - si, sf - si - stroke_theory,
            fwd.max(), math.sqrt(np.mean(fwd * fwd)), bwd.min(), math.sqrt(np.mean(bwd * bwd)),
            data.force[passing],
        )):
            per[key].append(float(value))
    return {k: _stat(v) for k, v in per.items()}


def _summarize(data: RunData, meta: RunMeta) -> tuple[dict[str, Any], list[Cycle]]:
    cycles = (segment_cycles(data.x_cmd, meta.x_open, meta.x_toggle, DEFAULT_END_TOL)
              if data.t.size else [])
    zero = meta.platen_zero if meta.platen_zero is not None else (
        float(data.platen[0]) if data.t.size else 0.0)
    summary: dict[str, Any] = {
        "units": "SI (m, N, s)",
        "samples": int(data.t.size),
        "cycles_complete": len(cycles),
        "platen_zero": zero,
        "aborted": meta.aborted,
        "abort_reason": meta.abort_reason,
        "link": meta.link,
    }
    if cycles:
        summary.update(cycle_statistics(data, cycles, meta.stroke_theory, zero))
    else:
        summary.update({k: None for k in STATISTICS})
    summary["meta"] = asdict(meta)
    return summary, cycles


def summarize(csv_path: str | Path, meta: RunMeta | Mapping[str, Any]) -> dict[str, Any]:
    """Summary of a run (JSON-ready, SI) from its samples CSV and metadata.

    The nine statistics are None when no cycle completed.
    """
    meta = meta if isinstance(meta, RunMeta) else RunMeta.from_dict(meta)
    return _summarize(read_samples(csv_path), meta)[0]


def averaged_force_curves(data: RunData, cycles: list[Cycle], x_open: float, x_toggle: float,
                          bins: int = 200) -> ForceCurves:
    """Force averaged over cycles in ``bins`` bins of x, per stroke direction (Figs 14-16).

    Every sample of every cycle's stroke is pooled into its x bin; the cycles share one
    timing, so each contributes equally and the bin mean is the cycle average.
    """
    edges = np.linspace(x_open, x_toggle, bins + 1)

    def binned(part: str) -> np.ndarray:
        idx = np.concatenate([np.arange(s.start, s.stop)
                              for s in (getattr(c, part) for c in cycles)])
        k = np.clip(np.searchsorted(edges, data.x_cmd[idx], side="right") - 1, 0, bins - 1)
        count = np.bincount(k, minlength=bins)
        total = np.bincount(k, weights=data.force[idx], minlength=bins)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(count > 0, total / np.maximum(count, 1), np.nan)

    return ForceCurves(0.5 * (edges[:-1] + edges[1:]), binned("forward"), binned("backward"))


def plot_force_curves(curves: Mapping[str, ForceCurves], path: str | Path,
                      title: str = "Averaged input force") -> Path:
    """Forward (solid) and backward (dashed) averaged force against x, one colour per run."""
    from toggle.plots import plt, save_figure

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for i, (label, c) in enumerate(curves.items()):
        colour = f"C{i % 10}"
        ax.plot(c.x * 1e3, c.forward, "-", color=colour, label=f"{label}, forward")
        ax.plot(c.x * 1e3, c.backward, "--", color=colour, label=f"{label}, backward")
    ax.axhline(0.0, color="0.5", lw=0.8)
    ax.set_xlabel("input position x (mm)")
    ax.set_ylabel("input force F (N)")
    ax.set_title(title)
    ax.legend(fontsize="small")
    return save_figure(fig, Path(path))


def _curve_label(meta: RunMeta) -> str:
    speed = f"v = {meta.speed * 1e3:g} mm/s, " if meta.speed is not None else ""
    return f"{speed}\u0394r8 = {meta.delta_r8 * 1e3:g} mm"


def summarize_run(run_dir: str | Path, *, plot: bool = True) -> dict[str, Any]:
    """(Re)compute a run directory's summary.json and force plot from its CSV and meta.json.

    A run whose meta.json was never completed (the process died) is marked aborted.
    """
    run_dir = Path(run_dir)
    try:
        meta = RunMeta.from_dict(json.loads((run_dir / META_JSON).read_text(encoding="utf-8")))
    except (OSError, json.JSONDecodeError) as exc:
        raise RecordingError(f"cannot read {run_dir / META_JSON}: {exc}") from exc
    if meta.finished is None and not meta.aborted:
        meta = replace(meta, aborted=True, abort_reason=NOT_CLOSED)
    data = read_samples(run_dir / SAMPLES_CSV)
    summary, cycles = _summarize(data, meta)
    _write_json(run_dir / SUMMARY_JSON, summary)
    if plot and cycles:
        curves = averaged_force_curves(data, cycles, meta.x_open, meta.x_toggle)
        plot_force_curves({_curve_label(meta): curves}, run_dir / FORCE_PNG,
                          title=f"{meta.preset} on {meta.backend}: averaged input force "
                                f"over {len(cycles)} cycles")
    return summary


def record_run(plant: Plant, trajectory: Trajectory, rec: RunRecorder,
               check: Callable[[], None] = lambda: None,
               on_sample: Callable[[Sample], None] = lambda _s: None) -> str | None:
    """Run ``trajectory`` on the active ``plant`` into ``rec``; stop and keep the rest on
    every ending (``hil run`` and the panel's rig service share it).

    Each sample is recorded, then handed to ``on_sample``, then ``check`` is called (it
    may raise to end the run: a signal, the panel's STOP). Returns why the run stopped
    early (None when complete); an exception other than the plant's stop propagates after
    the samples up to the standstill are recorded and the run is marked aborted.
    """
    from hil.host.backends import RunStoppedError

    reason = None
    samples = plant.run(trajectory, check)
    try:
        for sample in samples:
            rec.append(sample)
            on_sample(sample)
            check()
    except (RunStoppedError, TrajectoryError) as exc:
        reason = str(exc)
    except BaseException as exc:
        reason = str(exc) or type(exc).__name__
        raise
    finally:
        samples.close()
        for sample in plant.stop():
            rec.append(sample)
            on_sample(sample)
        rec.annotate(plant=plant.describe(), link=plant.link_report())
        if reason is not None:
            rec.abort(reason)
    return reason


def prototype_statistics(preset: str, speed: float | None,
                         delta_r8: float) -> dict[str, Any] | None:
    """Seed 000's measured statistics (Tables 3-8, SI: mean and printed 3 sigma) of a
    constant-speed run of ``preset`` at one of their speeds and link-8 errors, with the
    table's number; None for any other run (a planned or replayed profile)."""
    if speed is None:
        return None
    tables = load_paper_tables()
    cell = tables.cell(preset, speed, delta_r8)
    if cell is None:
        return None
    i, j = cell
    return {"speed": float(tables.speeds[i]), "delta_r8": float(tables.errors[j]),
            **{key: {"table": (3 if key == "stroke" else 6) + i,
                     "mean": float(tables.mean[key][i, j]),
                     "three_sigma": float(tables.three_sigma[key][i, j])}
               for key in tables.mean}}
