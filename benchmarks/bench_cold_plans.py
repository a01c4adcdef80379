"""Benchmark: every ``toggle plan`` command of the README and docs/*.md, cold and warm,
beside one CPU hog (issue 45).

Cold: the command in a new process on an empty compile cache (a temporary
TOGGLE_CACHE_DIR of its own): the first answer, with the problem's functions interpreted
while a detached process compiles them. The benchmark then waits until that compile is
done (no job file left in the cache: "compile" is that wait, wall) and runs the command
again, warm: the functions loaded compiled. Wall and CPU (the command and the children it
waits for, not the detached compile) per command, the answer (peak force and duration, a
refusal's message) and whether cold and warm printed the same (the solve's time, the one
figure that differs, left out). Targets: every cold answer <= 15 s, every warm <= 5 s,
answers equal.

The commands: the lines of the fenced code blocks that run ``toggle plan`` and the first
cells of the tables in docs/planning.md, each as written without its optional ``[...]``
parts and again with them (where they name no placeholder), alternatives ``a|b`` as
their first; a command naming a placeholder (``<key>``, ``W``) or a preset file that is
not there is listed as skipped. The output files (``--out plan.csv``) go to a temporary
folder.

On a pipe (every run here has stderr on a pipe): each progress line's arrival is timed;
"gap" is the longest time without a line of stderr while the command ran (from its start
to its end), and each ETA printed is compared with the time then left (its error in % of
that). The robust plan's cold run is the issue's figure (target: gap <= 10 s, every ETA
within 30 %).

The table is written into docs/planning.md between the markers (``--no-docs``: printed
only). Figures on a shared machine are noisy: one run, beside the hog this starts (one
process spinning on one core).
Run: python benchmarks/bench_cold_plans.py [--list] [--only COMMAND ...] [--no-docs]
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import re
import resource
import shlex
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs" / "planning.md"
START, END = "<!-- bench_cold_plans: start -->", "<!-- bench_cold_plans: end -->"
TOGGLE = [sys.executable, "-m", "toggle_cli"]
PLACEHOLDER = re.compile(r"<[^>]*>|(?<=\s)[A-Z]+(?=\s|$)")
#: Files a command writes, for their placeholders (``--out T``).
OUTPUTS = {"--out": "out.csv", "--cycle-out": "cycle.csv", "--duty-plot": "duty.png"}
ETA = re.compile(r"ETA (\d+):(\d{2})")
COMPILE_WAIT = 300.0  # s, the most a detached compile is waited for (--compile-wait)


def _normalised(line: str) -> list[str]:
    """The commands a documented line stands for: without its ``[...]`` parts, and with
    them; ``a|b`` values as ``a``; ``x | y`` alternatives each."""
    line = line.split("  #")[0].strip().lstrip("$ ").strip()
    out = []
    for alternative in re.split(r"\s+\|\s+", line):
        alternative = alternative if alternative.startswith("toggle plan") else (
            "toggle plan " + alternative)
        bare = re.sub(r"\s*\[[^\]]*\]", "", alternative)
        full = re.sub(r"\[([^\]]*)\]", r"\1", alternative)
        for text in (bare, full):
            words = [w.split("|")[0] for w in shlex.split(text)]
            for k, word in enumerate(words[:-1]):
                if word in OUTPUTS and re.fullmatch(r"<[^>]*>|[A-Z]+", words[k + 1]):
                    words[k + 1] = OUTPUTS[word]
            out.append(" ".join(words))
    return out


def documented_commands() -> list[str]:
    """Every ``toggle plan`` command of README.md and docs/*.md (see the module's text),
    in order of appearance, once each (a command that differs from another only by a final
    ``--json`` is left out: the same plan)."""
    seen: dict[str, None] = {}
    for path in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        text = path.read_text(encoding="utf-8")
        if START in text:  # this benchmark's own table
            text = text[:text.index(START)] + text[text.index(END) + len(END):]
        text = re.sub(r"\\\n\s*", " ", text)  # a command continued on the next line
        fenced = False
        for line in text.splitlines():
            if line.startswith("```"):
                fenced = not fenced
                continue
            found = []
            if fenced and re.match(r"(\$ )?toggle plan\b", line.strip()):
                found = [line]
            elif path == DOCS and (m := re.match(r"\| `(toggle plan[^`]*)`", line)):
                found = [m.group(1)]
            for command in found:
                for each in _normalised(command):
                    seen.setdefault(each, None)
    # --json prints the same plan otherwise: one of the two is run
    return [c for c in seen if not (c.endswith(" --json") and c[:-7] in seen)]


def _skip(command: str) -> str | None:
    """Why a command cannot run as documented, or None."""
    if PLACEHOLDER.search(command):
        return "names a placeholder"
    words = shlex.split(command)
    if "--preset" in words:
        preset = words[words.index("--preset") + 1]
        if preset.endswith(".toml") and not (ROOT / preset).exists():
            return f"{preset} is made by another command"
    return None


def _answer_text(out: str) -> str:
    """The printed answer without the solve's time (and iterations' time in JSON)."""
    out = re.sub(r"solved in [0-9.]+ ms", "solved in - ms", out)
    try:
        data = json.loads(out)
    except ValueError:
        return out

    def strip(value: object) -> object:
        if isinstance(value, dict):
            return {k: strip(v) for k, v in value.items() if k != "solve_time"}
        if isinstance(value, list):
            return [strip(v) for v in value]
        return value
    return json.dumps(strip(data), sort_keys=True)


def _summary(code: int, out: str, err: str) -> str:
    """The answer in a few words: peak force and duration, or the refusal."""
    if code != 0:
        last = err.strip().splitlines()[-1] if err.strip() else f"exit {code}"
        return f"exit {code}: {last.split(': error: ')[-1][:70]}"
    try:
        data = json.loads(out)
        if "trade_off" in data:
            first = data["trade_off"][0]
            return f"{len(data['trade_off'])} points from {first['peak_force']:.6g} N"
        return f"{data['peak_force']:.6g} N in {data['duration']:.4g} s"
    except ValueError:
        peak = re.search(r"planned\s+([0-9.]+)", out)
        stroke = re.search(r"stroke of ([0-9.]+) s", out)
        if peak and stroke:
            return f"{peak.group(1)} N in {stroke.group(1)} s"
        rows = re.findall(r"^\s+([0-9.]+)\s+([0-9.]+)\s*$", out, re.M)
        return f"{len(rows)} points from {rows[0][0]} N" if rows else out.splitlines()[0][:70]


def _argv(command: str) -> list[str]:
    """The command's arguments, a preset file named from the checkout (as the docs run it)
    by its absolute path: each run has a scratch folder of its own."""
    words = shlex.split(command)[1:]
    for k, word in enumerate(words[:-1]):
        if word == "--preset" and words[k + 1].endswith(".toml"):
            words[k + 1] = str(ROOT / words[k + 1])
    return words


class Run:
    """One command in a new process: wall, CPU, output, and stderr's lines with their
    arrival times (s from the start)."""

    def __init__(self, command: str, cache: Path, cwd: Path) -> None:
        self.command = command
        env = dict(os.environ, TOGGLE_CACHE_DIR=str(cache), TOGGLE_COMPILE="background")
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        tic = time.monotonic()
        proc = subprocess.Popen([*TOGGLE, *_argv(command)], cwd=cwd, env=env,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self.lines: list[tuple[float, str]] = []
        reader = threading.Thread(target=self._read, args=(proc, tic))
        reader.start()
        self.out = proc.stdout.read()
        self.code = proc.wait()
        reader.join()
        self.wall = time.monotonic() - tic
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        self.cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
        self.err = "".join(line for _, line in self.lines)

    def _read(self, proc: subprocess.Popen, tic: float) -> None:
        for line in proc.stderr:
            self.lines.append((time.monotonic() - tic, line))

    def gap(self) -> float:
        """The longest time without a line of stderr while the command ran."""
        times = [0.0, *(t for t, _ in self.lines), self.wall]
        return max(b - a for a, b in itertools.pairwise(times))

    def eta_errors(self) -> list[tuple[float, float, float]]:
        """(time, ETA printed, time then left) of each line with an ETA."""
        out = []
        for t, line in self.lines:
            if m := ETA.search(line):
                out.append((t, 60 * int(m.group(1)) + int(m.group(2)), self.wall - t))
        return out


def _wait_for_compiles(cache: Path) -> float:
    """Seconds until no compile job is left in the cache (at most COMPILE_WAIT)."""
    tic = time.monotonic()
    while list(cache.glob("job-*.json")) and time.monotonic() - tic < COMPILE_WAIT:
        time.sleep(0.5)
    return time.monotonic() - tic


#: An ETA is printed in whole seconds: its error is judged against the larger of 30 % of
#: the time then left and this resolution (an "ETA 0:00" 0.4 s before the end is right).
ETA_RESOLUTION = 1.0


def _eta_cell(run: Run) -> str:
    etas = run.eta_errors()
    if not etas:
        return "none printed"
    worst = max(abs(eta - left) / max(left, 1e-9) for _, eta, left in etas)
    off = sum(abs(eta - left) > max(0.3 * left, ETA_RESOLUTION) for _, eta, left in etas)
    return f"{len(etas)}, worst {100 * worst:.0f} %, {off} beyond 30 % (or 1 s)"


def measure(commands: list[str], hog: bool = True) -> tuple[list[str], list[Run]]:
    rows, robust = [], []
    spinning = subprocess.Popen([sys.executable, "-c", "while True: pass"]) if hog else None
    try:
        with tempfile.TemporaryDirectory(prefix="bench-cold-") as tmp:
            for k, command in enumerate(commands):
                if reason := _skip(command):
                    rows.append(f"| `{command}` | skipped: {reason} | | | | | | | |")
                    continue
                cache, cwd = Path(tmp) / f"cache{k}", Path(tmp) / f"cwd{k}"
                cwd.mkdir()
                cold = Run(command, cache, cwd)
                wait = _wait_for_compiles(cache)
                answer = _summary(cold.code, cold.out, cold.err)
                if list(cache.glob("job-*.json")):  # starved: no warm run to speak of
                    warm_cell, same_cell = f"compile not done in {wait:.0f} s", "-"
                else:
                    warm_cwd = Path(tmp) / f"cwd{k}-warm"  # its own: --out files are new
                    warm_cwd.mkdir()
                    warm = Run(command, cache, warm_cwd)
                    warm_cell = f"{warm.wall:.1f} / {warm.cpu:.1f}"
                    same_cell = "yes" if _answer_text(cold.out) == _answer_text(warm.out) and (
                        cold.code == warm.code) else "NO"
                row = (f"| `{command}` | {cold.wall:.1f} / {cold.cpu:.1f} | {wait:.0f} | "
                       f"{warm_cell} | {answer} | {same_cell} | {cold.gap():.1f} | "
                       f"{_eta_cell(cold)} |")
                rows.append(row)
                print(row, flush=True)
                if "--robust" in command and cold.code == 0:  # not the refusal
                    robust.append(cold)
    finally:
        if spinning is not None:
            spinning.kill()
            spinning.wait()
    return rows, robust


def table(rows: list[str], robust: list[Run], documented: int) -> str:
    load = os.getloadavg()[0]
    lines = [f"Generated by `benchmarks/bench_cold_plans.py` ({time.strftime('%Y-%m-%d')}: "
             f"{len(rows)} of the {documented} documented commands; load average "
             f"{load:.1f} at the end, "
             f"{os.cpu_count()} cores shared with other work, beside one CPU hog the "
             "benchmark starts; one run each: noisy figures). Cold: an empty compile "
             "cache, the functions interpreted while they compile in a detached process; "
             "compile: the wait until that was done; warm: the same command again. Wall / "
             "CPU in s (CPU: the command and its planning process, not the detached "
             "compile). Gap: the longest time without a line on stderr (a pipe) in the "
             "cold run; ETAs: those printed in the cold run and the worst error against "
             "the time then left, and how many missed it by more than 30 % of that (or "
             "the ETA's 1 s resolution). Targets: cold <= 15 s, warm <= 5 s, gap <= 10 s, "
             "ETAs within 30 %.", "",
             "| command | cold wall / CPU | compile | warm wall / CPU | answer | equal | "
             "gap | ETAs |", "|---|---|---|---|---|---|---|---|", *rows]
    for run in robust:
        lines += ["", f"`{run.command}` cold on a pipe, its stderr lines (time from the "
                  "start, the line):", "", "```"]
        lines += [f"{t:6.1f} s  {line.rstrip()}" for t, line in run.lines]
        lines += [f"{run.wall:6.1f} s  (end)", "```"]
    return "\n".join(lines)


def write_docs(text: str) -> None:
    doc = DOCS.read_text(encoding="utf-8")
    section = f"{START}\n{text}\n{END}"
    if START in doc:
        doc = doc[:doc.index(START)] + section + doc[doc.index(END) + len(END):]
    else:
        doc = doc.rstrip("\n") + "\n\n## Cold and warm answers (issue 45)\n\n" + section + "\n"
    DOCS.write_text(doc, encoding="utf-8")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", action="append",
                        help="this command only (as --list prints it; repeatable)")
    parser.add_argument("--no-docs", action="store_true", help="do not rewrite docs/planning.md")
    parser.add_argument("--list", action="store_true", help="list the commands and stop")
    parser.add_argument("--no-hog", action="store_true",
                        help="without the CPU hog (a check of the benchmark itself)")
    parser.add_argument("--compile-wait", type=float, default=COMPILE_WAIT,
                        help="the most seconds a detached compile is waited for")
    args = parser.parse_args()
    globals()["COMPILE_WAIT"] = args.compile_wait
    commands = [c for c in documented_commands() if not args.only or c in args.only]
    if args.list:
        print("\n".join(f"{c}   [{_skip(c) or 'runs'}]" for c in commands))
        return
    rows, robust = measure(commands, hog=not args.no_hog)
    text = table(rows, robust, len(documented_commands()))
    print(text)
    if not args.no_docs:
        write_docs(text)


if __name__ == "__main__":
    main()
