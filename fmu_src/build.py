"""Build this project's FMI 2.0 Co-Simulation FMUs with pythonfmu 0.7.

pythonfmu writes no units, no min/max, no output dependencies and no
InitialUnknowns, so fmpy's validator rejects its FMUs.
:mod:`fmu_src.description` (called from :meth:`fmu_src.slave.DeclaredSlave.to_xml`)
completes the description from the slave's :class:`~fmu_src.variables.Var` table;
:func:`build_fmu` bundles the
modules of ``toggle`` and ``fmu_src`` that the slave uses under names unique to their
code, puts the FMI guard (:mod:`fmu_src.guard_build`) in front of pythonfmu's binary and
refuses to write an FMU that fmpy does not validate.
"""

from __future__ import annotations

import hashlib
import os
import re
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

#: This package's folder, and the project's root (the model package toggle/ beside it).
FMU_SRC_DIR = Path(__file__).resolve().parent
ROOT = FMU_SRC_DIR.parent
PACKAGE_DIR = ROOT / "toggle"
DEFAULT_SLAVE = FMU_SRC_DIR / "toggle_clamp_fmu.py"
#: The project's packages an FMU bundles (the model, and this one's slave support).
BUNDLED_PACKAGES = ("toggle", "fmu_src")
#: The Python the FMU needs (major.minor): the one it is built with.
PYTHON_VERSION = f"{sys.version_info.major}.{sys.version_info.minor}"

_SITE_HEADER = f"""\
# pythonfmu 0.7's findClass releases a reference to this module's dict that it does not
# own, once per fmi2Instantiate, after running this text again: each run keeps one more.
globals().setdefault("_pythonfmu_dict_refs", []).append(globals())

# A host that embeds Python (a C master) starts with the base interpreter's path: add the
# site-packages of the venv VIRTUAL_ENV names (the guard loaded that venv's Python). No
# path of the build machine is written into the FMU.
import os as _os
import site as _site
import sys as _sys

_venv = _os.environ.get("VIRTUAL_ENV")
if _venv:
    _site.addsitedir(_os.path.join(_venv, "lib", "python%d.%d" % _sys.version_info[:2],
                                   "site-packages"))
try:
    import casadi as _casadi, numpy as _numpy, scipy as _scipy  # noqa: F401
except ImportError as _missing:
    _sys.stderr.write("ToggleClamp.fmu: %s in Python %s at %s: run the master in a venv of "
                      "CPython {PYTHON_VERSION} with toggle-clamp installed (a master without "
                      "Python: set VIRTUAL_ENV to it)\\n" % (_missing, _sys.version.split()[0],
                                                           _sys.prefix))
    raise
"""
_IMPORT = re.compile(r"^(\s*)(from|import)\s+(toggle|fmu_src)(?=[\s.])", re.MULTILINE)


def bundled_modules(slave_file: Path) -> tuple[list[str], str]:
    """The project's modules the slave imports, and its slave class (in a fresh interpreter)."""
    code = ("import importlib.util, sys\n"
            "from pythonfmu import Fmi2Slave\n"
            f"spec = importlib.util.spec_from_file_location('_slave', {str(slave_file)!r})\n"
            "module = importlib.util.module_from_spec(spec)\n"
            "spec.loader.exec_module(module)\n"
            "print(' '.join(sorted(m for m in sys.modules "
            f"if m.split('.')[0] in {BUNDLED_PACKAGES!r})))\n"
            "print(' '.join(k for k, v in vars(module).items() if isinstance(v, type) "
            "and issubclass(v, Fmi2Slave) and v.__module__ == '_slave'))")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                            env=env, cwd=ROOT)
    if result.returncode:
        raise RuntimeError(f"the slave {slave_file} does not import:\n{result.stderr}")
    modules, classes = result.stdout.splitlines()
    if len(classes.split()) != 1:
        raise ValueError(f"{slave_file} must define one Fmi2Slave class, found {classes!r}")
    return modules.split(), classes


def stage_sources(slave_file: Path, preset: str | None, stage: Path) -> tuple[Path, list[Path]]:
    """Copy the slave and the modules it uses into ``stage`` under a name unique to the code.

    The bundled packages are ``toggle_<hash>`` and ``fmu_src_<hash>`` (the hash of the
    bundled sources), with their imports rewritten to those names and the slave module
    inside the second, so an FMU
    never shares Python modules with another version of the project or with a
    ``toggle`` installed in the host (pythonfmu imports into the host's
    ``sys.modules``). pythonfmu's entry script is a generated stub that imports
    the slave class: pythonfmu executes that script's text again at every
    fmi2Instantiate, when an earlier extraction of the FMU may be deleted, so
    it must read no file. Returns the stub and the files for ``resources/``.
    """
    modules, slave_class = bundled_modules(slave_file)
    files = {}
    for module in {*modules, "fmu_src"}:  # the slave goes into fmu_src's bundle
        relative = Path(*module.split("."))
        source = ROOT / relative / "__init__.py"
        if not source.is_file():
            source = (ROOT / relative).with_suffix(".py")
        files[source.relative_to(ROOT)] = source.read_text(encoding="utf-8")
    files[Path("fmu_src", f"{slave_file.stem}.py")] = slave_file.read_text(encoding="utf-8")
    if preset is not None:
        files[Path("fmu_src", "preset.toml")] = preset_table_text(preset)
    digest = hashlib.sha256(repr(sorted(files.items())).encode()).hexdigest()[:12]
    for relative, text in files.items():
        target = stage / f"{relative.parts[0]}_{digest}" / Path(*relative.parts[1:])
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_text(_IMPORT.sub(rf"\1\2 \3_{digest}", text), encoding="utf-8")
    script = stage / f"toggle_{digest}_slave.py"
    script.write_text(f'"""pythonfmu entry point written by toggle build-fmu."""\n{_SITE_HEADER}'
                      f"from fmu_src_{digest}.{slave_file.stem} import {slave_class}"
                      "  # noqa: E402\n", encoding="utf-8")
    packages = sorted({stage / f"{relative.parts[0]}_{digest}" for relative in files})
    return script, packages


