"""Files the project writes: refused before the work when they cannot be written, and
written atomically (a temporary file renamed onto the target), so a failure leaves no
half-written file. Every floor that writes files (figures, tables, runs, designs) uses these.

The convention, stated once here:

* never over what is not a regular file: a device node, a fifo or a socket at the target is
  refused (an atomic rename over ``/dev/null`` would replace the device);
* files come out mode 0666 under the user's umask (0644 for the usual 022), as ``open``
  makes them, not mkstemp's 0600; a file replaced keeps its own mode;
* an existing file is replaced only when allowed: :func:`check_writable`, the check before
  the work, refuses it unless ``force`` (or, by default, the process's policy, which the
  command line sets from ``--force`` with :func:`allow_overwrite`; library callers keep the
  default, replace).

Refusals are :class:`OutputError`, both an OSError and a ValueError: the command lines
answer it as a usage error (exit 2) in one line naming the option and the path.

Input files are read by :func:`read_text` and :func:`read_toml`: a file that is missing,
unreadable, not UTF-8 text or not TOML is an :class:`InputError` (a ValueError: exit 2)
whose one line names the file and says what is wrong in words, not "[Errno 2]" or
"'utf-8' codec can't decode"; :func:`in_words` rewrites such phrases in any message.
"""

from __future__ import annotations

import contextlib
import os
import re
import stat
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

_POLICY = {"overwrite": True}
#: Every file :func:`atomic_path` completed since :func:`take_written` last emptied it:
#: what a command wrote, for its last line (:func:`results_line`).
_WRITTEN: list[Path] = []


class OutputError(OSError, ValueError):
    """An output path that must not or cannot be written (the message names it)."""


class InputError(ValueError):
    """An input file that cannot be read or is not what it should be (the message names it)."""


def read_text(path: str | Path, what: str = "file") -> str:
    """The UTF-8 text of an input file; :class:`InputError` in words when it cannot be."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise InputError(f"{what} {path}: no such file") from None
    except IsADirectoryError:
        raise InputError(f"{what} {path}: is a folder, not a file") from None
    except PermissionError:
        raise InputError(f"{what} {path}: not readable (permission denied)") from None
    except OSError as exc:
        raise InputError(f"{what} {path}: cannot be read ({_reason(exc)})") from None
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        column = exc.start - raw.rfind(b"\n", 0, exc.start)
        raise InputError(f"{what} {path}: not UTF-8 text (line {line}, column {column}: byte "
                         f"0x{raw[exc.start]:02x}); save it as UTF-8") from None


def read_toml(path: str | Path, what: str = "file") -> dict[str, Any]:
    """An input TOML file's table; :class:`InputError` naming the file and the line."""
    text = read_text(path, what)
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{what} {path}: not valid TOML: {exc}") from None


_ERRNO = re.compile(r"\[Errno -?\d+\]\s*")
_CODEC = re.compile(r"'[\w-]+' codec can't decode byte (0x[0-9a-f]+) in position (\d+)"
                    r"(: [\w ]+)?")


def in_words(text: str) -> str:
    """A message with Python's internals in words: no "[Errno N]", and "'utf-8' codec
    can't decode byte 0xff in position 3: ..." as "not UTF-8 text (byte 3)"."""
    text = _ERRNO.sub("", text)
    return _CODEC.sub(lambda m: f"not UTF-8 text (byte {m.group(2)})", text)


def one_line(exc: BaseException) -> str:
    """The message of ``exc`` on one line, in words (an OSError with its file name and its
    reason, no "[Errno N]": :func:`in_words`): what both command lines print after
    ``error:``."""
    if isinstance(exc, OSError) and exc.filename is not None:
        text = f"{exc.filename}: {(exc.strerror or str(exc)).lower()}"
    else:
        text = str(exc) or "failed"
    return " ".join(in_words(text).split())


#: A results line names a sub-folder instead of its files when it holds more than this.
CROWDED = 3


def take_written() -> list[Path]:
    """The files written through :func:`atomic_path` since the last call (emptied)."""
    written = list(dict.fromkeys(_WRITTEN))
    _WRITTEN.clear()
    return written


def note_written(path: Path) -> None:
    """Count a file written by other means than :func:`atomic_path` (a builder's own
    rename, such as the FMU's) among what the command wrote, for its results line."""
    _WRITTEN.append(Path(path))


def results_line(files: list[Path]) -> str:
    """``results in DIR/ (a.png, b.csv, presets/)``: the one folder that holds ``files``
    and what is in it, by the path from there (several files of one sub-folder as the
    sub-folder, once, when it holds more than :data:`CROWDED`)."""
    if len({p.is_absolute() for p in files}) > 1:
        files = [p.absolute() for p in files]
    folder = Path(os.path.commonpath([str(p.parent) for p in files]))
    relative = [p.relative_to(folder) for p in files]
    crowded = {r.parts[0] for r in relative if len(r.parts) > 1
               and sum(q.parts[0] == r.parts[0] for q in relative) > CROWDED}
    names = list(dict.fromkeys(f"{r.parts[0]}/" if r.parts[0] in crowded else str(r)
                               for r in relative))
    return f"results in {str(folder).rstrip('/')}/ ({', '.join(names)})"


