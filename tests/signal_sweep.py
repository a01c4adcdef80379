"""A Ctrl-C at many moments of a ``toggle`` command, each in a process of its own.

Sending a signal after a delay hits the moments a loaded machine happens to offer; this
sweep chooses them. A first run of the command counts the Python function calls its main()
makes (outside imports, where the handlers only note a signal); each further run sends
SIGINT to itself at the K-th call, for K drawn from that count, and must end with 130 and
one line. This is how the CasADi type checks that clear a raised KeyboardInterrupt were
found (toggle/interrupts.py; tests/test_toggle_interrupts.py pins the sites it found).

    python tests/signal_sweep.py [--samples N] [--jobs J] [--seed S] -- plan --trade-off 6

Prints each K whose run ended otherwise, with the stack where the signal was sent, then
the count of exit statuses. Minutes: each sample runs the whole command.
"""

from __future__ import annotations

import argparse
import collections
import os
import random
import signal
import subprocess
import sys
import traceback
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

TOGGLE = Path(sys.executable).with_name("toggle")


def _run_here(k: int, words: list[str]) -> None:
    """The command in this process; with ``k`` > 0, SIGINT to itself at the k-th call
    outside imports; ``k`` == 0 prints the number of such calls on stderr's last line."""
    sys.argv = [str(TOGGLE), *words]
    import toggle_cli
    from toggle.interrupts import in_import

    calls = 0
    where: list[str] = []

    def tracer(frame, event, arg):  # noqa: ANN001, ANN202 - sys.settrace's signature
        nonlocal calls
        if in_import(frame):
            return None
        calls += 1
        if calls == k:
            sys.settrace(None)
            where.append("".join(traceback.format_stack(frame, limit=12)))
            os.kill(os.getpid(), signal.SIGINT)
        return None

    sys.settrace(tracer)
    code = toggle_cli.main()
    sys.settrace(None)
    sys.stderr.write("".join(where) + f"\ncalls {calls}\n")
    sys.exit(code)


def _sample(k: int, words: list[str]) -> tuple[int, int, str]:
    proc = subprocess.run([sys.executable, __file__, "--here", str(k), "--", *words],
                          capture_output=True, text=True, timeout=600,
                          preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    return k, proc.returncode, proc.stderr


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=100)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--here", type=int, default=None, help=argparse.SUPPRESS)
    parser.add_argument("words", nargs="+", help="the toggle command line")
    args = parser.parse_args()
    if args.here is not None:
        _run_here(args.here, args.words)
    _, code, err = _sample(0, args.words)
    calls = int(err.strip().splitlines()[-1].split()[1])
    rng = random.Random(args.seed)
    ks = sorted(rng.sample(range(1, calls + 1), min(args.samples, calls)))
    print(f"toggle {' '.join(args.words)}: exit {code} undisturbed, {calls} calls outside "
          f"imports; {len(ks)} samples", flush=True)
    codes: collections.Counter[int] = collections.Counter()
    with ThreadPoolExecutor(args.jobs) as pool:
        for k, code, err in pool.map(lambda k: _sample(k, args.words), ks):
            codes[code] += 1
            lines = [line for line in err.splitlines() if line.startswith("toggle")]
            if code != 130 or len(lines) != 1:
                print(f"K={k}: exit {code}, {len(lines)} lines\n{err}", flush=True)
    print(dict(codes))
    return 0 if set(codes) == {130} else 1


if __name__ == "__main__":
    sys.exit(main())
