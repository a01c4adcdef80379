"""What a search writes: the Pareto set as CSV and Parquet (units in the column names) and
every design as a preset TOML that the other commands take with ``--preset FILE``.

A design's preset is its base preset (clamp data, drive, masses, the family's group
merged in) with the linkage replaced by the design's half (both halves equal), the clamp's
open position set to the design's, its final tie-bar force to the target and its links'
mass to the design's (scaled with their sizes).
"""

from __future__ import annotations

import csv
import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from design.objectives import MEASURES, Evaluation, half_dims
from design.targets import OBJECTIVES, VARIABLES, Targets
from toggle.files import atomic_path
from toggle.params import DIMENSIONS, preset_table, select_group, split_group


def columns(targets: Targets) -> list[tuple[str, str, str]]:
    """(header, kind, key) of every column: key, variables, objectives, other measures."""
    out = [("key", "key", "key")]
    out += [(f"{v} ({VARIABLES[v][0]})", "variables", v) for v in VARIABLES]
    out += [(OBJECTIVES[k].header, "metrics", k) for k in targets.objectives]
    out += [(f"{k} ({u})", "metrics", k) for k, u in MEASURES.items()
            if k not in targets.objectives]
    return out


def rows(targets: Targets, evaluations: Sequence[Evaluation]) -> list[list[Any]]:
    cols = columns(targets)
    return [[e.key if kind == "key" else getattr(e, kind).get(key, math.nan)
             for _, kind, key in cols] for e in evaluations]


def write_csv(path: Path, targets: Targets, evaluations: Sequence[Evaluation]) -> Path:
    """The evaluations as CSV, one row per design, SI values, units in the headers."""
    with atomic_path(path) as tmp, tmp.open("w", newline="", encoding="utf-8") as f:
        writer = csv.writer(f)
        writer.writerow([h for h, _, _ in columns(targets)])
        writer.writerows([[repr(v) if isinstance(v, float) else v for v in row]
                          for row in rows(targets, evaluations)])
    return path


def write_parquet(path: Path, targets: Targets, evaluations: Sequence[Evaluation]) -> Path:
    """The same table as Parquet (pyarrow), column names as the CSV's headers."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    cols, data = columns(targets), rows(targets, evaluations)
    table = pa.table({h: [r[i] for r in data] for i, (h, _, _) in enumerate(cols)})
    with atomic_path(path) as tmp:
        pq.write_table(table, tmp)
    return path


def preset_dict(targets: Targets, evaluation: Evaluation, name: str,
                origin: str | None = None) -> dict[str, Any]:
    """The design as a preset table (SI), ready for :func:`toml_text`; ``origin``: how its
    description names the targets file (default: as the targets name it)."""
    base, group = split_group(targets.preset)
    table = select_group(preset_table(base)[0], group, targets.origin)
    table = {k: v for k, v in table.items() if k not in ("lower", "upper", "half")}
    dims = half_dims(evaluation.variables)
    table["name"] = name
    table["description"] = (f"designed by toggle design from {targets.preset} for "
                            f"{origin or targets.origin} (key {evaluation.key})")
    table["half"] = {d: getattr(dims, d) for d in DIMENSIONS}
    if "link_mass" in evaluation.metrics and "dynamics" in table:  # scaled with the links
        table["dynamics"] = dict(table["dynamics"], links=evaluation.metrics["link_mass"])
    if "clamp" in table:
        table["clamp"] = dict(table["clamp"], x_open=evaluation.metrics["x_open"])
        if "clamp_force" in targets.targets:
            table["clamp"]["final_tiebar_force"] = targets.targets["clamp_force"]
    return table


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {v!r} to TOML")


def toml_text(table: Mapping[str, Any], prefix: str = "") -> str:
    """A nested table of numbers, strings and lists as TOML (what the presets use)."""
    plain = [f"{k} = {_value(v)}" for k, v in table.items() if not isinstance(v, Mapping)]
    parts = ["\n".join(plain)] if plain else []
    for k, v in table.items():
        if isinstance(v, Mapping):
            name = f"{prefix}{k}"
            parts.append(f"[{name}]\n" + toml_text(v, name + ".").strip("\n"))
    return "\n\n".join(p for p in parts if p) + "\n"


def write_preset(path: Path, targets: Targets, evaluation: Evaluation,
                 name: str | None = None) -> Path:
    """Write a design as a preset TOML file. It names its targets file relative to its own
    folder, never by the machine's absolute path (the file moves with the project)."""
    stem = name or f"design-{evaluation.key[:12]}"
    origin = targets.origin
    if Path(origin).is_file():  # relative where the two share a folder, else its name
        shared = os.path.commonpath([Path(origin).resolve(), path.resolve().parent])
        origin = (os.path.relpath(origin, path.parent) if Path(shared).parent != Path(shared)
                  else Path(origin).name)
    text = (f"# {stem}: written by toggle design (SI units); load it with --preset and its "
            f"path\n" + toml_text(preset_dict(targets, evaluation, stem, origin)))
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return path


def write_results(folder: Path, targets: Targets, front: Sequence[Evaluation],
                  evaluations: Sequence[Evaluation]) -> dict[str, Path]:
    """pareto.csv, pareto.parquet, all.csv and presets/<key>.toml of the front's designs."""
    folder.mkdir(parents=True, exist_ok=True)
    out = {"pareto_csv": write_csv(folder / "pareto.csv", targets, front),
           "pareto_parquet": write_parquet(folder / "pareto.parquet", targets, front),
           "all_csv": write_csv(folder / "all.csv", targets,
                                [e for e in evaluations if e.feasible])}
    for e in front:
        write_preset(folder / "presets" / f"design-{e.key[:12]}.toml", targets, e)
    out["presets"] = folder / "presets"
    return out
