"""The compiled-code cache stays bounded and visible: killed compiles' scratch removed on
the next compile, a size cap (least recently used first), ``toggle cache`` shows and
clears it. Every test has its own TOGGLE_CACHE_DIR."""

from __future__ import annotations

import fcntl
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from toggle import c_library
from toggle_cli import main


@pytest.fixture
def cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    folder = tmp_path / "cache"
    monkeypatch.setenv("TOGGLE_CACHE_DIR", str(folder))
    monkeypatch.delenv("TOGGLE_CACHE_MAX_MB", raising=False)
    folder.mkdir()
    return folder


def _dead_pid() -> int:
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    return child.pid


def _library(cache: Path, name: str, index: int, size: int, age: float) -> Path:
    path = cache / f"{name}_{index:024x}_00000000.so"
    path.write_bytes(b"\0" * size)
    stamp = time.time() - age
    os.utime(path, (stamp, stamp))
    return path


def _scratch(cache: Path, pid: int) -> Path:
    folder = cache / f"{c_library._scratch_prefix(pid)}abc"  # noqa: SLF001
    folder.mkdir()
    (folder / "unit0.o").write_bytes(b"\0" * 1000)
    return folder


def test_a_killed_compiles_scratch_goes_and_a_running_ones_stays(cache: Path) -> None:
    dead, alive = _scratch(cache, _dead_pid()), _scratch(cache, os.getpid())
    old = cache / "tmp_legacy"
    old.mkdir()
    stamp = time.time() - 3600
    os.utime(old, (stamp, stamp))
    assert c_library.cache_report().stale_scratch == (2, 1000)
    assert c_library.remove_stale_scratch() == 1000
    assert not dead.exists() and not old.exists() and alive.exists()


@pytest.mark.skipif(shutil.which(os.environ.get("CC", "gcc")) is None, reason="no C compiler")
def test_the_next_compile_removes_a_killed_compiles_scratch(cache: Path) -> None:
    dead = _scratch(cache, _dead_pid())

    def sources(tmp: Path) -> list:
        source = tmp / "unit0.c"
        source.write_text("int answer(void) { return 42; }\n")
        return [((), source)]

    library = c_library.shared_library("probe", "key", sources, lambda p: p)
    assert library is not None and library.parent == cache and library.exists()
    assert not dead.exists()
    # no scratch of its own left; the lock file stays
    assert sorted(p.name for p in cache.iterdir()) == sorted([library.name, c_library.LOCK])


def test_the_cache_is_capped_least_recently_used_first(cache: Path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("TOGGLE_CACHE_MAX_MB", "0.25")  # 250 000 bytes
    old = [_library(cache, "stroke", i, 100_000, age=100 - i) for i in range(4)]
    other = _library(cache, "mc_kernel", 9, 50_000, age=1000)  # the oldest of all
    just_made = _library(cache, "stroke", 99, 100_000, age=500)  # old time, but just loaded
    c_library._prune("stroke", just_made)  # noqa: SLF001
    left = sorted(p.name for p in cache.glob("*.so"))
    assert left == sorted(p.name for p in (old[3], just_made))
    assert not other.exists()
    assert c_library.cache_report().total <= 250_000


def test_only_keep_libraries_of_a_name_are_kept(cache: Path) -> None:
    made = [_library(cache, "stroke", i, 10, age=1000 - i) for i in range(c_library.KEEP + 3)]
    c_library._prune("stroke")  # noqa: SLF001
    assert sorted(cache.glob("*.so")) == sorted(made[3:])


def test_toggle_cache_shows_and_clears(cache: Path, capsys: pytest.CaptureFixture) -> None:
    _library(cache, "stroke", 1, 2_000_000, age=0)
    _library(cache, "mc_kernel", 2, 500_000, age=0)
    _scratch(cache, _dead_pid())
    assert main(["cache", "--json"]) == 0
    shown = json.loads(capsys.readouterr().out)
    assert shown["folder"] == str(cache) and shown["total_bytes"] == 2_501_000
    assert shown["libraries"]["stroke"] == {"count": 1, "bytes": 2_000_000}
    assert shown["stale_scratch"] == {"count": 1, "bytes": 1000}
    assert main(["cache"]) == 0
    assert f"{cache}: 2.5 MB of at most 200 MB" in capsys.readouterr().out
    assert main(["cache", "clear"]) == 0
    assert "removed 2 libraries" in capsys.readouterr().out
    assert list(cache.iterdir()) == []


def test_toggle_version_loads_no_command() -> None:
    """``toggle --version`` answers without numpy, CasADi or the commands (benchmarks/
    bench_startup.py times it: under 0.3 s where loading them took seconds)."""
    probe = ("import sys, toggle_cli; code = toggle_cli.main(['--version']); "
             "print(code, sorted(m for m in ('numpy', 'casadi', 'scipy', 'toggle.kinematics', "
             "'toggle_cli.plan', 'importlib.metadata') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                         check=True).stdout.split("\n")
    from toggle import __version__
    assert out[0] == f"toggle {__version__}"
    assert out[1] == "0 []"


@pytest.mark.skipif(shutil.which(os.environ.get("CC", "gcc")) is None, reason="no C compiler")
def test_a_compile_holds_the_caches_lock_and_looks_again_once_it_has_it(cache: Path) -> None:
    held = []

    def sources(tmp: Path) -> list:
        with open(cache / c_library.LOCK) as other:  # another process's try, in effect
            try:
                fcntl.flock(other, fcntl.LOCK_EX | fcntl.LOCK_NB)
                held.append(False)
            except BlockingIOError:
                held.append(True)
        source = tmp / "unit0.c"
        source.write_text("int answer(void) { return 42; }\n")
        return [((), source)]

    first = c_library.shared_library("probe", "locked", sources, lambda p: p)
    assert held == [True] and first is not None
    # the same library asked for again: found (as after another process's compile), not
    # compiled
    again = c_library.shared_library("probe", "locked", lambda tmp: pytest.fail("compiled"),
                                     lambda p: p)
    assert again == first


def test_clearing_removes_a_killed_compiles_job_but_not_a_running_ones(cache: Path) -> None:
    cache.mkdir(exist_ok=True)
    left, running = cache / f"{c_library.JOB_PREFIX}a.json", cache / f"{c_library.JOB_PREFIX}b.json"
    left.write_text("{}")
    running.write_text("{}")
    with open(running) as held:
        fcntl.flock(held, fcntl.LOCK_EX)
        assert c_library.clear_cache() == (1, 2)
    assert not left.exists() and running.exists()
