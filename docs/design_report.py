"""The numbers, tables and figures of docs/design-runs.md, from the commands it documents.

Run from the repository: ``.venv/bin/python docs/design_report.py``. It runs each documented
``toggle design`` command as written (in this process, through the command line; the record
goes to build/design/ and a rerun resumes from it, with --force over a finished run's
files), reads the record back by replaying the same seeded search (nothing is computed
again: it checks that), and prints the Markdown of
docs/design-runs.md's tables: seed 004's groups against the front, and the SM-55 redesign with
every objective and constraint against the SM-55, both opened by the same rule. Writes the
figures to docs/design/ and the chosen SM-55 design to design/examples/sm55_design.toml
(the SM-55 opened by the same rule to build/design/sm55_reference.toml), runs
``toggle plan --min-time --cycle`` and ``hil run`` (the simulated rig) on both, as placed and
with the open position moved by up to 100 um (what holds across them), and draws the
design to scale with ``toggle plot linkage``.
``tests/test_design_report.py`` runs it on a reduced search.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import os
import shutil
import sys
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from design.figures import front_figure, parallel_figure  # noqa: E402
from design.objectives import Evaluator  # noqa: E402
from design.output import write_preset  # noqa: E402
from design.placement import Row, compare, improvements, place  # noqa: E402
from design.search import SearchResult, run_search  # noqa: E402
from design.targets import OBJECTIVES, load_targets  # noqa: E402

EXAMPLES, FIGURES = ROOT / "design" / "examples", ROOT / "docs" / "design"
#: The documented searches: targets file and the options of its command line.
SEARCHES = {"li_micro": {"generations": 40, "population": 60, "seed": 0},
            "sm55": {"generations": 40, "population": 60, "seed": 0}}


def command(name: str, search: dict, out: Path) -> list[str]:
    """The documented command line (after ``toggle``), paths relative to the repository."""
    return ["design", f"design/examples/{name}.toml", "--generations",
            str(search["generations"]), "--population", str(search["population"]), "--seed",
            str(search["seed"]), "--out", os.path.relpath(out, ROOT), "--no-figures", "--json"]


def run_cli(main: Callable[[Sequence[str]], int], prog: str, argv: list[str]) -> str:
    """Run a command line in this process from the repository's root; its standard output.
    A failed run stops the script, naming the command."""
    text, here = io.StringIO(), Path.cwd()
    os.chdir(ROOT)
    try:
        with contextlib.redirect_stdout(text):
            code = main(argv)
    finally:
        os.chdir(here)
    if code != 0:
        raise SystemExit(f"{prog} {' '.join(argv)} exited {code}")
    return text.getvalue()


def run_documented(name: str, search: dict, out: Path) -> tuple[str, SearchResult]:
    """Run the documented command, then replay its record (which must compute nothing).
    Over a finished run it adds --force: the record is kept and resumed, its files replaced
    (``toggle design`` refuses them otherwise)."""
    from toggle_cli import main
    argv = command(name, search, out)
    run_cli(main, "toggle", argv + ["--force"] * (out / "pareto.csv").exists())
    targets = load_targets(EXAMPLES / f"{name}.toml")
    result = run_search(targets, out, workers=0, **search)
    if result.evaluated:
        raise SystemExit(f"the record in {out} does not replay: {result.evaluated} computed")
    return "$ toggle " + " ".join(argv), result


def _cell(unit: str, value: float) -> str:
    return f"{math.degrees(value):.2f} deg" if unit == "rad" else f"{value:.5g}"


def seed_004(records: Path, search: dict, figures: bool = True) -> str:
    line, result = run_documented("li_micro", search, records / "li_micro")
    targets = result.targets
    placements = place(targets, result.front)
    keys = targets.objectives
    out = [f"```text\n{line}\n```\n",
           f"li_micro: {len(result.evaluations)} designs, {len(result.feasible)} feasible, "
           f"{len(result.front)} in the Pareto set\n"]
    headers = [f"{k} (deg)" if OBJECTIVES[k].unit == "rad" else OBJECTIVES[k].header
               for k in keys]
    out.append("| group | " + " | ".join(headers) + " | platen_stroke (mm) | place "
               "| dominated by | least gain |")
    out.append("|---" * (len(keys) + 5) + "|")
    for p in placements:
        by = f"design-{p.dominated_by.key[:12]}" if p.dominated_by else "-"
        gain = (f"{100 * p.margin:.2f} %" if p.dominated_by else
                f"nearest design-{p.nearest.key[:12]} is {100 * p.shortfall:.2f} % short"
                if p.nearest else "-")
        m = p.reference.metrics
        out.append(f"| {p.name} | " + " | ".join(_cell(OBJECTIVES[k].unit, m[k]) for k in keys)
                   + f" | {1e3 * m['platen_stroke']:.1f} | {p.status} | {by} | {gain} |")
        if p.dominated_by:
            d = p.dominated_by.metrics
            out.append(f"| ↳ design-{p.dominated_by.key[:12]} | "
                       + " | ".join(f"{_cell(OBJECTIVES[k].unit, d[k])} "
                                    f"({100 * p.improvements[k]:+.1f} %)" for k in keys)
                       + f" | {1e3 * d['platen_stroke']:.1f} | | | |")
    if figures:
        front_figure(FIGURES / "li_micro_front.png", keys, result.feasible, result.front,
                     placements)
        named = {d.key: d for p in placements for d in (p.dominated_by, p.nearest) if d}
        parallel_figure(FIGURES / "li_micro_parallel.png", keys, list(named.values()),
                        placements)
    return "\n".join(out)


def _change(row: Row) -> str:
    if row.unit == "rad":
        return f"{math.degrees(row.design - row.reference):+.2f} deg"
    return f"{100 * row.change:+.2f} %"


def _pct(reference: dict[str, float], design: dict[str, float], key: str) -> str:
    return f"{100 * (design[key] / reference[key] - 1):+.2f} %"


def _rows(rows: list[Row], limits: bool) -> list[str]:
    out = []
    for r in rows:
        better = "higher" if r.better > 0 else "lower"
        limit = (f" | {'at least' if r.better > 0 else 'at most'} {_cell(r.unit, r.limit)}"
                 if limits else "")
        out.append(f"| {r.key} ({'deg' if r.unit == 'rad' else r.unit}) | {better}{limit} | "
                   f"{_cell(r.unit, r.reference)} | {_cell(r.unit, r.design)} | {_change(r)} "
                   f"| {r.verdict} |")
    return out


def sm55(records: Path, search: dict, design_file: Path | None = None,
         figures: bool = True) -> str:
    line, result = run_documented("sm55", search, records / "sm55")
    targets = result.targets
    (reference,) = place(targets, result.front)
    keys = targets.objectives

    def gains_of(design: object) -> list[float]:
        return list(improvements(design, reference.reference, keys).values())

    # better by more than 1 % on at least two objectives; of those, the one whose worst
    # loss is least (then the largest total gain); else the least worst loss of all
    eligible = [d for d in result.front if sum(g > 0.01 for g in gains_of(d)) >= 2]
    best = min(eligible or result.front,
               key=lambda d: (max(0.0, -min(gains_of(d))), -sum(gains_of(d))))
    evaluator = Evaluator(targets)
    stroke = targets.targets["mold_open_stroke"]
    design, ref, objectives, limits = compare(evaluator, best.variables,
                                              reference.reference.variables, stroke)
    if design_file is not None:
        write_preset(design_file, targets, design, name="sm55_design")
        write_preset(records / "sm55_reference.toml", targets, ref, name="sm55_reference")
    wins = list(dict.fromkeys(r.key for r in objectives + limits if r.verdict == "wins"))
    loses = list(dict.fromkeys(r.key for r in objectives + limits if r.verdict == "loses"))
    out = [f"```text\n{line}\n```\n",
           f"sm55: {len(result.evaluations)} designs, {len(result.feasible)} feasible, "
           f"{len(result.front)} in the Pareto set; SM-55: {reference.status}; chosen: "
           f"design-{best.key[:12]}, compared with both opened to {1e3 * stroke:.1f} mm "
           f"(x_open SM-55 {1e3 * ref.metrics['x_open']:.2f} mm, design "
           f"{1e3 * design.metrics['x_open']:.2f} mm); the design is "
           f"{'feasible' if design.feasible else 'infeasible: ' + design.reason}\n",
           "| objective | better | SM-55 | sm55_design | change | design |",
           "|---|---|---|---|---|---|", *_rows(objectives, False), "",
           "| constraint | better | limit | SM-55 | sm55_design | change | design |",
           "|---|---|---|---|---|---|---|", *_rows(limits, True), "",
           f"wins on {len(wins)}: {', '.join(wins)}; loses on {len(loses)}: "
           f"{', '.join(loses)}\n"]
    if "die_height_thrust" in ref.metrics and "die_height_thrust" in design.metrics:
        r, d = ref.metrics, design.metrics
        out.append("die-height range, the worse end: peak thrust "
                   f"{r['die_height_thrust']:.0f} N (SM-55) against "
                   f"{d['die_height_thrust']:.0f} N ({_pct(r, d, 'die_height_thrust')}), "
                   f"clamp-force sensitivity {r['die_height_sensitivity']:.0f} /m against "
                   f"{d['die_height_sensitivity']:.0f} /m "
                   f"({_pct(r, d, 'die_height_sensitivity')})\n")
    out += ["| variable | SM-55 | sm55_design |", "|---|---|---|"]
    out += [f"| {v} | {a:.5g} | {design.variables[v]:.5g} |" for v, a in ref.variables.items()]
    if figures:
        chosen = replace(reference, name="sm55_design", reference=best, dominated_by=None)
        front_figure(FIGURES / "sm55_front.png", keys, result.feasible, result.front,
                     [replace(reference, dominated_by=None), chosen])
    return "\n".join(out)


#: The planner's run on each side of the comparison (the molding cycle with it).
PLAN = ["--min-time", "--force-limit", "1e5", "--cycle", "--hold", "8", "--eject", "1.5",
        "--json"]


def plans(presets: dict[str, Path]) -> str:
    """``toggle plan`` on each preset: the minimum-time stroke's times, peak input force, the
    motor's RMS torque and energy over the stroke and over the molding cycle."""
    from toggle_cli import main
    got = {name: json.loads(run_cli(main, "toggle", ["plan", "--preset",
                                                      os.path.relpath(path, ROOT), *PLAN]))
           for name, path in presets.items()}
    quantities = [("stroke time (s)", lambda r: r["duration"]),
                  ("closing time (s)", lambda r: r["closing_time"]),
                  ("peak input force (N)", lambda r: r["peak_force"]),
                  ("stroke RMS torque (N m)", lambda r: r["duty"]["rms_torque"]),
                  ("stroke electrical energy, no regeneration (J)",
                   lambda r: r["duty"]["energy_without_regeneration"]),
                  ("peak motor torque (N m)", lambda r: r["peak_motor_torque"]),
                  ("molding cycle (s)", lambda r: r["molding_cycle"]["cycle_time"]),
                  ("cycle RMS torque (N m)", lambda r: r["molding_cycle"]["rms_torque"]),
                  ("cycle peak torque (N m)", lambda r: r["molding_cycle"]["peak_torque"]),
                  ("cycle electrical energy, no regeneration (J)",
                   lambda r: r["molding_cycle"]["energy_without_regeneration"])]
    (a, ra), (b, rb) = got.items()
    out = ["```text", *(f"$ toggle plan --preset {os.path.relpath(p, ROOT)} {' '.join(PLAN)}"
                        for p in presets.values()), "```", "",
           f"| quantity | {a} | {b} | change |", "|---|---|---|---|"]
    for label, value in quantities:
        x, y = value(ra), value(rb)
        out.append(f"| {label} | {x:.5g} | {y:.5g} | {100 * (y - x) / abs(x):+.2f} % |")
    return "\n".join(out)


