"""ToggleClampNative.fmu: the plant generated to C behind a small FMI 2.0 wrapper.

Checked against the pythonfmu ToggleClamp (same variables; every output to 1e-9
relative over a closing and opening stroke with mold contact), against
:func:`toggle.plant.drive_step` (variable steps), for its state, reset and error
handling, and in four masters: fmpy, libcosim (two instances), Ecos (with the Python FMU
twice in its process) and a C host compiled here that loads the binary with dlopen and no
Python environment.
"""

from __future__ import annotations

import math
import os
import subprocess
import zipfile
from ctypes import byref
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract, read_model_description, simulate_fmu
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave, fmi2Boolean, fmi2Error, fmi2Terminated
from fmpy.model_description import read_build_description
from fmu_support import (
    close_slave,
    run_ecos,
    run_libcosim,
    run_steps,
    slip_along,
    validator_problems,
)
from native_support import native_build

from fmu_src.build import build_fmu
from fmu_src.c_code import fmi2_headers
from fmu_src.host import start_slave
from fmu_src.native_build import slave_variables
from toggle.drive import motor_torque
from toggle.kinematics import stroke_limits
from toggle.params import ParameterError
from toggle.plant import DriveState, PlantOutputs, configure, drive_step, plant_outputs

VARIABLES = slave_variables()[0]
DEFAULT_BANDWIDTH = next(v.start for v in VARIABLES if v.name == "drive_bandwidth")  # Hz
OUTPUTS = list(PlantOutputs._fields)
X_OPEN, X_TOGGLE = stroke_limits(configure("chang2021").mechanism.lower)
X_CONTACT = X_TOGGLE - 1e-3  # m: mold contact 1 mm of crosshead travel before the toggle
REL = 1e-9


@pytest.fixture(scope="module")
def native() -> Path:
    return native_build()  # built once per session (tests/native_support.py)


