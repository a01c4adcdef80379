"""FMU tooling on a trivial slave: build, validation, simulation, state, errors, hosts."""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract, read_model_description, simulate_fmu
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import fmi2Error
from fmu_support import (
    built_fmu,
    close_slave,
    load_module,
    run_fresh,
    run_libcosim,
    validator_problems,
)

from fmu_src.description import extend_model_description
from fmu_src.host import start_slave
from fmu_src.slave import Var

SLAVE_FILE = Path(__file__).parent / "fmu_fixtures" / "trivial_slave.py"
TRIVIAL = load_module(SLAVE_FILE, "trivial_slave_inproc")


@pytest.fixture(scope="module")
def fmu() -> Path:
    return built_fmu("trivial")


@pytest.fixture(scope="module")
def unzipped(fmu: Path, tmp_path_factory: pytest.TempPathFactory):
    """The FMU extracted once."""
    return Path(extract(str(fmu), str(tmp_path_factory.mktemp("unzipped"))))


def _run(slave, refs, u_and_dt) -> list[tuple[float, float]]:
    """Step the slave through (u, dt) pairs; return (y, x) after each step."""
    out, t = [], 0.0
    for u, dt in u_and_dt:
        slave.setReal([refs["u"]], [u])
        slave.doStep(t, dt)
        t += dt
        out.append(tuple(slave.getReal([refs["y"], refs["x"]])))
    return out


# ---- build and model description ---------------------------------------------------


def test_fmpy_and_fmutool_find_no_problem(fmu: Path):
    assert validator_problems(fmu) == []


def test_description_carries_units_limits_and_structure(fmu: Path):
    md = read_model_description(str(fmu))
    units = {u.name for u in md.unitDefinitions}
    by_name = {v.name: v for v in md.modelVariables}
    for spec in TRIVIAL.TrivialGain.VARIABLES:
        v = by_name[spec.name]
        assert (v.unit, v.description) == (spec.unit, spec.description)
        assert v.unit in units
    gain = by_name["gain"]
    assert (gain.initial, float(gain.start), float(gain.min), float(gain.max)) == (
        "exact",
        2.0,
        0.0,
        1e3,
    )
    assert {by_name[n].initial for n in ("y", "x")} == {"calculated"}
    outputs = {u.variable.name: u.dependencies for u in md.outputs}
    assert outputs == {"y": [], "x": []}
    assert {u.variable.name for u in md.initialUnknowns} == {"y", "x"}
    assert md.defaultExperiment.stepSize == "0.001"
    assert md.coSimulation.canGetAndSetFMUstate and md.coSimulation.canSerializeFMUstate
    assert md.version and md.license == "MIT" and md.copyright


def test_bundle_is_the_slave_and_the_modules_it_uses_under_a_name_of_their_own(fmu: Path):
    """No top-level ``toggle`` or ``fmu_src`` (they would be shared with the host's and
    other FMUs'), only the modules the slave imports, and no binary for a platform no test
    loads."""
    with zipfile.ZipFile(fmu) as archive:
        names = set(archive.namelist())
        stub = archive.read("resources/slavemodule.txt").decode().strip()
    digest = stub.removeprefix("toggle_").removesuffix("_slave")
    assert len(digest) == 12 and int(digest, 16) >= 0
    package = f"fmu_src_{digest}"
    assert {f"resources/{stub}.py", f"resources/{package}/__init__.py",
            f"resources/{package}/slave.py", f"resources/{package}/trivial_slave.py",
            "binaries/linux64/TrivialGain.so", "binaries/linux64/pythonfmu-export.so"} <= names
    assert not any(n.startswith(("resources/toggle/", "resources/fmu_src/", "binaries/win64"))
                   for n in names)
    assert not any(n.startswith(f"resources/{package}/build") for n in names)


def test_output_dependencies_are_written_as_indices():
    class Feedthrough(TRIVIAL.TrivialGain):
        VARIABLES = (
            *TRIVIAL.TrivialGain.VARIABLES[:2],
            Var("y", "output", "m/s", "gain * u", depends_on=("u",)),
            TRIVIAL.TrivialGain.VARIABLES[3],
        )

    root = Feedthrough(instance_name="probe").to_xml()
    deps = [u.get("dependencies") for u in root.find("ModelStructure/Outputs")]
    assert deps == ["2", ""]  # u is variable 2 (1-based); x depends on no input


@pytest.mark.parametrize(
    ("row", "message"),
    [
        (Var("y", "output", "furlong", "bad unit"), "unit"),
        (Var("y", "output", "m", "bad dep", depends_on=("gain",)), "non-inputs"),
    ],
)
def test_extension_rejects_bad_tables(row: Var, message: str):
    root = TRIVIAL.TrivialGain(instance_name="probe").to_xml()
    table = (*TRIVIAL.TrivialGain.VARIABLES[:2], row, TRIVIAL.TrivialGain.VARIABLES[3])
    with pytest.raises(ValueError, match=message):
        extend_model_description(root, table)


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(name="y", causality="output", unit="m", description="d", start=1.0),
        dict(name="u", causality="input", unit="m", description="d"),
        dict(name="p", causality="parameter", unit="m", description="", start=1.0),
        dict(name="p", causality="parameter", unit="m", description="d", start=1.0, min=2, max=1),
        dict(name="a.b", causality="parameter", unit="m", description="d", start=1.0),
    ],
)
def test_var_rejects_inconsistent_rows(kwargs: dict):
    with pytest.raises(ValueError):
        Var(**kwargs)