#: The simulated rig's run on each side (3 forward-backward cycles, deterministic).
RIG = ["--force-limit", "1e5", "--json", "--quiet", "--force"]
#: The open position moved by these on both sides (m), and (None) rounded to 0.01 mm as
#: this document prints it (the issue's -69.950 mm): the rig drives the planner's
#: minimum-peak plan of each preset, and that problem has two families of local optima
#: with peaks 0.24 % apart whose RMS forces differ by 5 %; which one the planner's starts
#: land in changes with a micrometre of x_open. The table states what holds across them.
OFFSETS = (0.0, -1e-6, 1e-6, -10e-6, 10e-6, -100e-6, 100e-6, None)
PRINTED = 1e-5  # m, the open position's last printed digit


def shifted(path: Path, offset: float | None, folder: Path) -> Path:
    """The preset at ``path`` with its ``x_open`` moved by ``offset`` (m), or rounded to
    :data:`PRINTED` for None, written to ``folder``; the preset itself for no offset."""
    if offset == 0.0:
        return path
    lines = path.read_text().splitlines()
    at = next(i for i, line in enumerate(lines) if line.startswith("x_open = "))
    x_open = float(lines[at].split("=")[1])
    moved = round(x_open / PRINTED) * PRINTED if offset is None else x_open + offset
    lines[at] = f"x_open = {moved!r}"
    tag = "printed" if offset is None else f"{offset * 1e6:+g}um"
    out = folder / f"{path.stem}_{tag}.toml"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("\n".join(lines) + "\n")
    return out


