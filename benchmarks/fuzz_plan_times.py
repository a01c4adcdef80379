"""How long ``toggle plan`` takes to answer: random realistic command lines, timed.

Issue 30 asks every ``toggle plan`` and ``toggle plot trade-off`` answer, refusals
included, within 10 s on this machine with a warm cache. This draws command lines
from the options a user combines (durations, force limits near and below the bound,
objectives and weights, robust plans against dimensional errors, friction, mold
position, protection zones, trade-offs, cycles with dwells; chang2021), runs each
with this checkout's ``toggle`` as a user would, and prints each one's wall time and
exit status, then the count over 10 s and the median. A warm-up pass (``--warm-up``)
fills the compiled-code cache for the plants drawn first.

    python benchmarks/fuzz_plan_times.py [--count N] [--seed S] [--limit 10] [--warm-up]
"""

from __future__ import annotations

import argparse
import random
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

TOGGLE = Path(sys.executable).with_name("toggle")


def draw(rng: random.Random, out: Path) -> list[str]:
    """One command line a machine builder might type."""
    kind = rng.choice(["duration", "min-time", "robust", "trade-off", "cycle", "plot",
                       "energy", "cam", "protect"])
    if kind == "plot":
        return ["plot", "trade-off", "--points", str(rng.randint(2, 8)), "--out",
                str(out / "t.png")]
    argv = ["plan", "--json"]
    if rng.random() < 0.3:
        argv += ["--mu", f"{rng.uniform(0.05, 0.2):.3f}"]
    if rng.random() < 0.3:
        argv += ["--x-contact", f"{rng.uniform(0.049, 0.0515):.5f}"]
    if kind == "duration":
        argv += ["--duration", f"{rng.uniform(1.4, 12.0):.2f}",
                 "--objective", rng.choice(["peak", "rms", "energy"])]
    elif kind == "min-time":
        argv += ["--min-time"] + (["--force-limit", f"{rng.uniform(14.5, 20.0):.3f}"]
                                  if rng.random() < 0.8 else [])
    elif kind == "robust":
        argv += ["--robust"]
        for name in rng.sample(["r8", "r3", "r6", "r1L", "r2U", "r5"], rng.randint(1, 3)):
            argv += [f"--delta-{name}", f"{rng.uniform(-0.3e-3, 0.3e-3):.6f}"]
    elif kind == "trade-off":
        argv += ["--trade-off", str(rng.randint(2, 8))]
    elif kind == "cycle":
        argv += ["--cycle", "--hold", f"{rng.uniform(0, 10):.1f}",
                 "--eject", f"{rng.uniform(0, 3):.1f}"]
    elif kind == "energy":
        argv += ["--energy-weight", f"{rng.uniform(0, 5):.2f}"]
    elif kind == "cam":
        fmt, interpolation = rng.choice(["csv", "plcopen"]), rng.choice(["linear", "cubic"])
        argv += ["--export", "cam", "--format", fmt,  # plcopen's interpolation is its own
                 *(["--interpolation", interpolation] if fmt == "csv" else []),
                 "--units", rng.choice(["si", "motor", "counts"]), "--out",
                 str(out / "cam.out")]
    elif kind == "protect":
        argv += ["--protect-distance", f"{rng.uniform(0.5e-3, 3e-3):.5f}",
                 "--protect-speed", f"{rng.uniform(2e-3, 10e-3):.4f}"]
    return argv


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=40)
    parser.add_argument("--seed", type=int, default=30)
    parser.add_argument("--limit", type=float, default=10.0, help="seconds (default 10)")
    parser.add_argument("--warm-up", action="store_true",
                        help="run every command once untimed first")
    args = parser.parse_args()
    rng = random.Random(args.seed)
    times, over = [], []
    with tempfile.TemporaryDirectory() as tmp:
        lines = [draw(rng, Path(tmp)) for _ in range(args.count)]
        for argv in lines:
            if args.warm_up:
                subprocess.run([str(TOGGLE), *argv], capture_output=True, timeout=600)
            tic = time.perf_counter()
            done = subprocess.run([str(TOGGLE), *argv], capture_output=True, text=True,
                                  timeout=600)
            wall = time.perf_counter() - tic
            times.append(wall)
            if wall > args.limit:
                over.append((wall, argv))
            last = (done.stderr.strip().splitlines() or [""])[-1][:70]
            print(f"{wall:6.2f} s  exit {done.returncode}  toggle {' '.join(argv)[:90]}"
                  f"{'  | ' + last if done.returncode else ''}", flush=True)
    print(f"\n{len(times)} command lines: median {statistics.median(times):.2f} s, "
          f"max {max(times):.2f} s, {len(over)} over {args.limit:g} s")
    for wall, argv in over:
        print(f"  {wall:.1f} s: toggle {' '.join(argv)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
