"""Files the project writes: refused before the work when they cannot be written, and
written atomically (a temporary file renamed onto the target), so a failure leaves no
half-written file. Every floor that writes files (figures, tables, runs, designs) uses these.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path


def check_writable(target: Path, option: str) -> None:
    """Refuse an output file that cannot be written, before any work is done (a file is
    created and removed in the nearest existing folder)."""
    if target.is_dir():
        raise OSError(f"{option} {target}: is a directory, not a file")
    _check_folder(target.parent, option, target)


def check_writable_dir(target: Path, option: str) -> None:
    """Refuse an output folder that cannot be created or written into."""
    if target.exists() and not target.is_dir():
        raise OSError(f"{option} {target}: not a directory")
    _check_folder(target, option, target)


def _check_folder(folder: Path, option: str, target: Path) -> None:
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    if not folder.is_dir():
        raise OSError(f"{option} {target}: {folder} is not a directory")
    try:
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as exc:
        raise OSError(f"{option} {target}: cannot write in {folder} ({exc.strerror})") from exc


@contextlib.contextmanager
def atomic_path(target: Path) -> Iterator[Path]:
    """A temporary path next to ``target``, renamed onto it only when the block succeeds:
    a failed write leaves no half-written file."""
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.",
                                   suffix=target.suffix)
    except OSError as exc:
        raise OSError(f"{target}: cannot write there ({exc.strerror})") from exc
    os.close(fd)
    try:
        yield Path(tmp)
        os.replace(tmp, target)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