def rig_runs(presets: dict[str, Path], records: Path) -> str:
    """``hil run`` on each preset, as placed and with x_open moved by each of
    :data:`OFFSETS`: the rig's stroke and forces (forward, opening, at the toggle; the mean
    over the cycles) as placed, their ranges over the offsets, and the change as placed and
    over every pair of offsets; it holds when its sign does over every pair. The change is
    of the magnitude, so a larger opening pull is a positive change."""
    from hil.cli.main import main
    from hil.cli.run import SUMMARY_ROWS

    got: dict[str, list[dict]] = {}
    lines = []
    for name, path in presets.items():
        got[name] = []
        for offset in OFFSETS:
            preset = shifted(path, offset, records / "hil" / "offsets")
            argv = ["run", "--preset", os.path.relpath(preset, ROOT), *RIG[:-1], "--out",
                    os.path.relpath(records / "hil" / preset.stem, ROOT), RIG[-1]]
            if offset == 0.0:
                lines.append("$ hil " + " ".join(argv))
            got[name].append(json.loads(run_cli(main, "hil", argv)))
    return rig_table(got, SUMMARY_ROWS, lines)


def rig_table(got: dict[str, list[dict]], rows: Sequence[tuple[str, str, float, str]],
              lines: Sequence[str]) -> str:
    """The table of :func:`rig_runs` from its runs (each side's, in :data:`OFFSETS`'
    order)."""
    (a, ra), (b, rb) = got.items()
    moved = ", ".join(f"{o * 1e6:+g}" for o in OFFSETS[1:] if o is not None)
    out = ["```text", *lines, f"# and each with x_open moved by {moved} um and rounded to "
           f"{PRINTED * 1e3:g} mm", "```", "",
           f"| quantity | {a} | {b} | change | {a}, x_open moved | {b}, x_open moved "
           "| change, any two | holds |", "|---|---|---|---|---|---|---|---|"]

    def change(x: float, y: float, key: str) -> float:
        return y - x if key == "stroke_error" else 100 * (abs(y) - abs(x)) / abs(x)

    def fmt(c: float, key: str, unit: str) -> str:
        return f"{c:+.4f} {unit}" if key == "stroke_error" else f"{c:+.2f} %"

    for key, label, scale, unit in rows:
        xs = [scale * r[key]["mean"] for r in ra]
        ys = [scale * r[key]["mean"] for r in rb]
        pairs = [change(x, y, key) for x in xs for y in ys]
        holds = "yes" if min(pairs) > 0 or max(pairs) < 0 else "no"
        out.append(f"| {label} ({unit}) | {xs[0]:.5g} | {ys[0]:.5g} | "
                   f"{fmt(change(xs[0], ys[0], key), key, unit)} | "
                   f"{min(xs):.5g} to {max(xs):.5g} | "
                   f"{min(ys):.5g} to {max(ys):.5g} | {fmt(min(pairs), key, unit)} to "
                   f"{fmt(max(pairs), key, unit)} | {holds} |")
    return "\n".join(out)


