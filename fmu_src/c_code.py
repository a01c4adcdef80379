"""What every C build of an FMU shares: C string literals and the FMI headers (from the
installed fmpy; no header is copied into the project)."""

from __future__ import annotations

from pathlib import Path


def c_string(text: str) -> str:
    """A C string literal of ``text``."""
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'



def fmi_headers(fmi_version: int = 2) -> Path:
    """The folder of the FMI headers (fmi2*.h, fmi3*.h) shipped inside the installed fmpy."""
    import fmpy

    folder = Path(fmpy.__file__).resolve().parent / "c-code"
    header = folder / f"fmi{fmi_version}Functions.h"
    if not header.is_file():
        raise FileNotFoundError(f"no {header.name} in {folder}: fmpy installation incomplete")
    return folder


def fmi2_headers() -> Path:
    """The folder of the FMI 2.0 headers shipped inside the installed fmpy."""
    return fmi_headers(2)
