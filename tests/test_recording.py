"""Run directories: CSV kept through crashes, the statistics of Tables 3-8 on known streams."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from hil.host.recording import (
    CSV_COLUMNS,
    FORCE_PNG,
    NOT_CLOSED,
    STATISTICS,
    SUMMARY_JSON,
    RecordingError,
    RunMeta,
    RunRecorder,
    read_samples,
    summarize,
    summarize_run,
)
from hil.host.samples import Sample, Status
from toggle.rig_tables import F_TP_LATENCY

X_OPEN, X_TP = -0.0034, 0.0516
STROKE_THEORY = 0.045
N = 40  # samples per stroke
#: The forward sample whose force is F_TP: F_TP_LATENCY before the toggle sample (the first
#: within the encoder's resolution of the end), the rig's reading (issue 18)
TP_INDEX = max(0, N - 1 - round(F_TP_LATENCY / 1e-3))


def meta(**kw) -> RunMeta:
    base = dict(backend="synthetic", preset="test", cycles=3, delta_r8=0.0, period=1e-3,
                x_open=X_OPEN, x_toggle=X_TP, stroke_theory=STROKE_THEORY, speed=0.025)
    return RunMeta(**{**base, **kw})


def synthetic_stream(si, sf, fmax, ftp, bmin, zero=0.2):
    """Cycles with known statistics; every sample belongs to exactly one stroke.

    Each stroke has N samples and the ends are held for two samples (at the toggle the
    forward stroke's last sample and the backward stroke's first one). Forward force
    alternates +-fmax except ftp at TP_INDEX, where the rig reads F_TP; backward force
    alternates +-|bmin|.
    """
    u = np.linspace(0.0, 1.0, N)
    alt = np.where(np.arange(N) % 2 == 0, 1.0, -1.0)
    samples, t = [], 0.0
    for k in range(len(si)):
        fwd_force = fmax[k] * alt
        fwd_force[TP_INDEX] = ftp[k]
        nxt = si[k + 1] if k + 1 < len(si) else si[k]
        strokes = (
            (X_OPEN + (X_TP - X_OPEN) * u, zero + si[k] + (sf[k] - si[k]) * u, fwd_force),
            (X_TP - (X_TP - X_OPEN) * u, zero + sf[k] + (nxt - sf[k]) * u, -bmin[k] * alt),
        )
        for x, p, f in strokes:
            for xi, pi, fi in zip(x, p, f):
                samples.append(Sample(t, float(xi), float(pi), float(fi), Status.OK))
                t += 1e-3
    return samples


def expected(values):
    a = np.asarray(values, dtype=float)
    return a.mean(), 3 * a.std(ddof=1)


def test_summary_statistics_of_a_known_stream(tmp_path):
    si = [0.0, -20e-6, 15e-6]
    sf = [45.40e-3, 45.38e-3, 45.42e-3]
    fmax, ftp, bmin = [60.0, 70.0, 80.0], [3.0, -2.0, 5.0], [-50.0, -40.0, -45.0]
    with RunRecorder(meta(), tmp_path / "run", flush_every=17) as rec:
        for s in synthetic_stream(si, sf, fmax, ftp, bmin):
            rec.append(s)
    summary = json.loads((tmp_path / "run" / SUMMARY_JSON).read_text())
    assert summary["cycles_complete"] == 3 and summary["samples"] == 3 * 2 * N
    assert summary["meta"]["aborted"] is False
    fwd_rms = [np.sqrt(((N - 1) * a**2 + b**2) / N) for a, b in zip(fmax, ftp)]
    want = {
        "stroke_initial": expected(si),
        "stroke_final": expected(sf),
        "stroke": expected(np.subtract(sf, si)),
        "stroke_error": expected(np.subtract(sf, si) - STROKE_THEORY),
        "force_forward_max": expected(fmax),
        "force_forward_rms": expected(fwd_rms),
        "force_backward_min": expected(bmin),
        "force_backward_rms": expected(np.abs(bmin)),
        "force_toggle": expected(ftp),
    }
    assert set(want) == set(STATISTICS)
    for key, (mean, three_sigma) in want.items():
        tol = 2e-9 if key.startswith("stroke") else 2e-5  # CSV: 1 nm and 10 uN digits
        assert summary[key]["mean"] == pytest.approx(mean, abs=tol), key
        assert summary[key]["three_sigma"] == pytest.approx(three_sigma, abs=3 * tol), key
    assert (tmp_path / "run" / FORCE_PNG).stat().st_size > 0


def test_csv_header_has_units(tmp_path):
    with RunRecorder(meta(), tmp_path / "run", plot=False) as rec:
        rec.append(Sample(0.0, X_OPEN, 0.1, 1.5))
    header = (tmp_path / "run" / "samples.csv").read_text().splitlines()[0].split(",")
    assert header == list(CSV_COLUMNS)
    for unit in ("time [s]", "x_cmd [m]", "platen [m]", "force [N]"):
        assert unit in header


def test_platen_zero_defaults_to_first_sample_and_can_be_given(tmp_path):
    stream = synthetic_stream([0.0, 1e-5, 2e-5], [0.045] * 3, [1.0] * 3, [0.0] * 3, [-1.0] * 3,
                              zero=0.3)
    with RunRecorder(meta(), tmp_path / "run", plot=False) as rec:
        for s in stream:
            rec.append(s)
    csv_path = tmp_path / "run" / "samples.csv"
    assert summarize(csv_path, meta())["stroke_initial"]["mean"] == pytest.approx(1e-5, abs=1e-9)
    shifted = summarize(csv_path, meta(platen_zero=0.3 - 1e-3))
    assert shifted["stroke_initial"]["mean"] == pytest.approx(1e-3 + 1e-5, abs=1e-9)
    assert shifted["stroke"]["mean"] == pytest.approx(0.045 - 1e-5, abs=1e-9)


KILLED_RUN = textwrap.dedent("""
    import os, signal, sys
    from hil.host.recording import RunMeta, RunRecorder
    from hil.host.samples import Sample
    meta = RunMeta(backend="synthetic", preset="test", cycles=1, delta_r8=0.0, period=1e-3,
                   x_open=-0.0034, x_toggle=0.0516, stroke_theory=0.045, speed=0.025)
    rec = RunRecorder(meta, sys.argv[1], flush_every=100, flush_interval=1e9)
    for i in range(1050):
        rec.append(Sample(i * 1e-3, -0.0034 + i * 1e-6, 0.2 + i * 1e-7, float(i)))
    os.kill(os.getpid(), signal.SIGKILL)
