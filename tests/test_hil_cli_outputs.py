"""``hil`` under ``toggle``'s output and error convention (docs/cli.md, "Outputs and errors"):
existing results only with --force (refused before the work), never over a non-regular
file, files 0644 under the umask, one results folder named on the last line, unreadable or
invalid input files exit 2 in one line naming the file, a sub-command's own usage."""

from __future__ import annotations

import functools
import os
import stat
from pathlib import Path

import numpy as np
import pytest
from cli_fuzz import INTERNALS, run_command

from hil.cli.main import main
from hil.host import experiment
from hil.host.recording import RUN_FILES
from hil.host.rsm import RsmError, fit_rsm

#: A quick run of the simulated rig (one cycle at 40 mm/s: about 3 s).
QUICK = ["run", "--speed", "40e-3", "--cycles", "1", "--quiet"]


answer = functools.partial(run_command, main)  # (argv, capsys) -> (code, stdout, stderr)


@pytest.fixture
def umask_022():
    old = os.umask(0o022)
    yield
    os.umask(old)


@pytest.fixture
def no_planning(monkeypatch):
    """Planning the default job is the work a refusal must come before."""
    monkeypatch.setattr(experiment, "planned_trajectory",
                        lambda *a, **k: pytest.fail("planned before the refusal"))


def test_a_run_names_its_results_folder_last_and_refuses_it_again_without_force(
        tmp_path: Path, capsys, umask_022) -> None:
    out = tmp_path / "run"
    code, stdout, _ = answer([*QUICK, "--out", str(out)], capsys)
    assert code == 0
    assert stdout.rstrip().splitlines()[-1] == (
        f"results in {out}/ ({', '.join(RUN_FILES)})")
    for name in RUN_FILES:
        assert stat.S_IMODE(os.stat(out / name).st_mode) == 0o644, name
    before = {name: (out / name).stat().st_mtime_ns for name in RUN_FILES}
    code, _, err = answer([*QUICK, "--out", str(out)], capsys)
    assert code == 2
    assert err.strip() == (f"hil run: error: --out {out / 'meta.json'}: exists; give --force "
                           "to replace it")
    assert before == {name: (out / name).stat().st_mtime_ns for name in RUN_FILES}
    code, stdout, _ = answer([*QUICK, "--out", str(out), "--force"], capsys)
    assert code == 0 and stdout.rstrip().endswith(f"({', '.join(RUN_FILES)})")
    assert all((out / name).stat().st_mtime_ns > before[name] for name in RUN_FILES)


def test_a_run_off_a_terminal_writes_its_cycles_as_lines(tmp_path: Path, capsys,
                                                         monkeypatch) -> None:
    """Off a terminal the cycle count is a line (once the run has taken
    progress.SHOW_AFTER, then at least every progress.LINE_EVERY s, and the last count at
    the end), not a bar's carriage returns in a log."""
    from controllers import progress
    monkeypatch.setattr(progress, "SHOW_AFTER", 0.0)
    loud = [arg for arg in QUICK if arg != "--quiet"]
    code, _, err = answer([*loud, "--out", str(tmp_path / "run")], capsys)
    lines = [ln for ln in err.splitlines() if ln.startswith("hil run (")]
    assert code == 0 and "\r" not in err
    assert 1 <= len(lines) <= 2 and " 1/" in lines[-1], err


def test_json_keeps_stdout_json_and_names_the_folder_on_stderr(tmp_path: Path, capsys) -> None:
    import json

    out = tmp_path / "run"
    code, stdout, err = answer([*QUICK, "--json", "--out", str(out)], capsys)
    assert code == 0 and json.loads(stdout)["run_dir"] == str(out)
    assert err.rstrip().splitlines()[-1].startswith(f"results in {out}/ (")


def test_an_existing_run_is_refused_before_planning(tmp_path: Path, capsys,
                                                    no_planning) -> None:
    out = tmp_path / "run"
    out.mkdir()
    (out / "samples.csv").write_text("mine\n")
    code, _, err = answer(["run", "--out", str(out)], capsys)
    assert code == 2 and "samples.csv: exists; give --force" in err
    assert (out / "samples.csv").read_text() == "mine\n"


