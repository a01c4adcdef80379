"""ToggleClamp.fmu: description, agreement with toggle.plant, state, errors, other masters.

The FMU is built once for the module. The reference for every output is
:func:`toggle.plant.plant_outputs` evaluated with numpy at the input-link
motion (x, velocity, acceleration) the FMU reports: the plant is algebraic in
that motion, so the two must agree to rounding (tolerance 1e-9 of each output's
peak; about 1e-11 is observed).
"""

from __future__ import annotations

import math
from dataclasses import fields as dataclass_fields
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
    run_steps,
    slip_along,
    validator_problems,
    variable_table,
)
from hypothesis import given, settings
from hypothesis import strategies as st

from fmu_src.build import DEFAULT_SLAVE
from fmu_src.host import start_slave
from toggle.drive import motor_torque
from toggle.kinematics import stroke_limits
from toggle.params import DYNAMICS_PARAMETERS, Dynamics, dynamics_fields, dynamics_parameters
from toggle.plant import DriveState, PlantOutputs, configure, drive_step, plant_outputs

SLAVE = load_module(DEFAULT_SLAVE, "toggle_clamp_fmu_inproc").ToggleClamp
DOC = Path(__file__).resolve().parents[1] / "docs" / "fmu.md"
OUTPUTS = list(PlantOutputs._fields)
X_OPEN, X_TOGGLE = stroke_limits(configure("chang2021").mechanism.lower)
X_CONTACT = X_TOGGLE - 1e-3  # mold contact 1 mm of crosshead travel before the toggle
DELTA_R8 = 0.3e-3  # m, link 8 too long: the halves differ
MOLD = {"x_contact": X_CONTACT, "delta_r8": DELTA_R8}
IDEAL = {"drive_bandwidth": 0.0}  # the FMU's default is the preset's drive lag
REL = 1e-9  # of each output's peak


@pytest.fixture(scope="module")
def fmu() -> Path:
    return built_fmu("clamp")


@pytest.fixture(scope="module")
def unzipped(fmu: Path, tmp_path_factory: pytest.TempPathFactory):
    """The FMU extracted once."""
    return Path(extract(str(fmu), str(tmp_path_factory.mktemp("unzipped"))))


def _reference(x, v, a, slip=None, before=(), **start) -> PlantOutputs:
    """plant_outputs at the reported motion, with the plant the FMU parameters describe, in
    the slip state ``slip`` (default: carried from rest along the positions ``before`` and
    then the reported path)."""
    errors = {k.removeprefix("delta_"): val for k, val in start.items() if k.startswith("delta_")}
    drive = {k: start[k] for k in ("rotor_inertia", "screw_inertia") if k in start}
    masses = dynamics_fields(start)
    cfg = configure("chang2021", x_contact=start.get("x_contact"), errors=errors, drive=drive,
                    masses=masses)
    if slip is None:
        slip = slip_along([*before, *np.atleast_1d(x)], cfg.asymmetry.slip_distance)[len(before):]
    return plant_outputs(np.asarray(x), np.asarray(v), np.asarray(a), cfg, slip_state=slip)


def _assert_outputs_match(actual: dict, reference: PlantOutputs) -> None:
    for name in OUTPUTS:
        got = np.asarray(actual[name], float)
        want = np.broadcast_to(np.asarray(getattr(reference, name), float), got.shape)
        if name == "mechanical_advantage":  # 1/|q|: ill-conditioned where the thrust ratio q
            got, want = 1.0 / got, 1.0 / want  # nears 0 at the toggle, so compare q itself
        peak = float(np.max(np.abs(want)))
        assert np.all(np.isfinite(got)), name
        np.testing.assert_allclose(got, want, rtol=0, atol=REL * peak + 1e-300, err_msg=name)


def _outputs(slave, refs) -> dict[str, float]:
    return dict(zip(OUTPUTS, slave.getReal([refs[n] for n in OUTPUTS])))


def _run(slave, refs, commands_and_steps, t: float = 0.0) -> list:
    """Set x_cmd, doStep for each (x_cmd, h); the outputs after each step."""
    return run_steps(slave, refs, commands_and_steps, _outputs, t)


def _logger(log: list[tuple[int, str]]):
    return lambda status, text: log.append((status, text))


# ---- model description -----------------------------------------------------------------


def test_fmpy_and_fmutool_find_no_problem(fmu: Path):
    assert validator_problems(fmu) == []