""")


def test_a_killed_run_keeps_every_flushed_sample(tmp_path):
    run = tmp_path / "killed"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    proc = subprocess.run([sys.executable, "-c", KILLED_RUN, str(run)], env=env, timeout=60,
                          capture_output=True, text=True)
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    data = read_samples(run / "samples.csv")
    assert data.t.size == 1000  # ten full chunks; the 50 unflushed samples died with it
    assert np.array_equal(data.force, np.arange(1000.0))
    with (run / "samples.csv").open("a") as fh:
        fh.write("1.000000,0.0001")  # a row cut short by the crash is skipped
    summary = summarize_run(run)
    assert summary["samples"] == 1000 and summary["cycles_complete"] == 0
    assert summary["meta"]["aborted"] is True and summary["meta"]["abort_reason"] == NOT_CLOSED
    assert all(summary[k] is None for k in STATISTICS)


def test_exception_marks_run_aborted_and_keeps_data(tmp_path):
    stream = synthetic_stream([0.0] * 3, [0.045] * 3, [1.0] * 3, [0.0] * 3, [-1.0] * 3)
    cut = len(stream) * 2 // 3 + 5  # dies during the third cycle
    with (pytest.raises(RuntimeError, match="link lost"),
          RunRecorder(meta(), tmp_path / "run", flush_every=1000) as rec):
        for s in stream[:cut]:
            rec.append(s)
        raise RuntimeError("link lost")
    summary = json.loads((tmp_path / "run" / SUMMARY_JSON).read_text())
    assert summary["samples"] == cut and summary["cycles_complete"] == 2
    assert summary["meta"]["aborted"] is True
    assert summary["meta"]["abort_reason"] == "RuntimeError: link lost"
    assert summary["force_toggle"]["mean"] == pytest.approx(0.0)


def test_recorder_guards(tmp_path):
    with (RunRecorder(meta(), tmp_path / "run", plot=False) as rec,
          pytest.raises(RecordingError, match="non-finite")):
        rec.append(Sample(0.0, X_OPEN, float("nan"), 0.0))
    with pytest.raises(RecordingError, match="already holds a run"):
        RunRecorder(meta(), tmp_path / "run")
    with pytest.raises(RecordingError, match="unknown run metadata"):
        RunMeta.from_dict({**json.loads((tmp_path / "run" / "meta.json").read_text()), "x": 1})


def test_meta_for_experiment_uses_the_nominal_stroke(chang):
    from toggle.kinematics import stroke, stroke_limits

    m = RunMeta.for_experiment(chang, backend="fmu", cycles=100, delta_r8=0.5e-3,
                               period=1e-3, speed=0.015)
    assert (m.x_open, m.x_toggle) == stroke_limits(chang.lower)
    assert m.stroke_theory == stroke(chang.lower) and m.preset == "chang2021"