# ---- running the FMU -----------------------------------------------------------------


def test_simulate_fmu_gives_gain_times_input(fmu: Path, unzipped: Path):
    u = 0.25
    signal = np.array([(0.0, u), (1.0, u)], dtype=[("time", float), ("u", float)])
    result = simulate_fmu(
        str(unzipped),
        stop_time=0.2,
        step_size=1e-3,
        input=signal,
        start_values={"gain": 3.0},
        output=["y", "x"],
    )
    np.testing.assert_allclose(result["y"], 3.0 * u, rtol=1e-15)
    np.testing.assert_allclose(result["x"], u * result["time"], rtol=1e-12, atol=1e-15)


def test_variable_step_sizes_integrate_exactly(unzipped: Path):
    slave, refs = start_slave(unzipped, "steps")
    steps = [(0.5, 1e-3), (-0.2, 5e-3), (1.0, 2e-2), (0.1, 1e-4)]
    out = _run(slave, refs, steps)
    close_slave(slave)
    assert out[-1][1] == pytest.approx(sum(u * dt for u, dt in steps), rel=1e-14)
    assert [y for y, _ in out] == [2.0 * u for u, _ in steps]


def test_state_rollback_reproduces_outputs(unzipped: Path):
    slave, refs = start_slave(unzipped, "rollback")
    _run(slave, refs, [(0.3, 1e-2)] * 3)
    state = slave.getFMUstate()
    serialized = slave.serializeFMUstate(state)
    future = [(0.7, 1e-2), (-0.4, 3e-2), (0.9, 1e-3)]
    first = _run(slave, refs, future)
    slave.setFMUstate(state)
    second = _run(slave, refs, future)
    slave.setFMUstate(state)  # the same state can be restored twice
    third = _run(slave, refs, future)
    restored = slave.deSerializeFMUstate(serialized)
    slave.setFMUstate(restored)
    fourth = _run(slave, refs, future)
    close_slave(slave, state, restored)
    assert first == second == third == fourth
    assert first[-1][1] != pytest.approx(0.09)  # the internal integral did advance


@pytest.mark.parametrize("logging", [True, False])
def test_invalid_parameter_fails_initialisation_with_an_error_always_logged(
        unzipped: Path, logging: bool):
    """fmi2Error from exitInitializationMode; the message reaches the logger even with
    logging off; the instance keeps finite values and refuses to step."""
    log: list[tuple[int, str]] = []
    with pytest.raises(FMICallException) as failure:
        start_slave(unzipped, "bad", {"gain": -1.0}, log=lambda *entry: log.append(entry),
                    logging=logging)
    assert failure.value.status == fmi2Error
    assert any(status == fmi2Error and "gain = -1.0" in text and "[0, 1000]" in text
               for status, text in log), log


def test_out_of_range_input_fails_the_step_and_keeps_state(unzipped: Path):
    log: list[tuple[int, str]] = []
    slave, refs = start_slave(unzipped, "range", log=lambda *entry: log.append(entry))
    before = _run(slave, refs, [(0.5, 0.1)])[-1]
    slave.setReal([refs["u"]], [5.0])
    with pytest.raises(FMICallException) as failure:
        slave.doStep(0.1, 0.1)
    after_discard = tuple(slave.getReal([refs["y"], refs["x"]]))
    slave.setReal([refs["u"]], [0.5])
    slave.doStep(0.1, 0.1)
    recovered = slave.getReal([refs["x"]])[0]
    close_slave(slave)
    assert failure.value.status == fmi2Error
    assert any(status == fmi2Error and "u = 5" in text for status, text in log), log
    assert after_discard == before
    assert recovered == pytest.approx(0.1)


# ---- other processes and masters -----------------------------------------------------


def test_fmu_runs_in_a_fresh_process_from_its_bundled_files(fmu: Path, tmp_path: Path):
    result = run_fresh(fmu, tmp_path, ("u", [0.0, 1.0], [0.5, 0.5]), ["y", "x"],
                       stop_time=0.01, step_size=1e-3)
    assert result["last"]["y"] == 1.0
    assert result["last"]["x"] == pytest.approx(0.005, rel=1e-12)
    assert Path(result["toggle"]).is_relative_to(Path(result["unzip"], "resources"))  # not dev
    assert not result["host_toggle"]


def test_two_instances_run_in_libcosim(fmu: Path, tmp_path: Path):
    pytest.importorskip("libcosimpy")
    result = run_libcosim(
        tmp_path,
        slaves={"a": fmu, "b": fmu},
        observe={"a": ["y", "x"], "b": ["y", "x"]},
        initial=[("a", "u", 0.25), ("b", "gain", 3.0)],
        connections=[("a", "y", "b", "u")],
    )
    assert result["ok"]
    a, b = result["last"]["a"], result["last"]["b"]
    assert [a["y"], a["x"]] == pytest.approx([0.5, 0.025], rel=1e-12)  # y = 2 u, x = u t
    # b.u = a.y = 0.5 from initialisation on (outputs are valid after init)
    assert [b["y"], b["x"]] == pytest.approx([1.5, 0.05], rel=1e-12)
