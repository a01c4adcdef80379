"""Input files in the user's words: a preset's unknown section or key refused by name where
it is, dimensions that cannot make the clamp refused with the reason, unreadable files as
one line without "[Errno N]" or codec names, exit status 2."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from toggle.elastics import clamp_stroke
from toggle.files import InputError, in_words, read_toml
from toggle.kinematics import AssemblyError, check_stroke
from toggle.params import ParameterError, load_preset, mechanism_from_dict, preset_table
from toggle_cli import main

LEAKS = re.compile(r"Errno|codec|Traceback|NoneType|\bstr\b|\bdict\b")


def chang(**changes: dict) -> dict:
    table = dict(preset_table("chang2021")[0])
    for key, value in changes.items():
        table[key] = value
    return table


def test_a_misspelled_section_is_refused_by_name() -> None:
    with pytest.raises(ParameterError, match=r"unknown section or key 'uper' \(did you mean "
                                             r"'upper'\?\)"):
        mechanism_from_dict(chang(uper={"r5": 0.1105}), "p.toml")


@pytest.mark.parametrize("table", ["half", "lower", "upper"])
def test_an_unknown_dimension_is_reported_in_its_own_table(table: str) -> None:
    base = chang()
    base[table] = {**base.get(table, {}), "r55": 0.1}
    with pytest.raises(ParameterError, match=rf"p.toml: \[{table}\]: unknown dimension 'r55' "
                                             r"\(did you mean 'r5'\?\)"):
        mechanism_from_dict(base, "p.toml")


def test_a_missing_dimension_says_where_to_give_it() -> None:
    half = {k: v for k, v in preset_table("chang2021")[0]["half"].items() if k != "e"}
    with pytest.raises(ParameterError, match=r"the lower half has no e \(give it in \[half\]"):
        mechanism_from_dict(chang(half=half), "p.toml")


def test_an_unknown_key_of_a_section_is_named() -> None:
    base = chang()
    base["drive"] = {**base["drive"], "leed": 5e-3}
    with pytest.raises(ParameterError, match=r"\[drive\]: unknown key 'leed' \(did you mean "
                                             r"'lead'\?\)"):
        mechanism_from_dict(base, "p.toml")


def test_a_link_5_too_short_for_the_open_position_is_refused_with_the_reason() -> None:
    """r5 = 5 mm was accepted as a clamp with a 5.38 mm stroke from x = 36.6 mm."""
    mech = load_preset("chang2021")
    short = mech.lower.replace(r5=5e-3)
    with pytest.raises(AssemblyError, match=r"cannot move from its open position \(link 3 "
                                            r"horizontal, x = -3.439 mm\).*loop of link 5"):
        check_stroke(short)
    check_stroke(mech.lower)  # the preset itself is a clamp
    bad = mech.with_error("lower", "r5", 5e-3 - mech.lower.r5)
    with pytest.raises(AssemblyError, match="not a double-toggle clamp"):
        clamp_stroke(bad)


def test_every_shipped_clamp_and_the_design_pass_the_check() -> None:
    root = Path(__file__).resolve().parents[1]
    for name in ("chang2021", "lin2003_sm55", "li_micro/1", "li_micro/5",
                 str(root / "design/examples/sm55_design.toml")):
        mech = load_preset(name)
        x_open = mech.clamp.x_open if mech.clamp else None
        for dims in (mech.lower, mech.upper):
            check_stroke(dims, x_open)


@pytest.fixture
def files(tmp_path: Path) -> dict[str, Path]:
    text = (Path(__file__).resolve().parents[1] / "toggle/presets/chang2021.toml").read_text()
    out = {"binary": tmp_path / "binary.toml", "latin1": tmp_path / "latin1.toml",
           "toml": tmp_path / "broken.toml", "short": tmp_path / "short.toml",
           "folder": tmp_path / "folder.toml", "missing": tmp_path / "missing.toml"}
    out["binary"].write_bytes(b"\xff\xfe\x00garbage")
    out["latin1"].write_bytes("# Größe\n".encode("latin-1") + text.encode())
    out["toml"].write_text("[half]\nr1 = \n")
    out["short"].write_text(text.replace("r5 = 110.000e-3", "r5 = 5e-3"))
    out["folder"].mkdir()
    return out


@pytest.mark.parametrize("kind, says", [
    ("binary", "not UTF-8 text (line 1, column 1: byte 0xff)"),
    ("latin1", "not UTF-8 text (line 1, column 5: byte 0xf6)"),
    ("toml", "not valid TOML: "),
    ("short", "not a double-toggle clamp"),
    ("missing", "no such file"),
])
def test_a_bad_preset_file_is_one_line_in_words_and_exit_2(
        kind: str, says: str, files: dict[str, Path], capsys: pytest.CaptureFixture) -> None:
    assert main(["kinematics", "--preset", str(files[kind])]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and str(files[kind]) in err and says in err
    assert not LEAKS.search(err), err


@pytest.mark.parametrize("kind", ["binary", "toml", "missing", "folder"])
def test_a_bad_force_table_is_one_line_and_exit_2(
        kind: str, files: dict[str, Path], capsys: pytest.CaptureFixture) -> None:
    assert main(["calibrate", "--table", str(files[kind])]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and str(files[kind]) in err
    assert not LEAKS.search(err), err


def test_read_toml_names_the_line(tmp_path: Path) -> None:
    path = tmp_path / "t.toml"
    path.write_text("a = 1\nb = \n")
    with pytest.raises(InputError, match=r"t.toml: not valid TOML: .*line 2"):
        read_toml(path, "targets")


def test_in_words_removes_errno_and_codec_phrases() -> None:
    assert in_words("x: [Errno 13] Permission denied: 'x'") == "x: Permission denied: 'x'"
    assert in_words("'utf-8' codec can't decode byte 0xff in position 7: invalid start byte"
                    ) == "not UTF-8 text (byte 7)"


@pytest.mark.parametrize("argv, usage", [
    (["kinematics", "--bogus"], "usage: toggle kinematics "),
    (["plot", "linkage", "--bogus", "1"], "usage: toggle plot linkage "),
])
def test_an_unknown_option_is_answered_with_the_sub_commands_usage(
        argv: list[str], usage: str, capsys: pytest.CaptureFixture) -> None:
    with pytest.raises(SystemExit) as info:
        main(argv)
    err = capsys.readouterr().err
    assert info.value.code == 2 and err.startswith(usage)
    assert err.rstrip().endswith(f"error: unrecognized arguments: {' '.join(argv[-2:])}"
                                 if argv[-1] == "1" else "error: unrecognized arguments: --bogus")


@pytest.mark.parametrize("text, says", [
    ("", "is empty; it needs preset = \"...\", objectives, [targets] and [bounds]"),
    ('preset = "lin2003_sm55"\n', "objectives must be a list of at least two names"),
    ('preset = "lin2003_sm55"\nobjectives = "close_time"\n', 'got "close_time"'),
])
def test_a_design_targets_file_says_what_is_missing_in_toml_words(
        tmp_path: Path, capsys: pytest.CaptureFixture, text: str, says: str) -> None:
    from cli_fuzz import INTERNALS
    targets = tmp_path / "targets.toml"
    targets.write_text(text)
    assert main(["design", str(targets), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert says in err and err.count("\n") == 1, err
    assert not [s for s in INTERNALS if s in err], err