def linkage(preset: Path, records: Path, figure: Path) -> str:
    """The design to scale: ``toggle plot linkage`` on its preset, the PNG copied to figure."""
    from toggle_cli import main
    out = records / "linkage"
    argv = ["plot", "linkage", "--preset", os.path.relpath(preset, ROOT), "--out",
            os.path.relpath(out, ROOT), "--force"]
    run_cli(main, "toggle", argv)
    shutil.copyfile(out / f"linkage_{preset.stem}.png", figure)
    return "$ toggle " + " ".join(argv)


def shrink(path: Path) -> None:
    """A 64-colour palette PNG: a tenth of the size, for the repository."""
    from PIL import Image
    Image.open(path).convert("RGB").quantize(64).save(path, optimize=True)


if __name__ == "__main__":
    FIGURES.mkdir(parents=True, exist_ok=True)
    records = ROOT / "build" / "design"
    print(seed_004(records, SEARCHES["li_micro"]))
    print()
    print(sm55(records, SEARCHES["sm55"], EXAMPLES / "sm55_design.toml"))
    print()
    both = {"SM-55": records / "sm55_reference.toml",
            "sm55_design": EXAMPLES / "sm55_design.toml"}
    print(plans(both))
    print()
    print(rig_runs(both, records))
    print()
    print(linkage(EXAMPLES / "sm55_design.toml", records, FIGURES / "sm55_design_linkage.png"))
    for png in FIGURES.glob("*.png"):
        shrink(png)
