"""The slow planning answers of issue 30, before and after: wall and CPU time, same answer.

Runs each command with a baseline ``toggle`` (``--before``: the ``toggle`` script of
another checkout's venv, e.g. one of the commit before the change) and with this
checkout's, in the same run, the
compiled-code cache warm (``--warm-up``: each command once untimed first; by default on
this checkout's side, whose changed code compiles for tens of seconds at first). Prints a
table: median wall time and CPU time (the process and its children: on a shared machine
the CPU time is the steadier figure) of each side, their ratio, the exit status and the answer (peak
input force of the first / last plan; a refusal's exit status), and whether the answers
agree within 1e-4 relative. ``--hog``: with one CPU hog running throughout (a process
spinning on one core, started here and ended by its id), as issue 37 asks answers to come
within 10 s on this machine with one. The load average (1 min) is printed before and
after each command: the machine is shared, and the wall time follows it. ``--json PATH``:
the same rows (every run's wall and CPU time, the answers, the load) as JSON.

    python benchmarks/bench_planner_speed.py --before PATH [--repeat N] [--warm-up SIDE]
        [--hog] [--only TEXT] [--json PATH]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

AFTER = Path(sys.executable).with_name("toggle")
ROBUST = ["--robust", "--delta-r8", "0.25e-3", "--delta-r3", "0.2e-3", "--delta-r6", "-0.2e-3"]
#: name, arguments (``{out}``: a temporary folder, the results folder ``--out`` names)
COMMANDS = (
    ("plan (default)", ["plan", "--json"]),
    ("plan --min-time --force-limit 14.91", ["plan", "--min-time", "--force-limit", "14.91",
                                             "--json"]),
    ("plan --min-time --force-limit 14.90", ["plan", "--min-time", "--force-limit", "14.90",
                                             "--json"]),
    ("plan --trade-off 6", ["plan", "--trade-off", "6", "--json"]),
    ("plan --robust --delta-r8/r3/r6", ["plan", *ROBUST, "--json"]),
    ("plot trade-off", ["plot", "trade-off", "--out", "{out}"]),
)


def _answer(stdout: str) -> list[float]:
    """The peak forces a JSON answer gives (plan: its peak; trade-off: every point's)."""
    try:
        report = json.loads(stdout)
    except ValueError:
        return []
    if "trade_off" in report:
        return [p["peak_force"] for name in ("trade_off", "trade_off_dry_cycle")
                for p in report[name]]
    return [report["peak_force"], report["duration"]]


def run(toggle: Path, argv: list[str]) -> tuple[float, float, int, list[float]]:
    """Wall time, CPU time (s), exit status and answer of one command."""
    with tempfile.TemporaryDirectory() as tmp:
        args = [a.replace("{out}", str(Path(tmp) / "figures")) for a in argv]
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        tic = time.perf_counter()
        done = subprocess.run([str(toggle), *args], capture_output=True, text=True)
        wall = time.perf_counter() - tic
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu, done.returncode, _answer(done.stdout)


def same(a: list[float], b: list[float]) -> bool:
    return len(a) == len(b) and all(abs(x - y) <= 1e-4 * abs(y) for x, y in zip(a, b))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--before", type=Path, required=True,
                        help="the baseline toggle script, e.g. OTHER_CHECKOUT/.venv/bin/toggle")
    parser.add_argument("--repeat", type=int, default=1)
    parser.add_argument("--warm-up", choices=("none", "before", "after", "both"),
                        default="after", help="run every command of that side once untimed "
                        "first, to fill the cache (default after: this checkout's changed code)")
    parser.add_argument("--hog", action="store_true",
                        help="keep one CPU-bound process running while the commands run")
    parser.add_argument("--only", default="",
                        help="only the commands whose name contains this text")
    parser.add_argument("--json", type=Path, default=None,
                        help="also write the rows (every run, the answers, the load) here")
    args = parser.parse_args()
    hog = subprocess.Popen([sys.executable, "-c", "while True: pass"]) if args.hog else None
    try:
        return _table(args)
    finally:
        if hog is not None:
            hog.kill()
            hog.wait()


def _table(args: argparse.Namespace) -> int:
    """Each command on both sides, a row of the table each (and of ``--json``)."""
    print(f"{'command':38} {'before wall/cpu (s)':>20} {'after wall/cpu (s)':>19} "
          f"{'cpu ratio':>9}  exit  answer (peak N) before -> after  same  load")
    rows = []
    for name, argv in COMMANDS:
        if args.only not in name:
            continue
        results, load = {}, [os.getloadavg()[0]]
        for side, toggle in (("before", args.before), ("after", AFTER)):
            if args.warm_up in (side, "both"):
                run(toggle, argv)
            runs = [run(toggle, argv) for _ in range(args.repeat)]
            results[side] = (statistics.median(r[0] for r in runs),
                             statistics.median(r[1] for r in runs), runs[-1][2], runs[-1][3],
                             runs)
        load.append(os.getloadavg()[0])
        (wb, cb, eb, ab, rb), (wa, ca, ea, aa, ra) = results["before"], results["after"]
        shown = (f"{ab[0]:.5g} -> {aa[0]:.5g}" if ab and aa else "(refusal)" if eb == ea != 0
                 else "(figure)")
        agree = same(ab, aa) and eb == ea
        print(f"{name:38} {wb:9.1f} /{cb:8.1f}  {wa:9.1f} /{ca:7.1f}  {cb / ca:8.1f}x  "
              f"{eb}->{ea}  {shown:30}  {agree}  {load[0]:.1f}-{load[1]:.1f}", flush=True)
        rows.append({"command": name, "argv": argv, "same_answer": agree, "load": load,
                     **{side: {"wall": [r[0] for r in runs], "cpu": [r[1] for r in runs],
                               "exit": runs[-1][2], "answer": runs[-1][3]}
                        for side, runs in (("before", rb), ("after", ra))}})
    if args.json:
        args.json.write_text(json.dumps({"hog": args.hog, "repeat": args.repeat,
                                         "warm_up": args.warm_up, "cores": os.cpu_count(),
                                         "rows": rows}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