def test_description_has_units_starts_and_structure(fmu: Path):
    md = read_model_description(str(fmu))
    units = {u.name for u in md.unitDefinitions}
    by_name = {v.name: v for v in md.modelVariables}
    assert list(by_name) == [v.name for v in SLAVE.VARIABLES]
    for spec in SLAVE.VARIABLES:
        v = by_name[spec.name]
        assert v.description == spec.description
        if v.type == "Real":
            assert v.unit == spec.unit and v.unit in units
        if spec.causality == "parameter":
            assert (v.initial, v.variability) == ("exact", "fixed")
            assert (v.start if spec.is_string else float(v.start)) == spec.start
        if spec.causality == "output":
            assert v.initial == "calculated" and v.start is None
    assert [v.type for v in md.modelVariables].count("Real") == len(SLAVE.VARIABLES) - 1
    outputs = [v.name for v in SLAVE.VARIABLES if v.causality == "output"]
    assert [u.variable.name for u in md.outputs] == outputs == OUTPUTS
    assert [u.variable.name for u in md.initialUnknowns] == outputs
    assert float(md.defaultExperiment.stepSize) == 1e-3
    assert md.coSimulation.canGetAndSetFMUstate and md.coSimulation.canSerializeFMUstate
    for spec in SLAVE.VARIABLES:  # every Real parameter and input has physical bounds
        if spec.causality != "output" and not spec.is_string:
            v = by_name[spec.name]
            assert float(v.min) <= float(v.start) <= float(v.max), spec.name
    assert (float(by_name["drive_bandwidth"].min), float(by_name["drive_bandwidth"].max)) == (
        0.0, 1e3)
    assert float(by_name["m_platen"].start) == configure("chang2021").dynamics.platen
    assert float(by_name["x_contact"].start) == X_TOGGLE  # no mold


def test_doc_variable_table_matches_the_slave():
    """docs/fmu.md embeds the table generated from VARIABLES (python tests/fmu_support.py)."""
    assert variable_table(SLAVE.VARIABLES) in DOC.read_text()


# ---- a closing stroke in fmpy ----------------------------------------------------------

STROKE_TIME, STOP_TIME = 0.4, 0.6  # s: quintic move from x_open to the toggle, then hold


def _stroke_command() -> np.ndarray:
    t = np.linspace(0.0, STOP_TIME, 601)
    s = np.clip(t / STROKE_TIME, 0.0, 1.0)
    x = X_OPEN + (X_TOGGLE - X_OPEN) * s**3 * (10 - 15 * s + 6 * s**2)
    return np.array(list(zip(t, x)), dtype=[("time", float), ("x_cmd", float)])


def _simulate_stroke(unzipped: Path, **start: float):
    """The stroke with the ideal drive unless ``start`` sets drive_bandwidth."""
    return simulate_fmu(str(unzipped), stop_time=STOP_TIME, step_size=1e-3,
                        input=_stroke_command(),
                        start_values={"x_cmd": X_OPEN, **IDEAL, **start},
                        output=[*OUTPUTS, "x_cmd"])


@pytest.mark.parametrize("bandwidth", [0.0, 20.0])
def test_stroke_outputs_equal_the_library(unzipped: Path, bandwidth: float):
    res = _simulate_stroke(unzipped, drive_bandwidth=bandwidth, **MOLD)
    _assert_outputs_match(res, _reference(res["x"], res["velocity"], res["acceleration"], **MOLD))
    before, after = res["x"] < X_CONTACT - 1e-6, res["x"] > X_CONTACT + 1e-6
    assert np.all(res["clamp_force"][before] == 0) and res["clamp_force"][-1] > 100.0  # N
    assert np.all(res["platen_velocity"][after] == 0)  # the platen stops at the mold
    assert abs(res["asymmetry"][-1]) > 0.1 * DELTA_R8


def test_motor_torque_is_the_drives_with_the_rotor_inertia(unzipped: Path):
    """With other rotor and screw inertias than the preset's, the FMU's motor_torque is
    toggle.drive.motor_torque of its input force and acceleration (the one equation)."""
    inertias = {"rotor_inertia": 3e-4, "screw_inertia": 4e-5}
    res = _simulate_stroke(unzipped, drive_bandwidth=20.0, **MOLD, **inertias)
    _assert_outputs_match(res, _reference(res["x"], res["velocity"], res["acceleration"],
                                          **MOLD, **inertias))
    drive = configure("chang2021", drive=inertias).mechanism.drive
    torque = motor_torque(res["input_force"], drive, res["acceleration"])
    np.testing.assert_allclose(res["motor_torque"], torque, rtol=1e-12, atol=1e-15)
    inertia = motor_torque(0.0, drive, res["acceleration"])
    assert np.max(np.abs(inertia)) > 0.1 * np.max(np.abs(torque))  # the rotor matters here


