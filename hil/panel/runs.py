"""Past runs for the page: the list of run directories, one run's curves, its statistics of
Tables 3-8 beside the prototype's. Everything is read with hil.host.recording (the same CSV
reader, summary and prototype cells as ``hil run``); nothing is recomputed here.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from hil.host.recording import (
    META_JSON,
    SAMPLES_CSV,
    STATISTICS,
    SUMMARY_JSON,
    RecordingError,
    RunMeta,
    prototype_statistics,
    read_samples,
    summarize_run,
)

#: Most points of a run sent to the page (the CSV is decimated evenly beyond).
MAX_POINTS = 5000
#: Most runs listed, newest first.
MAX_RUNS = 200


class RunNotFoundError(LookupError):
    """No run of that name under the runs folder."""


def _run_dir(root: Path, name: str) -> Path:
    path = root / name
    if "/" in name or "\\" in name or name.startswith(".") or not (path / META_JSON).is_file():
        raise RunNotFoundError(f"no run {name!r} in {root}")
    return path


def list_runs(root: Path) -> list[dict[str, Any]]:
    """The runs under ``root``, newest first: name, start, backend, job, cycles, state."""
    out = []
    dirs = sorted((d for d in root.glob("*") if (d / META_JSON).is_file()),
                  key=lambda d: d.name, reverse=True)
    for d in dirs[:MAX_RUNS]:
        try:
            meta = json.loads((d / META_JSON).read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError):
            continue
        out.append({"name": d.name, "started": meta.get("started"),
                    "backend": meta.get("backend"), "job": meta.get("profile"),
                    "speed": meta.get("speed"), "cycles": meta.get("cycles"),
                    "aborted": meta.get("aborted"),
                    "finished": meta.get("finished") is not None})
    return out


def open_run(root: Path, name: str) -> dict[str, Any]:
    """One run: its samples (decimated to MAX_POINTS), summary and the prototype's cells."""
    d = _run_dir(root, name)
    try:
        data = read_samples(d / SAMPLES_CSV)
        meta = RunMeta.from_dict(json.loads((d / META_JSON).read_text(encoding="utf-8")))
        summary = (json.loads((d / SUMMARY_JSON).read_text(encoding="utf-8"))
                   if (d / SUMMARY_JSON).is_file() else summarize_run(d, plot=False))
    except (RecordingError, OSError, json.JSONDecodeError) as exc:
        raise RunNotFoundError(f"run {name!r} cannot be read: {exc}") from None
    step = max(1, -(-data.t.size // MAX_POINTS))
    pick = np.arange(0, data.t.size, step)
    paper = prototype_statistics(meta.preset, meta.speed, meta.delta_r8)
    rows = [{"key": key, "mean": (summary.get(key) or {}).get("mean"),
             "three_sigma": (summary.get(key) or {}).get("three_sigma"),
             "paper": None if paper is None else paper.get(key)} for key in STATISTICS]
    return {"name": name, "meta": {"backend": meta.backend, "preset": meta.preset,
                                   "speed": meta.speed, "delta_r8": meta.delta_r8,
                                   "cycles": meta.cycles, "profile": meta.profile,
                                   "aborted": meta.aborted, "abort_reason": meta.abort_reason},
            "samples": int(data.t.size), "cycles_complete": summary.get("cycles_complete"),
            "t": data.t[pick].round(4).tolist(), "x": data.x_cmd[pick].tolist(),
            "platen": data.platen[pick].tolist(), "force": data.force[pick].round(4).tolist(),
            "statistics": rows, "link": summary.get("link") or {}}