def build_folder() -> Path:
    """The one folder ``toggle build-fmu`` writes its FMU into and ``hil run`` takes it from:
    the checkout's build/ when the project runs from its checkout (an editable install,
    wherever the command is started), else build/ of the current folder (an installed
    package has no folder of its own to write in), as ``cargo``'s target/ or CMake's
    build tree do."""
    return (ROOT if (ROOT / "pyproject.toml").is_file() else Path.cwd()) / "build"


def fmu_preset(path: Path) -> str | None:
    """The preset an FMU of this project was built for (its String parameter ``preset``'s
    start value, in either FMU's modelDescription.xml, FMI 2.0 or 3.0); None for another
    FMU or a file that is none."""
    from xml.etree import ElementTree

    try:
        with zipfile.ZipFile(path) as archive:
            root = ElementTree.fromstring(archive.read("modelDescription.xml"))
    except (OSError, KeyError, zipfile.BadZipFile, ElementTree.ParseError):
        return None
    for node in root.iter():
        if node.get("name") != "preset":
            continue
        string = node.find("String")  # FMI 2.0: <ScalarVariable><String start=.../>
        start = string.get("start") if string is not None else node.get("start")
        if start is None and node.find("Start") is not None:  # FMI 3.0: <String><Start value>
            start = node.find("Start").get("value")
        return start
    return None


def preset_table_text(preset: str) -> str:
    """The TOML text of a preset that the FMU can run (it needs [dynamics] and [drive])."""
    from toggle.params import load_preset, preset_file, preset_table, split_group
    from toggle.plant import PlantConfig

    PlantConfig(load_preset(preset))  # names what the preset lacks
    name, group = split_group(preset)  # a file's path may hold "/"; a family's group does
    table, _ = preset_table(name)
    if "groups" in table or group is not None:
        raise ValueError(f"preset {preset!r}: build the FMU from a single mechanism")
    path = preset_file(name) or PACKAGE_DIR / "presets" / f"{name}.toml"
    return path.read_text(encoding="utf-8")


def build_fmu(
    out_dir: Path,
    slave_file: Path = DEFAULT_SLAVE,
    preset: str | None = "chang2021",
) -> Path:
    """Build ``<out_dir>/<ModelName>.fmu`` from a slave file; return its path.

    The modules of ``toggle`` and ``fmu_src`` that the slave uses are bundled in ``resources/``
    under a name unique to their code (see :func:`stage_sources`), with the
    preset's TOML for the clamp slave; the binary is the FMI guard
    (:mod:`fmu_src.guard_build`) in front of pythonfmu's library. The FMU runs in
    the Python it was built with (docs/fmu.md). Raises RuntimeError if the
    guard does not compile or fmpy's validator finds problems in the result.
    """
    from fmpy import extract
    from fmpy.validation import validate_fmu
    from pythonfmu import FmuBuilder

    from fmu_src.guard_build import INNER_LIBRARY, PLATFORM, compile_guard

    slave_file = Path(slave_file).resolve()
    if not slave_file.is_file():
        raise FileNotFoundError(f"no slave file {slave_file}")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="toggle_fmu_") as tmp:
        stage = Path(tmp) / "stage"
        stage.mkdir()
        script, project = stage_sources(slave_file, preset if slave_file == DEFAULT_SLAVE
                                        else None, stage)
        try:
            built = Path(FmuBuilder.build_FMU(script, dest=tmp, project_files=project))
        finally:  # FmuBuilder imports the script and leaves it on sys.path/sys.modules
            bundled = {script.stem, *(path.name for path in project)}
            for name in [m for m in sys.modules if m.split(".")[0] in bundled]:
                sys.modules.pop(name, None)
            while str(stage) in sys.path:
                sys.path.remove(str(stage))
        unzipped = Path(extract(str(built), str(Path(tmp) / "unzipped")))
        guard = Path(tmp) / "guard" / "guard.so"
        guard.parent.mkdir()
        compile_guard(unzipped, guard)
        fmu = out_dir / built.name
        binary = f"binaries/{PLATFORM}/{built.stem}.so"
        with zipfile.ZipFile(built) as src, zipfile.ZipFile(fmu.with_suffix(".tmp"), "w",
                                                            zipfile.ZIP_DEFLATED) as dst:
            for item in src.infolist():
                if item.filename == binary:
                    dst.writestr(f"binaries/{PLATFORM}/{INNER_LIBRARY}", src.read(item))
                    dst.write(guard, binary)
                elif not item.filename.startswith("binaries/") or item.filename.startswith(
                        f"binaries/{PLATFORM}/"):  # no binary that no test loads (win64)
                    dst.writestr(item, src.read(item))
        fmu.with_suffix(".tmp").replace(fmu)
    problems = validate_fmu(str(fmu))
    if problems:
        raise RuntimeError(f"{fmu} is not a valid FMU:\n" + "\n".join(problems))
    return fmu
