"""The fuzz of both command lines, tabulated: ``python tests/cli_fuzz_table.py [N] [SEED]``.

Generates N command lines (749 by default, as issue 40's count) against ``toggle`` and
``hil``: each a leaf command with what it needs to run, then one mistake of a kind a user
makes (an unknown option, a value that is not a number, a choice that is not offered, an
option without its value, an input file that is missing, a folder, binary, not UTF-8,
empty, truncated or in mm, an output that is a fifo, a device node, an existing file or
a folder that holds the results already), or with no mistake against a rig that does
not answer (a run that fails: exit 1). Each runs in this process with the expensive
parts faked (:func:`cli_fuzz.cheap_commands`: no figure rendered, no FMU built, no rig
served) and is judged by the convention (docs/cli.md, "Outputs and errors"): no traceback, no
message naming a Python type or errno, exit 2 for every one of these mistakes (usage or
input, told before the work; 1 for the run that fails), one ``error:`` line, nothing in
the fixture replaced.
Prints one row per kind of mistake and the lines that broke the convention;
``tests/test_cli_fuzz_table.py`` runs a few dozen of them in the suite.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import random
import signal
import stat
import sys
import tempfile
import time
from collections import Counter, defaultdict
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from cli_fuzz import INTERNALS, cheap_commands, commands  # noqa: E402

#: Phrases that name Python's internals instead of saying the problem in words.
#: A line that takes longer is stopped and counted as such, s.
TIMEOUT = 120
ROOT_DIR = Path(__file__).resolve().parent.parent

#: What each command needs to run at all (then one mistake is added).
BASE: dict[tuple[str, ...], list[str]] = {
    ("sweep",): ["--dim", "r3", "0.088", "0.100", "3", "--dim", "r4b", "0.155", "0.167", "3"],
    ("plot", "sweep"): ["--dim", "r3", "0.088", "0.100", "3", "--dim", "r4b", "0.155",
                        "0.167", "3"],
    ("design",): [str(ROOT_DIR / "design/examples/sm55.toml")],
    ("cache",): ["info"],
    ("completion",): ["bash"],
    ("rig", "status"): ["--port", "/nonexistent/tty"],
    ("rig", "clear"): ["--port", "/nonexistent/tty"],
    ("rig", "home"): ["--port", "/nonexistent/tty"],
    ("rig", "jog"): ["--port", "/nonexistent/tty", "--to", "0.001"],
    ("rig", "tare"): ["--port", "/nonexistent/tty"],
    ("rig", "span"): ["--port", "/nonexistent/tty", "--force", "50"],
    ("rig", "store"): ["--port", "/nonexistent/tty"],
    ("rig", "check"): ["--port", "/nonexistent/tty"],
    ("rsm",): ["--paper-tables"],
}
#: No mistake in the line: a rig that does not answer (nothing listens on port 9), a run
#: that fails (exit 1).
FAILURES: tuple[tuple[str, ...], ...] = (
    ("rig", "status", "--port", "socket://127.0.0.1:9"),
    ("rig", "clear", "--port", "socket://127.0.0.1:9"),
    ("rig", "home", "--port", "socket://127.0.0.1:9"),
    ("run", "--real", "--port", "socket://127.0.0.1:9", "--quiet"),
)
#: Options and positionals whose value is an input file (by argparse dest).
INPUTS = ("preset", "config", "profile", "table", "fmu", "csv", "targets", "runs")
#: Options whose value is an output (a file or the results folder).
OUTPUTS = ("out", "cycle_out", "duty_plot", "plot")
NOT_NUMBERS = ("nan", "inf", "-inf", "abc", "", "1e999", "0x10", "0.25kg", "mm")
#: Rig ports that are no serial port (each refused before the work, exit 2), by label.
BAD_PORTS = {"/dev/null": "/dev/null", "spy://nonexistent": "spy://nonexistent",
             "a folder": "{folder}", "a regular file": "{file}", "no such device":
             "/nonexistent/tty"}
#: Every file name a command writes into its results folder (a folder "holding" them).
#: Figures named after their preset (toggle_cli.common.preset_tag), by stem.
TAGGED = ("kinematics", "linkage", "sensitivity_IT7", "asymmetry_vs_it", "fig4_tiebar_force",
          "fig5_mechanical_advantage", "fig6_thrust", "fig7_thrust_max", "fig8_motor_torque",
          "study", "sweep", "asymmetry", "plan", "trade_off")
RESULT_NAMES = (
    *(f"{stem}_{tag}.png" for stem in TAGGED
      for tag in ("chang2021", "lin2003_sm55", "li_micro", "li_micro-1")),
    "linkage_chang2021.gif", "significance_dong2022.png", "ToggleClamp.fmu", "pareto.csv",
    "pareto.parquet", "all.csv",
    "front.png", "parallel.png", "meta.json", "samples.csv", "summary.json",
    "force_curves.png", "rsm.json", "rsm_stroke_error.png",
    *(f"tables_{s}.png" for s in ("stroke", "stroke_error", "force_forward_max",
                                  "force_forward_rms", "force_backward_min",
                                  "force_backward_rms", "force_toggle")),
)


def make_fixture(root: Path) -> dict[str, dict[str, str]]:
    """The files the mistakes use, by kind: input files and output targets."""
    chang = (ROOT_DIR / "toggle/presets/chang2021.toml").read_text()
    files = {
        "missing": root / "missing.toml",
        "a folder": root / "folder",
        "binary": root / "binary.png",
        "not UTF-8": root / "latin1.toml",
        "empty": root / "empty.toml",
        "truncated TOML": root / "truncated.toml",
        "unknown section": root / "section.toml",
        "truncated plan": root / "truncated_plan.csv",
        "plan in mm": root / "plan_mm.csv",
    }
    files["a folder"].mkdir()
    files["binary"].write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\xff\xfe")
    files["not UTF-8"].write_bytes("# Größe\nname = 'x'\n".encode("latin-1"))
    files["empty"].write_text("")
    files["truncated TOML"].write_text(chang[: len(chang) // 2].rsplit("=", 1)[0] + "= 0.")
    files["unknown section"].write_text(chang + "\n[uper]\nr5 = 0.05\n")
    columns = "time [s],position [m],velocity [m/s],acceleration [m/s^2],input_force [N]," \
              "platen_position [m]"
    rows = "".join(f"{t / 1e3:.3f},{-3.4e-3 + 10e-3 * t / 1e3:.6f},0.01,0,1,0\n"
                   for t in range(0, 400))
    files["truncated plan"].write_text(f"# duration = 1.0\n{columns}\n{rows}")
    files["plan in mm"].write_text(f"{columns}\n" + "".join(
        f"{t / 1e3:.3f},{-3.4 + 10 * t / 1e3:.6f},10,0,1,0\n" for t in range(0, 1001)))
    outputs = {"a fifo": root / "fifo", "a device node": root / "null_device",
               "/dev/null": Path("/dev/null"), "an existing file": root / "existing.csv",
               "a file as the folder": root / "existing.csv" / "sub",
               "a folder holding results": root / "results",
               "a folder holding fifos": root / "fifos",
               "a name of 315 characters": root / ("n" * 315)}
    os.mkfifo(outputs["a fifo"])
    try:
        os.mknod(outputs["a device node"], 0o666 | stat.S_IFCHR, os.makedev(1, 3))
    except PermissionError:  # not root: a fifo stands in
        os.mkfifo(outputs["a device node"])
    outputs["an existing file"].write_text("mine\n")
    for kind, make in (("a folder holding results", lambda p: p.write_text("mine\n")),
                       ("a folder holding fifos", os.mkfifo)):
        outputs[kind].mkdir()
        for name in RESULT_NAMES:
            make(outputs[kind] / name)
    ports = {k: v.format(folder=files["a folder"], file=outputs["an existing file"])
             for k, v in BAD_PORTS.items()}
    return {"input": {k: str(v) for k, v in files.items()},
            "output": {k: str(v) for k, v in outputs.items()}, "port": ports}


def snapshot(root: Path) -> dict[str, tuple[int, int, int]]:
    """(type and mode, size, mtime) of everything in the fixture: what must not change."""
    out = {}
    for p in [root, *root.rglob("*")]:
        st = os.lstat(p)
        out[str(p)] = (st.st_mode, st.st_size, st.st_mtime_ns)
    return out


@dataclass
class Line:
    cli: str
    argv: list[str]
    kind: str
    expected: int = 2


def _actions(parser: argparse.ArgumentParser) -> list[argparse.Action]:
    return [a for a in parser._actions  # noqa: SLF001 - argparse has no public walk
            if not isinstance(a, (argparse._HelpAction, argparse._VersionAction))  # noqa: SLF001
            and a.dest != "force"]


def _is_number(action: argparse.Action) -> bool:
    return action.type in (float, int) or getattr(action.type, "__name__", "") in (
        "number", "integer", "length")


def _put(argv: list[str], action: argparse.Action, value: str) -> list[str]:
    """``argv`` with ``action`` given ``value`` (a positional's value replaced or added)."""
    if action.option_strings:
        return [*argv, action.option_strings[-1], value]
    return [*argv[:-1], value] if argv and action.dest in ("csv", "targets") else [*argv, value]


def _mistake(rng: random.Random, kind: str, base: list[str],
             actions: list[argparse.Action], fixture: dict[str, dict[str, str]]
             ) -> tuple[list[str], str] | None:
    """``base`` with one mistake of ``kind`` and its label; None where the command has no
    option to make it with."""
    if kind == "failure":
        return None  # drawn by generate(): hil only
    if kind == "unknown":
        bogus = rng.choice(["--bogus", "--outt", "-z", "--json=3", "--preset-file"])
        return [*base, bogus], "unknown option"
    if kind == "value":
        valued = [a for a in actions if a.option_strings and a.nargs != 0]
        return ([*base, rng.choice(valued).option_strings[-1]], "an option without value"
                ) if valued else None
    pick = {"number": lambda a: _is_number(a) and a.option_strings
            and isinstance(a.nargs, (type(None), str)),
            "choice": lambda a: a.choices and a.option_strings,
            "input": lambda a: a.dest in INPUTS,
            "output": lambda a: a.dest in OUTPUTS,
            "port": lambda a: a.dest == "port"}[kind]
    chosen = [a for a in actions if pick(a)]
    if not chosen:
        return None
    action = rng.choice(chosen)
    if kind == "number":
        return _put(base, action, rng.choice(NOT_NUMBERS)), "not a number"
    if kind == "choice":
        return _put(base, action, rng.choice(["nope", "", "BASH"])), "a choice not offered"
    if kind == "port":  # hil run takes a port with --real only
        what = rng.choice(sorted(fixture["port"]))
        real = ["--real"] if base[:1] == ["run"] else []
        return [*_put(base, action, fixture["port"][what]), *real], f"port: {what}"
    # an empty --config is a valid one (every setting at its default): not a mistake
    what = rng.choice([w for w in sorted(fixture[kind])
                       if not (action.dest == "config" and w == "empty")])
    return _put(base, action, fixture[kind][what]), f"{kind}: {what}"


#: The kinds of line: the mistakes, drawn alike, and a run that fails, drawn in
#: :data:`FAILURE_SHARE` of the lines.
KINDS = ("unknown", "value", "number", "choice", "input", "output", "port", "failure")
FAILURE_SHARE = 0.05


def generate(n: int, seed: int, fixture: dict[str, dict[str, str]],
             parsers: dict[str, argparse.ArgumentParser]) -> list[Line]:
    """``n`` command lines, each with one mistake, drawn with ``seed``."""
    rng = random.Random(seed)
    table = [(cli, words, sub) for cli, parser in sorted(parsers.items())
             for words, sub in sorted(commands(parser).items())]
    lines: list[Line] = []
    while len(lines) < n:
        cli, words, parser = rng.choice(table)
        kind = "failure" if rng.random() < FAILURE_SHARE else rng.choice(KINDS[:-1])
        if kind == "failure":
            lines.append(Line("hil", list(rng.choice(FAILURES)), "run failure: no rig answers",
                              expected=1))
            continue
        base = [*words, *BASE.get(words, [])]
        if words == ("plot", "plan"):
            base.append(fixture["input"]["plan in mm"])
        made = _mistake(rng, kind, base, _actions(parser), fixture)
        if made is not None:
            lines.append(Line(cli, *made))
    return lines


class _Timeout(BaseException):
    pass


def _alarm(_signum: int, _frame: object) -> None:
    raise _Timeout


@dataclass
class Answer:
    code: int | str
    last: str
    traceback: bool
    internals: list[str] = field(default_factory=list)
    error_lines: int = 0
    seconds: float = 0.0


def run_line(main: Callable[[Sequence[str]], int], argv: list[str]) -> Answer:
    """Run one command line in this process; what a user would see of it."""
    err, out = io.StringIO(), io.StringIO()
    traceback = False
    old = signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(TIMEOUT)
    start = time.monotonic()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
            try:
                code: int | str = main(argv)
            except SystemExit as exc:
                code = exc.code if isinstance(exc.code, int) else 1
            except _Timeout:
                code = "timeout"
            except Exception:  # noqa: BLE001 - what escapes is the traceback a user would see
                import traceback as tb

                tb.print_exc()
                code, traceback = "traceback", True
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)
    text = err.getvalue()
    lines = text.strip().splitlines()
    return Answer(code, lines[-1] if lines else "", traceback or "Traceback" in text,
                  [p for p in INTERNALS if p in text],
                  sum("error:" in ln for ln in lines), time.monotonic() - start)