@pytest.fixture(scope="module")
def unzipped(native: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return Path(extract(str(native), str(tmp_path_factory.mktemp("native_unzipped"))))


@pytest.fixture(scope="module")
def python_fmu(tmp_path_factory: pytest.TempPathFactory):
    """The pythonfmu ToggleClamp, extracted; its runtime released after the module."""
    fmu = build_fmu(tmp_path_factory.mktemp("pythonfmu"))
    return Path(extract(str(fmu), str(tmp_path_factory.mktemp("pythonfmu_unzipped"))))


def _outputs(slave, refs) -> list[float]:
    return slave.getReal([refs[n] for n in OUTPUTS])


def _run(slave, refs, commands_and_steps, t: float = 0.0) -> list:
    """Set x_cmd, doStep for each (x_cmd, h); the outputs after each step."""
    return run_steps(slave, refs, commands_and_steps, _outputs, t)


def _reference(x, v, a, x_contact: float, slip=None, **errors: float) -> PlantOutputs:
    """plant_outputs (numpy) of chang2021 with these parameters; floats for float input. The
    slip state ``slip`` defaults to the one carried along the path x from rest."""
    cfg = configure("chang2021", x_contact=x_contact, errors=errors)
    if slip is None:
        slip = slip_along(x, cfg.asymmetry.slip_distance)
        slip = slip if np.ndim(x) else float(slip[0])
    out = plant_outputs(x, v, a, cfg, slip_state=slip)
    return PlantOutputs(*map(float, out)) if np.ndim(x) == 0 else out


# ---- the FMU as a file ----------------------------------------------------------------------


def test_fmpy_and_fmutool_find_no_problem(native: Path):
    assert validator_problems(native) == []


def test_variables_are_the_pythonfmu_slaves(native: Path):
    md = read_model_description(str(native))
    by_name = {v.name: v for v in md.modelVariables}
    assert list(by_name) == [v.name for v in VARIABLES]
    for spec in VARIABLES:
        v = by_name[spec.name]
        assert (v.causality, v.description) == (spec.causality, spec.description)
        if not spec.is_string:
            assert v.unit == spec.unit
        if spec.start is not None:
            assert (v.start if spec.is_string else float(v.start)) == spec.start
    assert [u.variable.name for u in md.outputs] == OUTPUTS
    assert not md.coSimulation.needsExecutionTool
    assert md.coSimulation.canGetAndSetFMUstate and md.coSimulation.canSerializeFMUstate


def test_archive_has_the_sources_to_rebuild_and_no_fmi_headers(native: Path):
    names = set(zipfile.ZipFile(native).namelist())
    assert {"binaries/linux64/ToggleClampNative.so", "sources/buildDescription.xml",
            "sources/fmi2_clamp.c", "sources/clamp_model.c", "sources/clamp_model.h",
            "sources/clamp_model_data.h"} <= names
    assert not any("fmi2Functions" in n or "win64" in n for n in names)
    build = read_build_description(str(native), validate=True)  # against the FMI 3.0 schema
    assert build[0].sourceFileSets[0].sourceFiles == [
        "fmi2_clamp.c", "clamp_core.c", "clamp_init.c", "clamp_motion.c", "clamp_state.c",
        "drive_lag.c", "clamp_model.c", "link_libm.o"]
    assert {"sources/clamp_core.h", "sources/clamp_core_internal.h",
            "sources/drive_lag.h"} <= names
    needed = subprocess.run(["readelf", "-d", str(_library(native))], capture_output=True,
                            text=True, check=True).stdout
    assert "[libm.so.6]" in needed
    undefined = subprocess.run(["nm", "-D", "--undefined-only", str(_library(native))],
                               capture_output=True, text=True, check=True).stdout
    assert "Py" not in undefined and "python" not in undefined.lower()


def test_sources_rebuild_the_binary_as_an_importing_tool_would(native: Path, tmp_path: Path):
    """gcc on the sources listed in the description, with the tool's own FMI headers."""
    folder = Path(extract(str(native), str(tmp_path / "fmu")))
    md = read_model_description(str(folder))
    sources = md.buildConfigurations[0].sourceFileSets[0].sourceFiles
    library = folder / "binaries" / "linux64" / "ToggleClampNative.so"
    library.unlink()
    subprocess.run(["gcc", "-std=c99", "-shared", "-fPIC", "-O2", "-I", str(folder / "sources"),
                    "-I", str(fmi2_headers()), *(str(folder / "sources" / f) for f in sources),
                    "-o", str(library), "-lm"], check=True, capture_output=True)
    res = simulate_fmu(str(folder), stop_time=0.01, step_size=1e-3,
                       start_values={"x_cmd": X_CONTACT + 5e-4, "x_contact": X_CONTACT})
    want = _reference(X_CONTACT + 5e-4, 0.0, 0.0, X_CONTACT)
    assert want.clamp_force > 0
    assert res["clamp_force"][-1] == pytest.approx(want.clamp_force, rel=REL)


def test_fmpy_cmake_rebuild_links_libm_and_runs_in_a_c_host(native: Path, tmp_path: Path):
    """fmpy's build (CMake on the listed sources, as `fmpy compile`) ignores <Library
    name="m"/>; the listed linker script link_libm.o links libm all the same, so a C host
    that does not link libm itself loads the rebuilt binary."""
    from fmpy.build import build_platform_binary

    folder = Path(extract(str(native), str(tmp_path / "fmu")))
    library = folder / "binaries" / "linux64" / "ToggleClampNative.so"
    library.unlink()
    (tmp_path / "build").mkdir()
    build_platform_binary(folder, build_dir=tmp_path / "build")
    needed = subprocess.run(["readelf", "-d", str(library)], capture_output=True, text=True,
                            check=True).stdout
    assert "[libm.so.6]" in needed
    run = _run_c_host(tmp_path, library, folder, loads=1)
    assert run.returncode == 0, run.stderr
    assert run.stdout.split()[0] == "0"


def _run_c_host(tmp_path: Path, library: Path, folder: Path, loads: int):
    """tests/fmu_c_host.c (no libm, no Python environment) on an extracted native FMU."""
    host = tmp_path / "host"
    subprocess.run(["gcc", "-std=c99", "-Wall", "-Wextra", "-Werror", "-I", str(fmi2_headers()),
                    str(Path(__file__).parent / "fmu_c_host.c"), "-o", str(host), "-ldl"],
                   check=True, capture_output=True)
    md = read_model_description(str(folder))
    refs = {v.name: v.valueReference for v in md.modelVariables}
    return subprocess.run(
        [str(host), str(library), md.guid, (folder / "resources").as_uri(),
         *(str(refs[n]) for n in ("x_cmd", "input_force", "m_platen")), "4.0", str(loads)],
        capture_output=True, text=True, env={"PATH": "/usr/bin:/bin"}, timeout=30)


def _library(native: Path) -> Path:
    folder = native.parent / "lib"
    folder.mkdir(exist_ok=True)
    zipfile.ZipFile(native).extract("binaries/linux64/ToggleClampNative.so", folder)
    return folder / "binaries" / "linux64" / "ToggleClampNative.so"


# ---- agreement with the pythonfmu FMU ------------------------------------------------------

STOP_TIME = 1.0  # s: close in 0.4 s, hold, open in 0.4 s, hold


def _stroke() -> np.ndarray:
    t = np.linspace(0.0, STOP_TIME, 1001)
    smooth = lambda s: s**3 * (10 - 15 * s + 6 * s**2)  # noqa: E731
    s_close, s_open = np.clip(t / 0.4, 0, 1), np.clip((t - 0.5) / 0.4, 0, 1)
    x = X_OPEN + (X_TOGGLE - X_OPEN) * (smooth(s_close) - smooth(s_open))
    return np.array(list(zip(t, x)), dtype=[("time", float), ("x_cmd", float)])


def _both(unzipped: Path, python_fmu: Path, stroke: np.ndarray | None = None,
          **start: float) -> list:
    start = {"x_cmd": X_OPEN, "x_contact": X_CONTACT, **start}
    stroke = _stroke() if stroke is None else stroke
    return [simulate_fmu(str(d), stop_time=STOP_TIME, step_size=1e-3, input=stroke,
                         start_values=start, output=OUTPUTS) for d in (unzipped, python_fmu)]


def _assert_same(native: dict, python: dict) -> None:
    for name in OUTPUTS:
        want = python[name]
        np.testing.assert_allclose(native[name], want, rtol=REL,
                                   atol=REL * 1e-3 * float(np.max(np.abs(want))), err_msg=name)


@pytest.mark.parametrize("delta_r8, frictions", [
    (0.0, {}), (0.5e-3, {}),
    (0.5e-3, {"platen_friction": 4.26, "platen_rate": 1.81, "guide_friction": 1.5})])
def test_native_and_pythonfmu_agree_over_the_stroke(unzipped: Path, python_fmu: Path,
                                                    delta_r8: float, frictions: dict):
    """Also with the guides' Coulomb frictions set (parameters of both, from one table)."""
    native, python = _both(unzipped, python_fmu, delta_r8=delta_r8, drive_bandwidth=0.0,
                           **frictions)  # the ideal drive: x ends at the command
    _assert_same(native, python)
    assert native["clamp_force"].max() > 100.0  # N: the mold was reached
    assert native["x"][-1] == pytest.approx(X_OPEN, abs=1e-6)  # and left again
    assert (abs(native["asymmetry"]).max() > 1e-4) == (delta_r8 != 0)


@pytest.mark.parametrize("delta_r8", [0.0, 0.5e-3])
def test_without_a_mold_both_fmus_run_over_the_toggle_and_back(unzipped: Path,
                                                               python_fmu: Path,
                                                               delta_r8: float):
    """x_contact left at its start value (the toggle): no mold in either build, so past the
    toggle the platen retreats in both. The two builds once found the toggle with different
    root finders, 1e-13 m apart: the native one saw a mold at its start value, held the
    platen and reported the mold's mechanical advantage (49,954 against 362)."""
    t = np.linspace(0.0, STOP_TIME, 1001)
    beyond = X_TOGGLE + 8e-3  # m of crosshead travel past the toggle, inside the range
    x = X_OPEN + (beyond - X_OPEN) * np.sin(np.pi * t / STOP_TIME) ** 2
    stroke = np.array(list(zip(t, x)), dtype=[("time", float), ("x_cmd", float)])
    native, python = _both(unzipped, python_fmu, stroke, x_contact=X_TOGGLE,
                           delta_r8=delta_r8)
    _assert_same(native, python)
    for run in (native, python):
        assert not run["clamp_force"].any()
        past = run["x"] > X_TOGGLE + 1e-3
        closing = run["velocity"] > 0
        assert (run["platen_velocity"][past & closing] < 0).all()  # over the toggle: back
        retreat = run["platen_position"].max() - run["platen_position"][np.argmax(run["x"])]
        assert 1e-5 < retreat < 1e-4  # m: 38 um at 8 mm past the toggle


def test_native_fmu_takes_the_rotor_inertia_as_a_parameter(unzipped: Path, python_fmu: Path):
    """Another rotor and screw inertia: the native FMU's outputs are the Python FMU's, its
    motor_torque the library's (toggle.drive.motor_torque, the one equation)."""
    inertias = {"rotor_inertia": 3e-4, "screw_inertia": 4e-5}
    native, python = _both(unzipped, python_fmu, **inertias)
    _assert_same(native, python)
    drive = configure("chang2021", drive=inertias).mechanism.drive
    torque = motor_torque(native["input_force"], drive, native["acceleration"])
    np.testing.assert_allclose(native["motor_torque"], torque, rtol=1e-12, atol=1e-15)
    default = _both(unzipped, python_fmu)[0]["motor_torque"]
    assert np.max(np.abs(native["motor_torque"] - default)) > 1e-3  # N m: the rotor counts


def test_lagging_drive_agrees_to_rounding_and_the_plant_exactly(unzipped: Path,
                                                                python_fmu: Path):
    """With a 20 Hz drive lag the two FMUs' motions differ by rounding only (their ZOH
    matrices by an ulp: closed form here, scipy's expm there); the input force is so
    sensitive to the velocity near standstill (the unequal halves' friction sign has a
    1e-6 m/s width) that such differences reach 1e-7 N, so the outputs are checked
    against the plant at the native FMU's own motion."""
    native, python = _both(unzipped, python_fmu, delta_r8=0.5e-3, drive_bandwidth=20.0)
    for name in ("x", "velocity", "acceleration"):
        scale = float(np.max(np.abs(python[name])))
        np.testing.assert_allclose(native[name], python[name], rtol=0, atol=1e-12 * scale)
    want = _reference(native["x"], native["velocity"], native["acceleration"], X_CONTACT,
                      r8=0.5e-3)
    for name in OUTPUTS:  # numpy's evaluation of the plant against CasADi's: 1e-9 of peak
        got, ref = native[name], np.broadcast_to(getattr(want, name), native[name].shape)
        if name == "mechanical_advantage":  # 1/|q| is ill-conditioned at the toggle: use q
            got, ref = 1.0 / got, 1.0 / ref
        np.testing.assert_allclose(got, ref, rtol=0, atol=REL * float(np.max(np.abs(ref))),
                                   err_msg=name)
    assert native["clamp_force"].max() > 100.0


@pytest.mark.parametrize("bandwidth", [0.0, 20.0])
def test_variable_step_sizes_follow_the_drive_model(unzipped: Path, bandwidth: float):
    steps = [(X_OPEN + 1e-3, 1e-3), (X_OPEN + 2e-3, 1e-3), (X_OPEN + 2e-2, 3e-2),
             (X_CONTACT + 5e-4, 0.2), (X_CONTACT + 5e-4, 7e-4), (X_OPEN, 3e-2)]
    slave, refs = start_slave(unzipped, "steps", {"x_cmd": X_OPEN, "x_contact": X_CONTACT,
                                                  "drive_bandwidth": bandwidth})
    out = _run(slave, refs, steps)
    close_slave(slave)
    drive, bounds = DriveState.at_rest(X_OPEN), configure("chang2021").input_range
    for (x_cmd, h), got in zip(steps, out, strict=True):  # extrapolated within x_cmd's range
        drive = drive_step(drive, x_cmd, h, bandwidth, 0.7, bounds=bounds)
        assert got[:3] == pytest.approx(tuple(drive[:3]), rel=1e-12, abs=1e-12)  # a: w^2 (u - x)
        assert got == pytest.approx(list(_reference(*got[:3], X_CONTACT)), rel=REL, abs=1e-12)


# ---- state, reset, errors -------------------------------------------------------------------

APPROACH = [(X_OPEN + k * 4.2e-3, 1e-3) for k in range(1, 14)]  # ends past the contact


def test_state_get_set_serialize_and_reset_reproduce_outputs(unzipped: Path):
    slave, refs = start_slave(unzipped, "state", {"x_cmd": X_OPEN, "x_contact": X_CONTACT,
                                                  "drive_bandwidth": 20.0})
    _run(slave, refs, APPROACH[:5])
    state = slave.getFMUstate()
    saved = slave.serializeFMUstate(state)
    first = _run(slave, refs, APPROACH[5:], t=5e-3)
    slave.setFMUstate(state)
    second = _run(slave, refs, APPROACH[5:], t=5e-3)
    restored = slave.deSerializeFMUstate(saved)
    slave.setFMUstate(restored)
    third = _run(slave, refs, APPROACH[5:], t=5e-3)
    corrupt = bytearray(saved)
    corrupt[40] ^= 1
    with pytest.raises(FMICallException):
        slave.deSerializeFMUstate(bytes(corrupt))
    slave.reset()
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    for name, value in {"x_cmd": X_OPEN, "x_contact": X_CONTACT, "drive_bandwidth": 20.0}.items():
        slave.setReal([refs[name]], [value])
    slave.exitInitializationMode()
    fourth = _run(slave, refs, APPROACH)[5:]
    close_slave(slave, state, restored)
    assert first == second == third == fourth
    assert first[0][OUTPUTS.index("velocity")] != 0  # the saved state had internal motion


@pytest.mark.parametrize(
    ("start", "named"),
    [
        ({"delta_r4b": 1.0}, "parameter delta_r4b = 1 m is outside [-0.005, 0.005] m"),
        ({"x_contact": -1.0}, "x_contact"),
        ({"m_platen": math.inf}, "m_platen"),
        ({"mu": math.inf}, "mu"),
        ({"mu": -0.2}, "mu"),
        ({"delta_r8": math.nan}, "delta_r8"),
        ({"x_cmd": 0.5}, "input x_cmd = 0.5 m is outside"),
        ({"delta_r7b": 1.0}, "delta_r7b"),
        ({"drive_bandwidth": 10.0, "drive_damping": -1.0}, "drive_damping"),
        ({"rotor_inertia": -1e-5}, "rotor_inertia"),
    ],
)
def test_bad_parameter_fails_initialisation_with_a_message(unzipped: Path, start, named):
    log: list[tuple[int, str]] = []
    with pytest.raises(FMICallException) as failed:
        start_slave(unzipped, "bad", start, log=lambda s, text: log.append((s, text)))
    assert failed.value.status == fmi2Error
    errors = [text for status, text in log if status == fmi2Error]
    assert errors and errors[0].startswith("initialisation failed") and named in errors[0], log


def test_a_preset_other_than_the_built_one_is_refused(unzipped: Path):
    with pytest.raises(FMICallException) as refused:
        start_slave(unzipped, "preset", {"preset": "dong2022"})
    assert refused.value.status == fmi2Error


@pytest.mark.parametrize("x_cmd", [0.09, -0.09, math.nan])
def test_input_outside_the_stroke_is_an_error_that_changes_nothing(unzipped: Path, x_cmd):
    log: list[tuple[int, str]] = []
    slave, refs = start_slave(unzipped, "range", {"x_cmd": X_OPEN, "drive_bandwidth": 0.0},
                              log=lambda s, text: log.append((s, text)))
    before = _run(slave, refs, APPROACH[:2])[-1]
    slave.setReal([refs["x_cmd"]], [x_cmd])
    with pytest.raises(FMICallException) as refused:
        slave.doStep(2e-3, 1e-3)
    after = _outputs(slave, refs)
    again = _run(slave, refs, APPROACH[2:3], t=2e-3)[-1]
    close_slave(slave)
    assert refused.value.status == fmi2Error and after == before
    assert any("outside the assemblable range" in text for s, text in log if s == fmi2Error)
    assert again[0] == APPROACH[2][0]


# ---- other masters --------------------------------------------------------------------------


def test_two_instances_run_in_libcosim(native: Path, tmp_path: Path):
    x = X_CONTACT + 5e-4
    initial = [(name, var, value) for name in ("nominal", "long_r8")
               for var, value in (("x_cmd", x), ("x_contact", X_CONTACT))]
    result = run_libcosim(tmp_path, {"nominal": native, "long_r8": native},
                          {n: OUTPUTS for n in ("nominal", "long_r8")},
                          initial=[*initial, ("long_r8", "delta_r8", 0.5e-3)], stop_time=0.05)
    assert result["ok"]
    for name, errors in (("nominal", {}), ("long_r8", {"r8": 0.5e-3})):
        want = _reference(x, 0.0, 0.0, X_CONTACT, **errors)
        got = result["last"][name]
        assert [got[n] for n in OUTPUTS] == pytest.approx(list(want), rel=REL, abs=1e-12)
    assert result["last"]["long_r8"]["input_force"] != result["last"]["nominal"]["input_force"]


def test_ecos_drives_both_builds_and_the_python_one_twice(native: Path, unzipped: Path,
                                                         tmp_path: Path):
    """Ecos, a C++ master we did not write, sets x_cmd before every step over a closing and
    opening stroke with a mold: the native FMU gives what fmpy gets from it, bit for bit; the
    Python FMU, loaded twice in the one process (with and without the link-8 error), gives
    the native one's outputs to REL and the symmetric clamp's."""
    python = build_fmu(tmp_path / "pythonfmu")
    t = np.arange(0.0, 2.0 + 5e-4, 1e-3)
    x = X_OPEN + (X_TOGGLE - X_OPEN) * np.sin(np.pi * t / t[-1]) ** 2
    long_r8 = [(name, var, value) for name in ("native", "python")
               for var, value in (("delta_r8", 0.5e-3), ("x_contact", X_CONTACT))]
    got = run_ecos(tmp_path, {"native": native, "python": python, "symmetric": python}, x,
                   OUTPUTS, [*long_r8, ("symmetric", "x_contact", X_CONTACT)])
    want = {}  # the native build in fmpy, per link-8 error
    for delta_r8 in (0.5e-3, 0.0):
        slave, refs = start_slave(unzipped, "fmpy", {"x_cmd": x[0], "x_contact": X_CONTACT,
                                                     "delta_r8": delta_r8})
        want[delta_r8] = _run(slave, refs, [(xk, 1e-3) for xk in x[1:]])
        close_slave(slave)
    assert got["native"] == want[0.5e-3]
    for name, delta_r8 in (("python", 0.5e-3), ("symmetric", 0.0)):
        np.testing.assert_allclose(got[name], want[delta_r8], rtol=REL, atol=1e-9,
                                   err_msg=name)
    clamp = OUTPUTS.index("clamp_force")
    assert max(row[clamp] for row in got["python"]) > 100.0  # N: the mold was clamped
    force = OUTPUTS.index("input_force")
    assert max(abs(row[force] - sym[force]) for row, sym in zip(got["python"], got["symmetric"])
               ) > 10.0  # N: the link-8 error of one instance did not leak into the other


def test_a_c_host_runs_the_binary_without_python(native: Path, unzipped: Path, tmp_path: Path):
    """tests/fmu_c_host.c (the pythonfmu FMU's C master too), with no Python environment:
    two loads in one process, each 500 steps, then a clean exit."""
    run = _run_c_host(tmp_path, _library(native), unzipped, loads=2)
    assert run.returncode == 0, run.stderr
    drive = DriveState.at_rest(-3.4386e-3)
    for k in range(1, 501):  # the host's ramp, in the same floating-point operations
        drive = drive_step(drive, -3.4386e-3 + (0.04 + 3.4386e-3) * k / 500.0, 1e-3,
                       DEFAULT_BANDWIDTH, 0.7)  # the default drive lag: the host sets none
    cfg = configure("chang2021", masses={"platen": 4.0})
    want = float(plant_outputs(drive.x, drive.v, drive.a, cfg).input_force)
    rows = [line.split() for line in run.stdout.splitlines()]
    assert [status for status, _ in rows] == ["0", "0"]
    assert [float(force) for _, force in rows] == pytest.approx([want, want], rel=1e-12)


def _closing_input(path: Path) -> Path:
    """CSV input of the FMI Compliance Checker: close to the toggle, hold, open, hold."""
    rows = [f"{float(t)!r},{float(x)!r}" for t, x in _stroke()]
    path.write_text('"time","x_cmd"\n' + "\n".join(rows) + "\n")
    return path


@pytest.mark.parametrize("closing", [False, True])
def test_fmi_compliance_checker_finds_no_problem(native: Path, tmp_path: Path, closing: bool):
    """The default experiment, and a 1 ms closing stroke from an input file."""
    checker = os.environ.get("FMUCHECK")
    if not checker:
        pytest.skip("set FMUCHECK to an fmuCheck.linux64 built from "
                    "modelica-tools/FMUComplianceChecker (see docs/fmu-native.md)")
    log, out = tmp_path / "check.log", tmp_path / "out.csv"
    args = ["-h", "1e-3", "-s", "1.0", "-n", "0", "-i",
            str(_closing_input(tmp_path / "in.csv"))] if closing else []
    run = subprocess.run([checker, "-l", "3", "-e", str(log), "-o", str(out), *args,
                          str(native)], capture_output=True, text=True, timeout=120)
    text = log.read_text()
    assert run.returncode == 0, text
    assert "0 warning(s) and error(s)" in text and "0 Warning(s)" in text
    assert "0 Error(s)" in text
    result = np.genfromtxt(out, delimiter=",", names=True)
    if not closing:
        assert result["x"].max() == pytest.approx(X_OPEN, abs=1e-7)
        return
    # the default drive lag overshoots the toggle a little: the checker's run is fmpy's
    fmpy_run = simulate_fmu(str(native), stop_time=1.0, step_size=1e-3, input=_stroke(),
                            output=["x"])
    assert result["x"].max() == pytest.approx(fmpy_run["x"].max(), rel=1e-9)
    assert result["x"].max() > X_TOGGLE - 1e-4


def test_command_line_builds_the_native_fmu(tmp_path: Path, capsys: pytest.CaptureFixture):
    from toggle_cli import main

    assert main(["build-fmu", "--native", "--preset", "chang2021", "--out", str(tmp_path)]) == 0
    assert (tmp_path / "ToggleClampNative.fmu").is_file()  # and named on the last line
    assert capsys.readouterr().out.strip() == f"results in {tmp_path}/ (ToggleClampNative.fmu)"


# ---- initialisation mode, re-initialisation, logging, status ---------------------------------


def _in_initialisation_mode(folder: Path, start: dict):
    """An fmpy slave of an extracted FMU in Initialization Mode with ``start`` set."""
    md = read_model_description(str(folder))
    refs = {v.name: v.valueReference for v in md.modelVariables}
    slave = FMU2Slave(guid=md.guid, unzipDirectory=str(folder),
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName="init")
    slave.instantiate(loggingOn=False)
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    for name, value in start.items():
        slave.setReal([refs[name]], [value])
    return slave, refs


def test_outputs_in_initialisation_mode_are_the_pythonfmu_builds(unzipped: Path,
                                                                 python_fmu: Path):
    """Declared calculated InitialUnknowns: both builds compute them from the values set
    so far, in Initialization Mode, and again after a parameter changes there."""
    start = {"x_cmd": X_CONTACT + 5e-4, "x_contact": X_CONTACT, "delta_r8": 0.5e-3}
    got = {}
    for name, folder in (("native", unzipped), ("python", python_fmu)):
        slave, refs = _in_initialisation_mode(folder, start)
        first = _outputs(slave, refs)
        slave.setReal([refs["m_platen"]], [4.0])
        slave.setReal([refs["x_cmd"]], [X_CONTACT + 2e-4])
        got[name] = (first, _outputs(slave, refs))
        slave.exitInitializationMode()
        close_slave(slave)
    for native, python in zip(got["native"], got["python"], strict=True):
        assert native == pytest.approx(python, rel=REL, abs=1e-300)
    assert got["native"][0][OUTPUTS.index("x")] == X_CONTACT + 5e-4
    assert got["native"][0][OUTPUTS.index("clamp_force")] > 0  # in the mold, at init
    assert got["native"][1][OUTPUTS.index("x")] == X_CONTACT + 2e-4


def test_parameters_can_be_set_again_after_a_failed_initialisation(unzipped: Path):
    """As docs/fmu.md says of both builds: no fmi2Reset needed."""
    log: list[tuple[int, str]] = []
    slave, refs = _in_initialisation_mode(unzipped, {"m_platen": -3.0, "drive_bandwidth": 0.0})
    with pytest.raises(FMICallException):
        slave.exitInitializationMode()
    with pytest.raises(FMICallException):  # no step after a failed initialisation
        slave.doStep(0.0, 1e-3)
    slave.setReal([refs["m_platen"]], [3.0])
    slave.exitInitializationMode()
    out = _run(slave, refs, APPROACH[:3])[-1]
    close_slave(slave)
    assert out[0] == APPROACH[2][0] and not log


def test_the_no_toggle_geometry_names_its_parameters(unzipped: Path):
    """delta_r1L and delta_r2L within their ranges, together such that the lower half never
    reaches its toggle: the message is the pythonfmu build's (toggle.plant.configure)."""
    log: list[tuple[int, str]] = []
    errors = {"r1L": 5e-3, "r2L": -5e-3}
    with pytest.raises(FMICallException):
        start_slave(unzipped, "geometry", {f"delta_{n}": v for n, v in errors.items()},
                    log=lambda s, text: log.append((s, text)))
    with pytest.raises(ParameterError) as python:
        configure("chang2021", errors=errors)
    text, want = log[0][1], f"initialisation failed: {python.value}"
    assert text.startswith(want.split(" in the assemblable range")[0]), (text, want)


def test_unknown_log_categories_are_refused_and_terminated_is_answered(unzipped: Path):
    log: list[tuple[int, str]] = []
    slave, refs = start_slave(unzipped, "categories", {},
                              log=lambda s, text: log.append((s, text)))
    slave.setDebugLogging(True, ["logStatusError", "logAll"])
    with pytest.raises(FMICallException):
        slave.setDebugLogging(True, ["logEverything"])
    assert 'unknown log category "logEverything"' in log[-1][1]
    status = fmi2Boolean()
    assert slave.fmi2GetBooleanStatus(slave.component, fmi2Terminated, byref(status)) == 0
    assert status.value == 0
    close_slave(slave)


def test_clamp_a_drives_clamp_b_in_libcosim(native: Path, tmp_path: Path):
    """A's x wired to B's x_cmd: B reads A's position in Initialization Mode (not 0.0, from
    which its first step would ask for 20 m/s), then follows A's stroke."""
    result = run_libcosim(tmp_path, {"a": native, "b": native},
                          {"a": ["x"], "b": ["x", "velocity", "input_force"]},
                          initial=[("a", "x_cmd", 0.02)],
                          connections=[("a", "x", "b", "x_cmd")], stop_time=0.1)
    assert result["ok"]
    assert result["last"]["b"]["x"] == result["last"]["a"]["x"] == 0.02
    assert result["last"]["b"]["velocity"] == 0.0
