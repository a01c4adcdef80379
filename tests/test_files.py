"""The output convention of toggle.files: never over a device or fifo, files mode 0666
under the umask, an existing file only when allowed, refused before the work."""

from __future__ import annotations

import os
import stat
from collections.abc import Iterator
from pathlib import Path

import pytest

from toggle import files
from toggle.files import OutputError, atomic_path, check_writable
from toggle.plots import plt, save_figure
from toggle_cli import main


@pytest.fixture
def umask() -> Iterator[None]:
    old = os.umask(0o022)
    try:
        yield
    finally:
        os.umask(old)


@pytest.fixture(autouse=True)
def _policy() -> Iterator[None]:
    yield
    files.allow_overwrite(True)  # the library default


def _fifo(tmp_path: Path) -> Path:
    node = tmp_path / "fifo"
    os.mkfifo(node)
    return node


def _device(tmp_path: Path) -> Path:
    if os.geteuid() != 0:
        pytest.skip("making a device node needs root")
    node = tmp_path / "null"
    os.mknod(node, stat.S_IFCHR | 0o666, os.makedev(1, 3))
    return node


@pytest.mark.parametrize("make", [_fifo, _device], ids=["fifo", "device"])
def test_a_device_or_fifo_is_never_replaced(tmp_path: Path, make) -> None:
    node = make(tmp_path)
    kind = os.stat(node).st_mode
    with pytest.raises(OutputError, match="not a regular file"):
        check_writable(node, "--out", force=True)
    with pytest.raises(OutputError, match="not a regular file"), atomic_path(node) as tmp:
        tmp.write_text("x")
    fig, _ = plt.subplots()
    with pytest.raises(OutputError, match="not a regular file"):
        save_figure(fig, node)
    assert os.stat(node).st_mode == kind  # still the node, not a regular file
    assert [p.name for p in tmp_path.iterdir()] == [node.name]  # no temporary left


def test_a_node_put_there_during_the_write_is_not_replaced(tmp_path: Path) -> None:
    target = tmp_path / "out.csv"
    with pytest.raises(OutputError), atomic_path(target) as tmp:
        tmp.write_text("x")
        os.mkfifo(target)
    assert stat.S_ISFIFO(os.stat(target).st_mode)


@pytest.mark.parametrize("mask", [0o022, 0o027, 0o002])
def test_new_files_get_0666_under_the_umask(tmp_path: Path, umask: None, mask: int) -> None:
    os.umask(mask)
    target = tmp_path / "sub" / "a.png"
    with atomic_path(target) as tmp:
        tmp.write_bytes(b"x")
    assert stat.S_IMODE(os.stat(target).st_mode) == 0o666 & ~mask
    assert target.read_bytes() == b"x"


def test_a_replaced_file_keeps_its_own_mode(tmp_path: Path, umask: None) -> None:
    target = tmp_path / "secret.csv"
    target.write_text("old")
    target.chmod(0o600)
    with atomic_path(target) as tmp:
        tmp.write_text("new")
    assert stat.S_IMODE(os.stat(target).st_mode) == 0o600
    assert target.read_text() == "new"


def test_an_existing_file_is_refused_unless_forced(tmp_path: Path) -> None:
    target = tmp_path / "plan.csv"
    target.write_text("keep")
    check_writable(target, "--out")  # the library default: replace
    with pytest.raises(OutputError, match="exists; give --force"):
        check_writable(target, "--out", force=False)
    files.allow_overwrite(False)
    with pytest.raises(OutputError, match="--out .*plan.csv: exists"):
        check_writable(target, "--out")
    check_writable(target, "--out", force=True)
    check_writable(tmp_path / "new.csv", "--out")
    assert target.read_text() == "keep"


def test_the_command_line_refuses_an_existing_figure_before_the_work(
        tmp_path: Path, capsys: pytest.CaptureFixture, umask: None) -> None:
    argv = ["plot", "kinematics", "--out", str(tmp_path)]
    assert main(argv) == 0
    figure = tmp_path / "kinematics_chang2021.png"
    assert stat.S_IMODE(os.stat(figure).st_mode) == 0o644
    before = figure.stat().st_mtime_ns
    capsys.readouterr()
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith(f"--out {figure}: exists; give --force to replace it")
    assert figure.stat().st_mtime_ns == before
    check_writable(figure, "--out")  # the refusal was the command's, not the library's
    assert main([*argv, "--force"]) == 0


def test_an_output_folder_that_is_a_file_is_refused_before_the_work(
        tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    folder = tmp_path / "existing"
    folder.write_text("not a folder")
    assert main(["plot", "synthesize", "--out", str(folder)]) == 2
    assert "not a directory" in capsys.readouterr().err


def test_plan_refuses_an_existing_out_before_solving(tmp_path: Path, monkeypatch,
                                                     capsys: pytest.CaptureFixture) -> None:
    import controllers.planner as planner  # toggle plan loads it when it runs

    monkeypatch.setattr(planner, "planner_for", lambda *a, **k: pytest.fail("solved first"))
    existing = tmp_path / "plan.csv"
    existing.write_text("mine\n")
    assert main(["plan", "--out", str(existing)]) == 2
    assert capsys.readouterr().err.strip().endswith("exists; give --force to replace it")
    assert existing.read_text() == "mine\n"


def test_force_is_offered_only_where_outputs_are_checked() -> None:
    from toggle_cli import build_parser

    def takes_force(*words: str) -> bool:
        parser = build_parser()
        for word in words:
            parser = next(a for a in parser._actions  # noqa: SLF001
                          if hasattr(a, "choices") and isinstance(a.choices, dict)
                          ).choices[word]
        return "--force" in parser._option_string_actions  # noqa: SLF001

    for words in (("plan",), ("tables",), ("plot", "kinematics"), ("plot", "linkage"),
                  ("plot", "synthesize"), ("plot", "clamp"), ("plot", "plan"),
                  ("plot", "trade-off"), ("build-fmu",), ("design",)):
        assert takes_force(*words), words
    for words in (("kinematics",), ("cache",)):
        assert not takes_force(*words), words
