"""What the repository holds: no file records the absolute paths of the machine that wrote it
(a checkout, a home folder, a temporary folder), so the project reads the same anywhere."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
#: An absolute path under /work, /home or /tmp (split so this file does not match itself).
MACHINE_PATH = re.compile(r"(?<![\w.~])/(?:wo" r"rk|ho" r"me|tm" r"p)/")


def tracked_text_files() -> list[Path]:
    names = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True,
                           check=True).stdout.decode().split("\0")
    files = []
    for name in filter(None, names):
        path = ROOT / name
        if path.is_file() and b"\0" not in path.read_bytes()[:4096]:
            files.append(path)
    return files


def test_no_tracked_file_records_a_machine_path() -> None:
    found = [f"{path.relative_to(ROOT)}:{number}: {line.strip()}"
             for path in tracked_text_files()
             for number, line in enumerate(path.read_text(errors="replace").splitlines(), 1)
             if MACHINE_PATH.search(line)]
    assert found == []


def test_the_scan_finds_a_machine_path() -> None:
    assert MACHINE_PATH.search('default=Path("/wo' 'rk/main/.venv/bin/toggle")')
    assert MACHINE_PATH.search("load with --preset /t" "mp/x/design.toml")
    assert not MACHINE_PATH.search("build/firmware/board-nucleo/rig.elf")
    assert not MACHINE_PATH.search("see docs/work/notes and ~/.cache/toggle-clamp")


#: The developers' guide: "no file over 600 lines" (issue 47), code, tests and pages alike;
#: a long file is split by what its parts do.
MAX_LINES = 600


def test_no_tracked_file_is_over_600_lines() -> None:
    long = {str(path.relative_to(ROOT)): n for path in tracked_text_files()
            if (n := len(path.read_text(errors="replace").splitlines())) > MAX_LINES}
    assert not long, long