@pytest.mark.parametrize("make", [os.mkfifo, lambda p: os.mkdir(p)])
def test_a_run_file_that_is_not_a_regular_file_is_refused(tmp_path: Path, capsys, make,
                                                          no_planning) -> None:
    out = tmp_path / "run"
    out.mkdir()
    make(out / "meta.json")
    code, _, err = answer(["run", "--out", str(out), "--force"], capsys)
    assert code == 2 and f"--out {out / 'meta.json'}: is a" in err


def _write_profile(path: Path, header_duration: float, rows_until: float) -> Path:
    t = np.arange(0.0, rows_until + 1e-9, 1e-3)
    x = np.linspace(-3.4e-3, -3.4e-3 + 10e-3 * rows_until, t.size)  # 10 mm/s
    path.write_text(f"# duration = {header_duration}\ntime [s],position [m]\n" + "".join(
        f"{ti:.6f},{xi:.9f}\n" for ti, xi in zip(t, x)))
    return path


@pytest.mark.parametrize("content, says", [
    (None, "no such file"),
    (b"\xff\xfe\x00binary", "not UTF-8 text"),
    (b"time [s],position [m]\n0,0.0\n", "need >= 2 rows"),
    (b"time [s],speed [m/s]\n0,0\n1,0\n", "lacks the column(s) position [m]; its header is: "
                                          "time [s], speed [m/s]"),
    (b"# duration = 1\ntime [s],position [m]\n0,0\n0.001,abc\n", "line 4: expected 2 numbers"),
    (b"time [s],position [m]\n0,-3.4\n0.001,-3.4\n", "soft travel limits"),  # in mm
])
def test_a_bad_profile_is_exit_2_naming_the_file(tmp_path: Path, capsys, content, says) -> None:
    profile = tmp_path / "p.csv"
    if content is not None:
        profile.write_bytes(content)
    out = tmp_path / "run"
    code, _, err = answer(["run", "--profile", str(profile), "--out", str(out)], capsys)
    lines = err.strip().splitlines()
    assert code == 2 and lines[-1].startswith(f"hil run: error: --profile {profile}: "), err
    assert says in lines[-1] and not [s for s in INTERNALS if s in err], err
    assert not out.exists()


def test_a_truncated_plan_is_refused(tmp_path: Path, capsys) -> None:
    whole = _write_profile(tmp_path / "whole.csv", 0.5, 0.5)
    cut = _write_profile(tmp_path / "cut.csv", 0.5, 0.3)
    out = tmp_path / "run"
    code, _, err = answer(["run", "--profile", str(cut), "--cycles", "1", "--out", str(out)],
                          capsys)
    assert code == 2 and "truncated" in err and "duration = 0.5 s" in err
    assert not out.exists()
    # the same file whole is accepted (it completes no cycle here: that is a run's answer)
    code, _, err = answer(["run", "--profile", str(whole), "--cycles", "1", "--quiet",
                           "--out", str(out)], capsys)
    assert "truncated: its samples end" not in err and code in (0, 1)


@pytest.mark.parametrize("content, says", [
    (None, "no such file"),
    (b"\xff\xfe", "not UTF-8 text"),
    (b"cycles = = 3\n", "not valid TOML"),
    (b'cycles = "3"\n', "cycles = '3' must be a whole number"),
])
def test_a_bad_config_is_exit_2_naming_the_file(tmp_path: Path, capsys, content, says) -> None:
    config = tmp_path / "rig.toml"
    if content is not None:
        config.write_bytes(content)
    code, _, err = answer(["run", "--config", str(config)], capsys)
    assert code == 2 and err.count("\n") == 1
    assert err.startswith(f"hil run: error: --config {config}: ") and says in err