def print_results(files: list[Path], *, to_stderr: bool = False) -> None:
    """The last line of a command that wrote files (:func:`results_line`): on stdout, or on
    stderr where stdout carries ``--json``."""
    if files:
        sys.stdout.flush()
        print(results_line(files), file=sys.stderr if to_stderr else sys.stdout, flush=True)


def allow_overwrite(allowed: bool) -> None:
    """Whether :func:`check_writable` lets an existing file be replaced when its caller does
    not say (the command line's ``--force``)."""
    _POLICY["overwrite"] = bool(allowed)


def check_writable(target: Path, option: str, force: bool | None = None) -> None:
    """Refuse an output file that cannot or must not be written, before any work is done:
    a folder, a device or fifo, an existing file without ``force`` (None: the policy of
    :func:`allow_overwrite`), a folder where nothing can be created (a file is created and
    removed in the nearest existing one)."""
    check_name_lengths(target, option)
    kind = _existing_kind(target)
    if kind == "directory":
        raise OutputError(f"{option} {target}: is a directory, not a file")
    if kind is not None:
        raise OutputError(f"{option} {target}: is {kind}, not a regular file; "
                          "give the path of a file")
    allowed = _POLICY["overwrite"] if force is None else force
    if os.path.lexists(target) and not allowed:
        raise OutputError(f"{option} {target}: exists; give --force to replace it")
    _check_folder(target.parent, option, target)


def check_name_lengths(target: Path, option: str) -> None:
    """Refuse a path with a name longer than the file system takes (``NAME_MAX``, 255 bytes
    on Linux) or longer than a path may be (``PATH_MAX``), in words, before the work."""
    name_max, path_max = 255, 4096
    with contextlib.suppress(OSError, ValueError, AttributeError):
        folder = next((p for p in (target, *target.parents) if p.exists()), Path("."))
        name_max = os.pathconf(folder, "PC_NAME_MAX")
        path_max = os.pathconf(folder, "PC_PATH_MAX")
    for part in target.parts:
        if len(os.fsencode(part)) > name_max:
            raise OutputError(f"{option} {_short(part)}: a name of {len(part)} characters; "
                              f"the file system takes at most {name_max}")
    if len(os.fsencode(str(target.absolute()))) >= path_max:
        raise OutputError(f"{option} {_short(str(target))}: a path of {len(str(target))} "
                          f"characters; the file system takes at most {path_max - 1}")


def _short(text: str, keep: int = 40) -> str:
    """``text`` cut to its first ``keep`` characters and an ellipsis (a name of hundreds of
    characters is named, not printed)."""
    return text if len(text) <= keep else f"{text[:keep]}..."


def check_writable_dir(target: Path, option: str) -> None:
    """Refuse an output folder that cannot be created or written into."""
    check_name_lengths(target, option)
    if target.exists() and not target.is_dir():
        raise OutputError(f"{option} {target}: not a directory")
    _check_folder(target, option, target)


def _existing_kind(target: Path) -> str | None:
    """What is at ``target`` when it is not a regular file (links followed): "directory",
    "a character device", ...; None for a regular file or nothing."""
    try:
        mode = os.stat(target).st_mode
    except OSError:  # nothing there (or a dangling link: the rename replaces the link)
        return None
    if stat.S_ISREG(mode):
        return None
    for test, name in ((stat.S_ISDIR, "directory"), (stat.S_ISCHR, "a character device"),
                       (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a fifo"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file"


def _check_folder(folder: Path, option: str, target: Path) -> None:
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    if not folder.is_dir():
        raise OutputError(f"{option} {target}: {folder} is not a directory")
    try:
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as exc:
        raise OutputError(f"{option} {target}: cannot write in {folder} "
                          f"({_reason(exc)})") from exc


def _reason(exc: OSError) -> str:
    """An OSError's reason in words, without its errno number."""
    return exc.strerror.lower() if exc.strerror else str(exc)


def _umask() -> int:
    """The process's umask (read without changing it where Linux shows it)."""
    with contextlib.suppress(OSError, ValueError):
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _file_mode(target: Path) -> int:
    """The mode a new ``target`` gets: an existing file's own, else 0666 under the umask."""
    try:
        st = os.stat(target)
    except OSError:
        return 0o666 & ~_umask()
    return stat.S_IMODE(st.st_mode) if stat.S_ISREG(st.st_mode) else 0o666 & ~_umask()


def _refuse_special(target: Path) -> None:
    kind = _existing_kind(target)
    if kind is not None:
        raise OutputError(f"{target}: is {kind}, not a regular file; not replaced")


@contextlib.contextmanager
def atomic_path(target: Path) -> Iterator[Path]:
    """A temporary path next to ``target``, renamed onto it only when the block succeeds:
    a failed write leaves no half-written file. Never over a device, fifo or folder; the
    file gets the mode :func:`open` would give it (a replaced file keeps its own)."""
    _refuse_special(target)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.",
                                   suffix=target.suffix)
    except OSError as exc:
        raise OutputError(f"{target}: cannot write there ({_reason(exc)})") from exc
    os.close(fd)
    try:
        yield Path(tmp)
        _refuse_special(target)  # something put there while the block ran
        if os.path.isfile(tmp) and not os.path.islink(tmp):
            with contextlib.suppress(OSError):  # a file system without modes (FAT)
                os.chmod(tmp, _file_mode(target))
        os.replace(tmp, target)
        _WRITTEN.append(target)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