@dataclass
class Row:
    lines: int = 0
    codes: Counter = field(default_factory=Counter)
    tracebacks: int = 0
    internals: int = 0
    off: int = 0
    clobbered: int = 0


def fuzz(n: int = 749, seed: int = 40, root: Path | None = None,
         report: Callable[[str], None] = lambda _line: None
         ) -> tuple[dict[str, Row], list[str]]:
    """Run ``n`` generated lines; the rows by kind of mistake and the lines off the
    convention (each with its answer)."""
    from hil.cli.main import build_parser as hil_parser
    from hil.cli.main import main as hil_main
    from toggle_cli import build_parser as toggle_parser
    from toggle_cli import main as toggle_main

    root = Path(tempfile.mkdtemp(prefix="cli_fuzz_table_")) if root is None else root
    fixture = make_fixture(root)
    mains = {"toggle": toggle_main, "hil": hil_main}
    lines = generate(n, seed, fixture, {"toggle": toggle_parser(), "hil": hil_parser()})
    rows: dict[str, Row] = defaultdict(Row)
    findings: list[str] = []
    import pytest

    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("TOGGLE_CACHE_DIR", str(root / "cache"))
        cheap_commands(mp, root / "work")
        for i, line in enumerate(lines):
            before = snapshot(root / "fifos"), snapshot(root / "results"), \
                (root / "existing.csv").read_text(), stat.S_IFMT(os.stat(root / "fifo").st_mode)
            answer = run_line(mains[line.cli], line.argv)
            after = snapshot(root / "fifos"), snapshot(root / "results"), \
                (root / "existing.csv").read_text(), stat.S_IFMT(os.stat(root / "fifo").st_mode)
            row = rows[line.kind]
            row.lines += 1
            row.codes[answer.code] += 1
            row.tracebacks += answer.traceback
            row.internals += bool(answer.internals)
            clobbered = before != after or not stat.S_ISCHR(
                os.stat("/dev/null").st_mode)
            row.clobbered += clobbered
            off = (answer.code != line.expected or answer.error_lines != 1
                   or not answer.last.startswith(f"{line.cli} ") and "usage" not in answer.last
                   and "error:" not in answer.last)
            row.off += off
            if off or answer.traceback or answer.internals or clobbered:
                findings.append(f"{line.cli} {' '.join(line.argv)!s}  ->  exit {answer.code}: "
                                f"{answer.last}")
            report(f"{i + 1}/{len(lines)} {answer.seconds:.2f} s exit {answer.code} "
                   f"{line.cli} {' '.join(line.argv)}")
    return dict(rows), findings