@pytest.mark.parametrize("content, says", [
    (None, "no such file"),
    (b"\x89PNG\r\n", "not UTF-8 text"),
    (b"{\"meta\": ", "not JSON"),
    (b"[1, 2]", "not a hil run's summary.json"),
    (b'{"meta": {"speed": null, "delta_r8": 0}}', "meta.speed must be a number"),
])
def test_a_bad_rsm_input_is_exit_2_naming_the_file(tmp_path: Path, capsys, content,
                                                   says) -> None:
    summary = tmp_path / "summary.json"
    if content is not None:
        summary.write_bytes(content)
    code, _, err = answer(["rsm", str(summary)], capsys)
    assert code == 2 and err.count("\n") == 1
    assert err.startswith(f"hil rsm: error: run summary {summary}: ") and says in err
    assert "NoneType" not in err


def test_too_few_runs_for_the_rsm_are_listed_in_mm_not_as_numpy_numbers() -> None:
    runs = [{"meta": {"speed": v, "delta_r8": 0.0}, "F_F": {"mean": 1.0}} for v in (0.01, 0.02)]
    with pytest.raises(RsmError) as info:
        fit_rsm(runs)
    assert str(info.value).endswith("2 point(s): 10 mm/s at 0 mm, 20 mm/s at 0 mm")
    assert not [s for s in INTERNALS if s in str(info.value)]


def test_rsm_writes_one_results_folder_and_refuses_it_again(tmp_path: Path, capsys,
                                                            umask_022) -> None:
    out = tmp_path / "rsm"
    code, stdout, _ = answer(["rsm", "--paper-tables", "--out", str(out)], capsys)
    last = stdout.rstrip().splitlines()[-1]
    assert code == 0 and last.startswith(f"results in {out}/ (rsm.json, rsm_")
    assert all(stat.S_IMODE(p.stat().st_mode) == 0o644 for p in out.iterdir())
    assert sorted(p.name for p in out.iterdir()) == sorted(last[last.index("(") + 1:-1]
                                                           .split(", "))
    code, _, err = answer(["rsm", "--paper-tables", "--out", str(out)], capsys)
    assert code == 2 and err.strip().endswith("rsm.json: exists; give --force to replace it")
    assert answer(["rsm", "--paper-tables", "--out", str(out), "--force"], capsys)[0] == 0


@pytest.mark.parametrize("argv, usage", [
    (["run", "--bogus"], "usage: hil run "),
    (["rig", "status", "--port", "loop://", "--bogus"], "usage: hil rig status "),
    (["rsm", "--paper-tables", "--bogus"], "usage: hil rsm "),
])
def test_an_unknown_option_shows_the_sub_commands_usage(argv, usage, capsys) -> None:
    code, _, err = answer(argv, capsys)
    assert code == 2 and err.startswith(usage)
    assert err.rstrip().endswith("error: unrecognized arguments: --bogus")


def test_hil_run_says_when_it_builds_the_fmu(tmp_path: Path, monkeypatch) -> None:
    import fmu_src.build as build
    from hil.host.backends import ensure_fmu

    def fake_build(folder: Path, preset: str = "chang2021") -> Path:
        (folder / "ToggleClamp.fmu").write_bytes(b"PK")
        return folder / "ToggleClamp.fmu"

    monkeypatch.setattr(build, "build_fmu", fake_build)
    said: list[str] = []
    target = tmp_path / "ToggleClamp.fmu"
    assert ensure_fmu(target, notify=said.append) == target
    assert said == [f"building the FMU {target} of chang2021 (missing)",
                    f"built the FMU {target}"]
    said.clear()
    ensure_fmu(target, notify=said.append)  # new enough: nothing built, nothing said
    assert said == []


@pytest.mark.parametrize("content, says", [
    (None, "no such file"),
    (b"\x89PNG\r\n", "not an FMU"),
    (b"", "not an FMU"),
])
def test_a_bad_fmu_is_exit_2_before_the_work(tmp_path: Path, capsys, content, says,
                                             no_planning) -> None:
    fmu = tmp_path / "rig.fmu"
    if content is not None:
        fmu.write_bytes(content)
    code, _, err = answer(["run", "--fmu", str(fmu)], capsys)
    assert code == 2 and err.strip() == f"hil run: error: --fmu {fmu}: {says}" + (
        "" if content is None else " (a zip archive with modelDescription.xml); build one "
                                   "with toggle build-fmu")