def test_platen_and_guide_friction_are_the_plants(unzipped: Path):
    """The frictions of the platen's bushings (with its rate strengthening) and of the
    crosshead guide are FMU parameters: the outputs are the plant's with them; the
    platen's is referred to the input by dL/dx, so it adds its value times the velocity
    ratio while the platen moves and nothing once it rests on the mold."""
    frictions = {"platen_friction": 4.0, "platen_rate": 1.8, "guide_friction": 1.5}
    res = _simulate_stroke(unzipped, **MOLD, **frictions)
    _assert_outputs_match(res, _reference(res["x"], res["velocity"], res["acceleration"],
                                          **MOLD, **frictions))
    bare = _simulate_stroke(unzipped, **MOLD)
    np.testing.assert_array_equal(res["x"], bare["x"])
    extra = res["input_force"] - bare["input_force"]
    # the closing stroke, once the slip state (from 0 at rest) has turned over: 1 mm on
    forward = ((res["velocity"] > 1e-3) & (res["x"] > X_OPEN + 1e-3)
               & (res["x"] < X_CONTACT - 1e-4))
    ratio = res["platen_velocity"][forward] / res["velocity"][forward]
    assert forward.sum() > 100 and ratio.max() > 1.0
    rate = 1 + 1.8 * np.log1p(res["platen_velocity"][forward] / 1e-3)  # the rate law
    np.testing.assert_allclose(extra[forward], 4.0 * ratio * rate + 1.5, rtol=1e-3)


def test_ideal_drive_puts_the_input_link_at_the_command(unzipped: Path):
    res = _simulate_stroke(unzipped, **MOLD)
    np.testing.assert_array_equal(res["x"], res["x_cmd"])
    # velocity: slope of the parabola through the last three commands, within [0, 2 x mean
    # slope of the step] (or [2 x, 0] backwards)
    x, h = res["x"], 1e-3
    rate = np.diff(x)[1:] / h
    parabola = (3 * x[2:] - 4 * x[1:-1] + x[:-2]) / (2 * h)
    want = np.clip(parabola, np.minimum(0, 2 * rate), np.maximum(0, 2 * rate))
    np.testing.assert_allclose(res["velocity"][2:], want, rtol=1e-9, atol=1e-12)
    assert np.mean(want == parabola) > 0.6  # the limit acts at the ends of the stroke only
    assert res["x"][-1] == pytest.approx(X_TOGGLE, abs=1e-12)


def test_drive_with_bandwidth_lags_then_settles(unzipped: Path):
    res = _simulate_stroke(unzipped, drive_bandwidth=20.0, drive_damping=0.7, **MOLD)
    error = res["x_cmd"] - res["x"]
    moving = res["time"] < STROKE_TIME
    assert np.max(error[moving]) > 1e-3  # m: a 20 Hz drive trails a 0.4 s stroke by mm
    assert abs(error[-1]) < 1e-9 and abs(res["velocity"][-1]) < 1e-6


# ---- state, step sizes, errors (in-process fmpy) ------------------------------------------

APPROACH = [(X_OPEN + k * 2.5e-3, 5e-3) for k in range(1, 21)]  # ends 5 mm before the toggle
FUTURE = [(X_CONTACT + 2e-4, 1e-3), (X_TOGGLE, 4e-3), (X_TOGGLE, 2e-2), (X_TOGGLE, 2e-4),
          (X_CONTACT, 1e-2)]


def test_state_rollback_reproduces_outputs(unzipped: Path):
    slave, refs = start_slave(unzipped, "rollback", {"drive_bandwidth": 50.0, **MOLD})
    _run(slave, refs, APPROACH)
    state = slave.getFMUstate()
    serialized = slave.serializeFMUstate(state)
    first = _run(slave, refs, FUTURE)
    slave.setFMUstate(state)
    second = _run(slave, refs, FUTURE)
    slave.setFMUstate(state)  # the same state restores twice
    third = _run(slave, refs, FUTURE)
    restored = slave.deSerializeFMUstate(serialized)
    slave.setFMUstate(restored)
    fourth = _run(slave, refs, FUTURE)
    close_slave(slave, state, restored)
    assert first == second == third == fourth
    assert first[0]["velocity"] != 0 and max(r["clamp_force"] for r in first) > 0  # it moved


