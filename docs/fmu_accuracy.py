"""docs/fmu.md's accuracy table: every build under stock and deriving masters, every output.

``python docs/fmu_accuracy.py [--docs docs/fmu.md]`` builds the native FMUs (FMI 2.0 CS
and ME, FMI 3.0 CS) and the pythonfmu one, feeds each the docs' stroke
(:mod:`fmu_src.accuracy`) at h = 2, 1 and 0.5 ms, and prints the largest pointwise error
and the peak's error of the clamp, tie-bar and input forces, the motor torque and the
acceleration, each over its reference peak; with ``--docs`` the table between the file's
markers is replaced. About 15 s, the builds included.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np
from fmpy import extract

from fmu_src.accuracy import (
    OUTPUTS,
    errors,
    model_exchange_every_evaluation,
    reference,
    simulate,
    stock,
    with_derivatives,
)
from fmu_src.build import build_fmu
from fmu_src.native_build import build_native_fmu

STEPS = (2e-3, 1e-3, 5e-4)  # s
BEGIN = "<!-- generated: python docs/fmu_accuracy.py --docs docs/fmu.md -->"
END = "<!-- end of generated accuracy table -->"
HEAD = ("| build, master | h | clamp force | tie-bar force | input force | motor torque | "
        "acceleration |")


def _row(label: str, h: float, got: dict[str, np.ndarray], ref: dict[str, np.ndarray]) -> str:
    cells = [f"{pointwise:.1e} / {peak:.0e}" for pointwise, peak in errors(got, ref, h).values()]
    return f"| {label} | {h * 1e3:g} ms | " + " | ".join(cells) + " |"


def _largest_difference(runs: list[dict[str, np.ndarray]]) -> float:
    """The largest difference between the runs over each output's peak in the first."""
    first = runs[0]
    return max(float(np.abs(run[n] - first[n]).max() / np.abs(first[n]).max())
               for run in runs[1:] for n in OUTPUTS)


def table(folder: Path) -> str:
    """The markdown table (and the line on the builds' agreement) of this run."""
    fmi2_cs = build_native_fmu(folder / "fmi2cs", "chang2021", 2, "cs")
    fmi3_cs = build_native_fmu(folder / "fmi3cs", "chang2021", 3, "cs")
    fmi2_me = build_native_fmu(folder / "fmi2me", "chang2021", 2, "me")
    python_cs = build_fmu(folder / "pythonfmu")
    unzipped = Path(extract(str(fmi2_cs), str(folder / "u2cs")))
    unzipped_me = Path(extract(str(fmi2_me), str(folder / "u2me")))
    ref = reference()
    rows = [HEAD, "|---|---|---|---|---|---|---|"]
    spread = []
    cases = [
        ("CS, `fmpy.simulate_fmu` (no input derivatives: extrapolated)",
         lambda h: stock(fmi2_cs, h)),
        ("CS, x_cmd with velocity and acceleration", lambda h: with_derivatives(unzipped, h, 2)),
        ("CS, x_cmd with velocity only", lambda h: with_derivatives(unzipped, h, 1)),
        ("ME, `fmpy.simulate_fmu`, CVode at its defaults, input every h",
         lambda h: stock(fmi2_me, h)),
        ("ME, x_cmd(t) set at every evaluation, CVode at fmpy's defaults",
         lambda h: model_exchange_every_evaluation(unzipped_me, h)),
        ("issue 39's build: x_cmd held, no derivatives", lambda h: simulate(h, "held")),
        ("before issue 39: x_cmd read as the step's end", lambda h: simulate(h, "before")),
    ]
    for label, run in cases:
        for h in STEPS:
            got = run(h)
            rows.append(_row(label, h, got, ref))
            if label.startswith("CS, `fmpy"):
                spread.append(_largest_difference(
                    [got, stock(fmi3_cs, h), stock(python_cs, h), simulate(h, "extrapolated")]))
    note = (f"\nThe stock CS rows are the native FMI 2.0 build's; the native FMI 3.0 build, the "
            f"pythonfmu build and `toggle.plant.drive_step` in-process give the same outputs "
            f"(within {max(spread):.0e} of each output's peak). Cells: largest pointwise "
            "error / error of the peak, both over the reference's peak.")
    return "\n".join(rows) + "\n" + note


def write_docs(path: Path, text: str) -> None:
    """Replace the block between BEGIN and END in ``path``."""
    doc = path.read_text(encoding="utf-8")
    if BEGIN not in doc or END not in doc:
        raise SystemExit(f"{path}: no {BEGIN} ... {END} block")
    head, rest = doc.split(BEGIN, 1)
    path.write_text(f"{head}{BEGIN}\n{text}\n{END}{rest.split(END, 1)[1]}", encoding="utf-8")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--docs", type=Path, help="write the table into this markdown file")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="fmu_accuracy_") as folder:
        text = table(Path(folder))
    print(text)
    if args.docs:
        write_docs(args.docs, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
