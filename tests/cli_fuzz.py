"""Generated command lines from an argparse definition, and the contract every answer keeps.

:func:`invocations` walks a parser's sub-commands and options and draws command lines
with bad and edge values (0, negative, NaN, inf, huge, empty, wrong type, unwritable
paths, missing and malformed files); :func:`check_answer` runs one in-process and asserts
what a user may rely on: no traceback, exit code 0, 1 (runtime failure) or 2 (usage),
the error on one line, and no output left behind by a refused command.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path

import pytest
from hypothesis import strategies as st

NUMBERS = ["0", "-1", "1", "3", "nan", "inf", "-inf", "1e308", "-0.5e-3", "0.5e-3", "25e-3",
           "", "abc", "1e-300", "2", "0.999"]
TEXTS = ["", "chang2021", "nope", "/tmp", "li_micro/6", "lin2003_sm55", "loop://"]
#: Lengths with a unit (toggle.args.length), good and bad, besides NUMBERS.
LENGTHS = ["0.25mm", "250um", "-0.5mm", "1e-3mm", "2.5 cm", "0.25kg", "mm", "1e999mm", "nanmm"]
#: Rig ports a user gets wrong: no device, a device that is no serial port, a URL to none.
PORTS = ["/dev/null", "spy://nonexistent", "spy:///dev/null", "/nonexistent/tty", "loop://",
         "/tmp"]


def path_values(root: Path) -> list[str]:
    """Paths a user gets wrong: unwritable, under a regular file, missing, malformed, a dir."""
    regular = root / "regular.txt"
    regular.write_text("not a directory\n")
    malformed = root / "malformed.toml"
    malformed.write_text("this is = = not toml\n\x00")
    csv = root / "bad.csv"
    csv.write_text("time [s],position [m]\n0,abc\n")
    return ["/sys/toggle/x", str(regular / "sub"), str(root / "missing.csv"), str(malformed),
            str(csv), str(root), ""]


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:  # noqa: SLF001 - argparse has no public walk
        if isinstance(action, argparse._SubParsersAction):  # noqa: SLF001
            return dict(action.choices)
    return {}


def commands(parser: argparse.ArgumentParser, prefix: tuple[str, ...] = ()
             ) -> dict[tuple[str, ...], argparse.ArgumentParser]:
    """Every leaf command (its words) and its parser."""
    subs = _subparsers(parser)
    if not subs:
        return {prefix: parser}
    out = {}
    for name, sub in subs.items():
        out.update(commands(sub, (*prefix, name)))
    return out


def _values(action: argparse.Action, paths: list[str]) -> st.SearchStrategy[list[str]]:
    if action.nargs == 0:
        return st.just([])
    if action.choices is not None:
        pool = [*map(str, action.choices), "nope", ""]
    elif action.dest == "port":
        pool = [*PORTS, *paths[:2]]
    elif getattr(action.type, "__name__", "") == "length":
        pool = [*NUMBERS, *LENGTHS]
    elif action.type in (float, int) or getattr(action.type, "__name__", "") == "number":
        pool = NUMBERS
    elif action.type is Path or getattr(action.type, "__name__", "") == "path":
        pool = paths
    else:
        pool = TEXTS + paths[:3]
    if isinstance(action.nargs, int):  # mostly the right count, sometimes one short
        values = st.sampled_from([*pool, *TEXTS[:2]])
        return st.lists(values, min_size=action.nargs - 1, max_size=action.nargs).filter(bool)
    many = action.nargs in ("*", "+")
    return st.lists(st.sampled_from(pool), min_size=1, max_size=3 if many else 1)


@st.composite
def invocations(draw: st.DrawFn, parser: argparse.ArgumentParser, paths: list[str],
                extra: Callable[[tuple[str, ...]], list[str]] = lambda _words: []
                ) -> list[str]:
    """One command line: a leaf command, some of its options (and positionals) with values
    drawn from the edge pools, then ``extra(words)`` (caps that keep a run cheap)."""
    table = commands(parser)
    words = draw(st.sampled_from(sorted(table)))
    argv = list(words)
    for action in table[words]._actions:  # noqa: SLF001
        if action.help == argparse.SUPPRESS or isinstance(action, argparse._HelpAction):  # noqa: SLF001
            continue
        if not action.option_strings:  # a positional (optional when nargs allows none)
            if action.nargs not in ("*", "?") or draw(st.booleans()):
                argv += draw(_values(action, paths))
        elif action.required or draw(st.booleans()):
            argv += [action.option_strings[-1], *draw(_values(action, paths))]
    return argv + extra(words)


def cheap_commands(mp: pytest.MonkeyPatch, workdir: Path) -> None:
    """Fakes for the expensive parts of both command lines, with ``mp``: figures are not
    rendered (a few bytes written where matplotlib writes the file, through the same
    writer), FMUs not built, the default HIL job not planned (a canned profile) and no
    emulated rig served (as if Ctrl-C came once its port was printed); the current folder
    is ``workdir`` (what a command writes by default lands there)."""
    import signal

    import numpy as np
    from matplotlib.figure import Figure

    import fmu_src.build as build  # toggle build-fmu loads it when it runs
    import fmu_src.native_build as native
    import toggle.linkage as linkage
    from hil.cli import emulate as hil_emulate
    from hil.cli.interrupts import Interrupted
    from hil.emulators.rig_emulator import RigEmulator
    from hil.host import experiment
    from hil.host.samples import Trajectory
    from hil.panel import server as panel_server
    from toggle.files import atomic_path

    def fake_build(out: Path, *_args: object, **_kwargs: object) -> Path:
        path = Path(out) / "ToggleClamp.fmu"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(b"PK")
        return path

    def fake_savefig(fig: object, path: Path, **_kw: object) -> None:
        Path(path).write_bytes(b"\x89PNG")  # rendering is matplotlib's; the writing is ours

    def fake_animation(mech: object, path: Path, frames: int = 2, **_kw: object) -> Path:
        with atomic_path(Path(path)) as tmp:  # the GIF writer renders through savefig
            tmp.write_bytes(b"GIF89a")
        return Path(path)

    def stop_at_once(_stopped: object) -> None:
        raise Interrupted(signal.SIGINT)

    async def serve_at_once(_state: object, announce: Callable[[str], None]) -> None:
        announce("http://127.0.0.1:0/?token=fuzz")  # hil panel: its server ends at once


    canned = Trajectory.from_positions(np.linspace(-3.4386e-3, 51.5e-3, 50), 1e-3)
    mp.setattr(Figure, "savefig", fake_savefig)
    mp.setattr(Figure, "tight_layout", lambda fig, **_kw: None)
    mp.setattr(linkage, "animate_linkage", fake_animation)
    mp.setattr(build, "build_fmu", fake_build)
    mp.setattr(build, "build_folder", lambda: workdir / "build")  # never the checkout's
    mp.setattr(native, "build_native_fmu", fake_build)
    mp.setattr(experiment, "planned_trajectory", lambda *a, **k: canned)
    mp.setattr(RigEmulator, "serve", lambda self: None)
    mp.setattr(hil_emulate, "serve_until", stop_at_once)  # QEMU, the rehosted board
    mp.setattr(panel_server, "serve", serve_at_once)  # hil panel serves until a signal
    workdir.mkdir(parents=True, exist_ok=True)
    mp.chdir(workdir)


def _files(root: Path | None) -> set[Path]:
    return set() if root is None else {p for p in root.rglob("*") if p.is_file()}


#: Command lines per CLI fuzz in the suite (derandomized: the same ones each run);
#: CLI_FUZZ_EXAMPLES=2000 for the long run, tests/cli_fuzz_table.py for the table.
EXAMPLES = int(os.environ.get("CLI_FUZZ_EXAMPLES", "300"))

#: Phrases of Python's internals that an answer in the user's words does not contain.
INTERNALS = ("Traceback", "[Errno", "codec can't", "NoneType", "got None", "<class ",
             "object has no attribute", "unsupported operand", "takes 1 positional",
             "np.float64", "float64", "could not convert")


def run_command(main: Callable[[Sequence[str]], int], argv: Sequence[str],
                capsys: pytest.CaptureFixture) -> tuple[int, str, str]:
    """(exit code, stdout, stderr) of one in-process command (``toggle``'s or ``hil``'s
    main); never a traceback."""
    try:
        code = main(argv)
    except SystemExit as exc:
        code = exc.code
    out, err = capsys.readouterr()
    assert "Traceback" not in err
    return code, out, err


def check_answer(main: Callable[[Sequence[str]], int], argv: list[str],
                 outputs: Sequence[Path], watch: Path | None = None,
                 in_words: bool = False) -> tuple[int, str]:
    """Run ``main(argv)`` in-process; assert the CLI contract; return (exit code, stderr).

    The contract: no traceback; exit 0, 1 (runtime failure) or 2 (usage); a failure says
    so on exactly one ``error:`` line (the last); a refused command leaves ``outputs`` as
    they were and adds no file under ``watch``; no temporary file is ever left behind; no
    numerical warning (a division by zero, an invalid value: the trace of a silent NaN);
    JSON output is JSON (no NaN or Infinity); with ``in_words`` no phrase of
    :data:`INTERNALS` ("[Errno 2]", "'utf-8' codec can't decode", a Python type's name).
    """
    before = {p: p.exists() for p in outputs}
    files = _files(watch)
    err, out = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out), \
            warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", RuntimeWarning)
        try:
            code = main(argv)
        except SystemExit as exc:  # argparse's usage errors
            code = exc.code if isinstance(exc.code, int) else 1
    text = err.getvalue()
    numeric = [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)]
    assert not numeric, (argv, numeric)
    if code == 0 and "--json" in argv:
        json.loads(out.getvalue(), parse_constant=lambda c: pytest.fail(f"{argv}: JSON {c}"))
    assert "Traceback" not in text, (argv, text)
    assert code in (0, 1, 2), (argv, code, text)
    after = _files(watch)
    assert not [p for p in after if p.name.startswith(".")], (argv, after)  # no temp files
    if code:
        errors = [ln for ln in text.splitlines() if "error:" in ln]
        assert len(errors) == 1 and text.rstrip().endswith(errors[0]), (argv, text)
        assert len(errors[0]) < 400, (argv, errors[0])  # one readable line, no dumped arrays
        for leak in ("np.float64(", "array(", "HalfDims(", "Traceback",
                     *(INTERNALS if in_words else ())):
            assert leak not in errors[0], (argv, errors[0])
        for p in outputs:
            assert p.exists() == before[p], (argv, p, text)  # a refused command left nothing
        assert after <= files, (argv, after - files, text)
    return code, text