@pytest.mark.parametrize("bandwidth", [0.0, 20.0])
def test_variable_step_sizes_follow_the_drive_model(unzipped: Path, bandwidth: float):
    steps = [*APPROACH[:3], (X_OPEN + 1e-2, 1e-3), (X_OPEN + 2e-2, 3e-2),
             (X_CONTACT - 2e-3, 5e-2), *FUTURE]
    slave, refs = start_slave(unzipped, "steps", {"drive_bandwidth": bandwidth,
                                                  "x_cmd": X_OPEN, **MOLD})
    out = _run(slave, refs, steps)
    close_slave(slave)
    drive = DriveState.at_rest(X_OPEN)
    for (x_cmd, h), got in zip(steps, out, strict=True):
        drive = drive_step(drive, x_cmd, h, bandwidth, 0.7)
        assert (got["x"], got["velocity"], got["acceleration"]) == pytest.approx(
            tuple(drive[:3]), rel=1e-12, abs=1e-15)
    columns = {n: [o[n] for o in out] for n in OUTPUTS}
    _assert_outputs_match(columns, _reference(columns["x"], columns["velocity"],
                                              columns["acceleration"], before=[X_OPEN], **MOLD))


@pytest.mark.parametrize(
    ("start", "named"),
    [
        ({"delta_r4b": 1.0}, "r4b"),  # link 4 cannot close: the geometry does not assemble
        ({"preset": "no_such_clamp"}, "no_such_clamp"),
        ({"x_contact": -1.0}, "x_contact"),
        ({"m_platen": math.inf}, "platen"),
        ({"mu": math.inf}, "mu"),
        ({"delta_r8": math.nan}, "delta_r8"),
        ({"x_cmd": 0.5}, "x_cmd = 0.5 m is outside"),
        ({"delta_r7b": 1.0}, "delta_r7b"),
        ({"drive_bandwidth": 10.0, "drive_damping": -1.0}, "drive_damping"),
        ({"mu": -0.2}, "mu"),
        ({"m_platen": float("nan")}, "m_platen"),
        ({"rotor_inertia": -1e-5}, "rotor_inertia"),
        ({"screw_inertia": math.inf}, "screw_inertia"),
    ],
)
def test_invalid_parameter_fails_initialisation_with_the_parameter_named(unzipped: Path, start,
                                                                          named):
    """fmi2Error from exitInitializationMode, and the message reaches the logger although
    logging is off (the default of fmpy, libcosim and the Compliance Checker)."""
    log: list[tuple[int, str]] = []
    with pytest.raises(FMICallException) as refused:
        start_slave(unzipped, "bad", start, log=_logger(log), logging=False)
    errors = [text for status, text in log if status == fmi2Error]
    assert refused.value.status == fmi2Error
    assert errors and errors[0].startswith("initialisation failed") and named in errors[0], log


@pytest.mark.parametrize("x_cmd", [0.09, -0.09, math.nan])
def test_input_outside_the_range_fails_the_step_and_keeps_working(unzipped: Path, x_cmd):
    log: list[tuple[int, str]] = []
    slave, refs = start_slave(unzipped, "range", {"x_cmd": X_OPEN, **MOLD, **IDEAL},
                              log=_logger(log))
    before = _run(slave, refs, APPROACH[:2])[-1]
    slave.setReal([refs["x_cmd"]], [x_cmd])
    with pytest.raises(FMICallException) as refused:
        slave.doStep(1e-2, 5e-3)
    after_discard = _outputs(slave, refs)
    recovered = _run(slave, refs, APPROACH[2:4], t=1e-2)
    close_slave(slave)
    assert refused.value.status == fmi2Error
    assert any(status == fmi2Error and "assemblable range" in text for status, text in log), log
    assert after_discard == before
    assert recovered[0]["velocity"] == pytest.approx(2.5e-3 / 5e-3)  # from the kept state
    columns = {n: [o[n] for o in recovered] for n in OUTPUTS}
    path = [X_OPEN, APPROACH[0][0], APPROACH[1][0]]  # the failed step moved nothing
    _assert_outputs_match(columns, _reference(columns["x"], columns["velocity"],
                                              columns["acceleration"], before=path, **MOLD))


@settings(max_examples=20, deadline=None)
@given(
    st.lists(st.tuples(st.floats(-0.1, 0.1), st.sampled_from([1e-5, 1e-3, 0.02])), min_size=1,
             max_size=6),
    st.sampled_from([0.0, 5.0]),
)
def test_outputs_are_finite_for_any_command_sequence(unzipped: Path, commands, bandwidth):
    """Every step either succeeds with finite outputs or fails leaving them unchanged."""
    slave, refs = start_slave(unzipped, "any", {"drive_bandwidth": bandwidth, "x_cmd": X_OPEN,
                                                **MOLD})
    t, previous = 0.0, _outputs(slave, refs)
    try:
        for x_cmd, h in commands:
            slave.setReal([refs["x_cmd"]], [x_cmd])
            try:
                slave.doStep(t, h)
                t += h
            except FMICallException as refused:
                assert refused.status == fmi2Error
                assert _outputs(slave, refs) == previous
            previous = _outputs(slave, refs)
            assert all(math.isfinite(v) for v in previous.values())
    finally:
        close_slave(slave)