def print_table(rows: dict[str, Row], findings: list[str], seconds: float) -> None:
    head = (f"{'mistake':34s} {'lines':>5s} {'exit 2':>6s} {'exit 1':>6s} {'exit 0':>6s} "
            f"{'other':>5s} {'traceb.':>7s} {'internals':>9s} {'off conv.':>9s} "
            f"{'clobbered':>9s}")
    print(head)
    print("-" * len(head))
    total = Row()
    for kind in sorted(rows):
        r = rows[kind]
        other = r.lines - r.codes[2] - r.codes[1] - r.codes[0]
        print(f"{kind:34s} {r.lines:5d} {r.codes[2]:6d} {r.codes[1]:6d} {r.codes[0]:6d} "
              f"{other:5d} {r.tracebacks:7d} {r.internals:9d} {r.off:9d} {r.clobbered:9d}")
        total.lines += r.lines
        total.codes.update(r.codes)
        total.tracebacks += r.tracebacks
        total.internals += r.internals
        total.off += r.off
        total.clobbered += r.clobbered
    print("-" * len(head))
    other = total.lines - total.codes[2] - total.codes[1] - total.codes[0]
    print(f"{'all':34s} {total.lines:5d} {total.codes[2]:6d} {total.codes[1]:6d} "
          f"{total.codes[0]:6d} {other:5d} {total.tracebacks:7d} {total.internals:9d} "
          f"{total.off:9d} {total.clobbered:9d}")
    print(f"\n{total.lines} command lines in {seconds:.0f} s; every mistake above should exit 2 "
          "with one error line in words, before the work; a run that fails, 1")
    for finding in findings:
        print(f"  off the convention: {finding}")


if __name__ == "__main__":
    count = int(sys.argv[1]) if len(sys.argv) > 1 else 749
    seed = int(sys.argv[2]) if len(sys.argv) > 2 else 40
    verbose = os.environ.get("CLI_FUZZ_VERBOSE")
    t0 = time.monotonic()
    result = fuzz(count, seed, report=(lambda s: print(s, file=sys.__stderr__, flush=True))
                  if verbose else (lambda _s: None))
    print_table(*result, time.monotonic() - t0)