# ---- other processes and masters -----------------------------------------------------------


def test_fmu_runs_in_a_fresh_process_from_its_bundled_files(fmu: Path, tmp_path: Path):
    signal = ("x_cmd", [0.0, 0.04, 1.0], [X_OPEN, X_CONTACT + 2e-4, X_CONTACT + 2e-4])
    result = run_fresh(fmu, tmp_path, signal, OUTPUTS, stop_time=0.05, step_size=1e-3,
                       start_values={"x_cmd": X_OPEN, **MOLD, **IDEAL})
    last = result["last"]
    _assert_outputs_match(last, _reference(last["x"], last["velocity"], last["acceleration"], 1.0,
                                           **MOLD))
    assert last["clamp_force"] > 0
    assert Path(result["toggle"]).is_relative_to(Path(result["unzip"], "resources"))  # not dev


def test_two_clamps_and_a_ramp_run_in_libcosim(fmu: Path, tmp_path: Path):
    """Two ToggleClamp instances (nominal and link 8 + 0.5 mm) follow one ramp FMU."""
    pytest.importorskip("libcosimpy")
    ramp = built_fmu("trivial")  # x = integral of u: the command ramp
    observed = ["x", "velocity", "acceleration", "input_force", "asymmetry", "platen_position"]
    result = run_libcosim(
        tmp_path,
        slaves={"ramp": ramp, "nominal": fmu, "long_r8": fmu},
        observe={"ramp": ["x"], "nominal": observed, "long_r8": observed},
        initial=[("ramp", "u", 0.1), ("nominal", "x_cmd", 0.0), ("long_r8", "x_cmd", 0.0),
                 ("long_r8", "delta_r8", 0.5e-3), ("nominal", "drive_bandwidth", 0.0),
                 ("long_r8", "drive_bandwidth", 0.0)],
        connections=[("ramp", "x", "nominal", "x_cmd"), ("ramp", "x", "long_r8", "x_cmd")],
        stop_time=0.3,
    )
    assert result["ok"]
    nominal, long_r8 = result["last"]["nominal"], result["last"]["long_r8"]
    assert nominal["x"] == long_r8["x"] == pytest.approx(0.03 - 1e-4, rel=1e-12)  # 1 step late
    assert nominal["velocity"] == pytest.approx(0.1, rel=1e-9)
    for last, start in [(nominal, {}), (long_r8, {"delta_r8": 0.5e-3})]:
        ref = _reference(last["x"], last["velocity"], last["acceleration"], 1.0, **start)
        for name in observed:
            assert last[name] == pytest.approx(float(getattr(ref, name)), rel=REL, abs=1e-300)
    assert nominal["asymmetry"] == 0 and long_r8["asymmetry"] > 0.25e-3
    assert long_r8["input_force"] != pytest.approx(nominal["input_force"], rel=1e-6)


def test_every_dynamics_field_is_a_parameter_of_the_fmus_by_one_name():
    """A [dynamics] field added without an FMU parameter would be silently fixed at its
    preset value in both FMUs; the two name maps are each other's inverse."""
    fields = {f.name: 1.0 + i for i, f in enumerate(dataclass_fields(Dynamics))}
    assert dynamics_fields(dynamics_parameters(fields)) == fields
    assert set(dynamics_parameters(fields)) == set(DYNAMICS_PARAMETERS)


@pytest.mark.parametrize("bandwidth", [0.0, 1e3])  # Hz: the declared range's corners
@pytest.mark.parametrize("damping", [0.0, 10.0])
def test_the_drive_at_rest_at_the_corners_of_its_range_at_any_step(unzipped: Path, bandwidth,
                                                                   damping):
    """1000 Hz with damping 10 at a 1 s step rejected every step before (cosh overflowed):
    at rest, steps of 1 us to 1 s pass, the input link stays, every output is finite."""
    slave, refs = start_slave(unzipped, "corner", {"drive_bandwidth": bandwidth,
                                                   "drive_damping": damping, "x_cmd": X_OPEN})
    try:
        rows = _run(slave, refs, [(X_OPEN, h) for h in (1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 0.1, 1.0)])
    finally:
        close_slave(slave)
    assert all(row["x"] == X_OPEN and row["velocity"] == 0.0 for row in rows)
    assert all(math.isfinite(v) for row in rows for v in row.values())
