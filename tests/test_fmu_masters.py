"""build/ToggleClamp.fmu driven the way other masters drive it (issue 15).

A C host compiled here (dlopen, no Python; PATH and VIRTUAL_ENV only), fmpy's
high-level and low-level APIs in fresh processes, the fmpy command line, and
the FMI rules a strict master relies on: error statuses and messages whatever
the logging state, variable communication steps, serialised states moved
between processes, refused crafted states, fixed parameters and outputs that
cannot be set. ``FMU_HOST_RUNS=20`` repeats the C host 20 times.
"""

from __future__ import annotations

import json
import os
import pickle
import shutil
import struct
import subprocess
import sys
import textwrap
import zlib
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import fmi2Error, fmi2OK, fmi2Terminated
from fmu_support import BARE_ENV, built_fmu, compile_c_host, load_module
from fmu_support import run_c_host as _run_host

from fmu_src.build import DEFAULT_SLAVE, PACKAGE_DIR
from fmu_src.host import start_slave
from toggle.kinematics import stroke_limits
from toggle.plant import DriveState, configure, drive_step, plant_outputs

pytestmark = pytest.mark.real_time

X_OPEN, X_TOGGLE = stroke_limits(configure("chang2021").mechanism.lower)
X_CONTACT = X_TOGGLE - 1e-3
OUTPUTS = ["x", "velocity", "acceleration", "platen_position", "input_force", "clamp_force",
           "asymmetry", "motor_torque"]
IDEAL = {"drive_bandwidth": 0.0}  # the FMU's default is the preset's drive lag
DEFAULT_BANDWIDTH = next(v.start for v in load_module(
    DEFAULT_SLAVE, "toggle_clamp_fmu_masters").ToggleClamp.VARIABLES if v.name == "drive_bandwidth")
HEAD = 20  # bytes before a state's payload: magic, version, phase, length


@pytest.fixture(scope="module")
def fmu() -> Path:
    return built_fmu("clamp")


@pytest.fixture(scope="module")
def unzipped(fmu: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return Path(extract(str(fmu), str(tmp_path_factory.mktemp("unzipped"))))


def _refs(unzipped: Path) -> dict[str, int]:
    return {v.name: v.valueReference for v in read_model_description(str(unzipped)).modelVariables}


def _script(code: str, *args: str, cwd: Path) -> dict:
    """Run ``code`` in a fresh Python; it must exit 0 and print JSON last."""
    run = subprocess.run([sys.executable, "-c", textwrap.dedent(code), *args], cwd=cwd,
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    return json.loads(run.stdout.strip().splitlines()[-1])


# ---- a C master -------------------------------------------------------------------------


@pytest.fixture(scope="module")
def c_host(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return compile_c_host(tmp_path_factory.mktemp("host"))


def test_c_host_loads_the_fmu_twice_and_exits_cleanly(c_host: Path, unzipped: Path):
    """instantiate → init → 500 steps → terminate → free → dlclose, twice in one process,
    then exit: status 0 every run (pythonfmu alone crashed at exit in every C host)."""
    drive = DriveState.at_rest(-3.4386e-3)
    for k in range(1, 501):  # the host's ramp, in the same floating-point operations, through
        drive = drive_step(drive, -3.4386e-3 + (0.04 + 3.4386e-3) * k / 500.0, 1e-3,
                       DEFAULT_BANDWIDTH, 0.7)  # the default drive lag
    want = float(plant_outputs(drive.x, drive.v, drive.a, configure("chang2021")).input_force)
    for _ in range(int(os.environ.get("FMU_HOST_RUNS", "2"))):
        run = _run_host(c_host, unzipped, 2.5, loads=2)
        assert run.returncode == 0, run.stderr
        lines = [line.split() for line in run.stdout.splitlines()]
        assert [int(status) for status, _ in lines] == [fmi2OK, fmi2OK]
        assert [float(f) for _, f in lines] == pytest.approx([want, want], rel=1e-12)


def test_c_host_gets_an_error_and_its_message_with_logging_off(c_host: Path, unzipped: Path):
    run = _run_host(c_host, unzipped, -3.0, loads=1)
    assert run.returncode == 0, run.stderr
    assert run.stdout.split()[0] == str(fmi2Error)
    assert "[3] initialisation failed: parameter m_platen = -3.0 kg is outside" in run.stderr


# ---- fmpy: several simulations, several versions, one process ------------------------------

SIMULATE = """
    import json, sys
    import numpy as np
    from fmpy import simulate_fmu
    runs = []
    for fmu, start in json.loads(sys.argv[1]):
        t = np.linspace(0.0, 0.3, 4)
        x = np.minimum(-3.4386e-3 + 0.2 * t, 0.049)
        signal = np.array(list(zip(t, x)), dtype=[("time", float), ("x_cmd", float)])
        res = simulate_fmu(fmu, stop_time=0.3, step_size=1e-3, input=signal,
                           start_values={"x_cmd": -3.4386e-3, **start},
                           output=["input_force", "asymmetry"])
        runs.append({k: res[k].tolist() for k in ("input_force", "asymmetry")})
    print(json.dumps({"runs": runs, "host_toggle": "toggle" in sys.modules}))
"""
STARTS = [{"m_platen": 2.5}, {"m_platen": 10.0, "delta_r8": 0.5e-3}, {"m_platen": 2.5}]


def test_simulate_fmu_three_times_in_one_process_equals_three_fresh_processes(fmu: Path,
                                                                                tmp_path: Path):
    together = _script(SIMULATE, json.dumps([[str(fmu), s] for s in STARTS]), cwd=tmp_path)
    alone = [_script(SIMULATE, json.dumps([[str(fmu), s]]), cwd=tmp_path)["runs"][0]
             for s in STARTS[:2]]
    assert together["runs"] == [alone[0], alone[1], alone[0]]  # bit for bit
    assert together["runs"][0]["input_force"] != together["runs"][1]["input_force"]
    assert not together["host_toggle"]


def test_two_versions_of_the_project_run_side_by_side_in_one_process(fmu: Path, tmp_path: Path):
    """A copy of the project whose plant reports asymmetry + 1 m, built into a second FMU:
    each FMU computes with its own code, in either order."""
    copy = tmp_path / "project"
    shutil.copytree(PACKAGE_DIR, copy / "toggle", ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copytree(PACKAGE_DIR.parent / "fmu_src", copy / "fmu_src")
    plant = copy / "toggle" / "plant.py"
    text = plant.read_text()
    assert "asymmetry=terms[1][0] - terms[0][0]," in text
    plant.write_text(text.replace("asymmetry=terms[1][0] - terms[0][0],",
                                  "asymmetry=terms[1][0] - terms[0][0] + 1.0,"))
    other = _script(f"""
        import json, sys
        sys.path.insert(0, {str(copy)!r})
        from fmu_src.build import build_fmu
        print(json.dumps({{"fmu": str(build_fmu({str(tmp_path / 'other')!r}))}}))
    """, cwd=copy)["fmu"]
    runs = _script(SIMULATE, json.dumps([[str(fmu), {}], [other, {}], [str(fmu), {}]]),
                   cwd=tmp_path)["runs"]
    assert runs[0] == runs[2]
    assert np.allclose(np.subtract(runs[1]["asymmetry"], runs[0]["asymmetry"]), 1.0,
                       rtol=0, atol=1e-12)
    assert runs[1]["input_force"] == runs[0]["input_force"]


def test_fmpy_command_line_refuses_a_bad_parameter_and_names_it(fmu: Path, tmp_path: Path):
    run = subprocess.run([str(Path(sys.executable).parent / "fmpy"), "simulate", str(fmu),
                          "--start-values", "m_platen", "-3"], capture_output=True, text=True,
                         cwd=tmp_path, timeout=120)
    assert run.returncode != 0
    assert "m_platen = -3.0 kg is outside [0, 250] kg" in run.stdout + run.stderr


# ---- variable steps -------------------------------------------------------------------------


def _ramp_up(slave, refs, steps) -> dict[float, np.ndarray]:
    """x_cmd = x_open + 0.25 t^2 (constant acceleration 0.5 m/s^2) at the given steps: its
    value, velocity and acceleration at each step's start (fmi2SetRealInputDerivatives)."""
    t, rows = 0.0, {}
    for h in steps:
        slave.setReal([refs["x_cmd"]], [X_OPEN + 0.25 * t**2])
        slave.setRealInputDerivatives([refs["x_cmd"]] * 2, [1, 2], [0.5 * t, 0.5])
        slave.doStep(t, h)
        t += h
        rows[round(t, 9)] = np.array(slave.getReal([refs[n] for n in OUTPUTS]))
    return rows


@pytest.mark.parametrize("bandwidth", [0.0, 30.0])
def test_variable_steps_give_the_fixed_step_results(unzipped: Path, bandwidth: float):
    """Alternating 0.5/1.5 ms steps against 1 ms steps, compared where both land (every
    2 ms): equal to 1e-6 of each output's peak (the command between communication points
    is the master's polynomial, exact for this command)."""
    results = []
    for steps in ([1e-3] * 300, [0.5e-3, 1.5e-3] * 150):
        slave, refs = start_slave(unzipped, "steps", {"x_cmd": X_OPEN, "x_contact": X_CONTACT,
                                                      "drive_bandwidth": bandwidth})
        results.append(_ramp_up(slave, refs, steps))
        slave.terminate()
        slave.freeInstance()
    common = sorted(set(results[0]) & set(results[1]))
    fixed, varied = (np.array([r[t] for t in common]) for r in results)
    assert len(common) == 150
    peak = np.abs(fixed).max(axis=0)
    assert np.all(np.abs(varied - fixed) <= 1e-6 * peak + 1e-15)
    if bandwidth == 0.0:
        assert fixed[:, OUTPUTS.index("acceleration")] == pytest.approx(0.5, rel=1e-9)


# ---- FMU state ------------------------------------------------------------------------------

STATE_RUN = """
    import json, sys
    from pathlib import Path
    from fmpy import extract
    from fmu_src.host import start_slave
    spec = json.loads(sys.argv[1])
    folder = extract(spec["fmu"])
    slave, refs = start_slave(Path(folder), "state", spec["start"])
    outputs = [refs[n] for n in spec["outputs"]]
    def steps(first, count):
        rows = []
        for k in range(first, first + count):
            slave.setReal([refs["x_cmd"]], [spec["x0"] + 4e-5 * k])
            slave.doStep(k * 1e-3, 1e-3 if k % 2 else 0.6e-3)
            rows.append([v.hex() for v in slave.getReal(outputs)])
        return rows
    if spec["state"] is None:
        steps(1, 200)
        state = slave.getFMUstate()
        Path(spec["file"]).write_bytes(bytes(slave.serializeFMUstate(state)))
    else:
        state = slave.deSerializeFMUstate(Path(spec["file"]).read_bytes())
        slave.setFMUstate(state)
    print(json.dumps({"next": steps(201, 1000)}))
"""


def test_a_state_restored_in_a_fresh_process_continues_bit_for_bit(fmu: Path, tmp_path: Path):
    """The state carries the parameters: a nominal instance in another process that
    restores it computes the erroneous clamp's next 1000 steps to the last bit."""
    spec = {"fmu": str(fmu), "outputs": OUTPUTS, "x0": X_OPEN, "file": str(tmp_path / "s.bin"),
            "start": {"x_cmd": X_OPEN, "delta_r8": 0.5e-3, "x_contact": X_CONTACT,
                      "drive_bandwidth": 50.0, "m_platen": 4.0}}
    original = _script(STATE_RUN, json.dumps({**spec, "state": None}), cwd=tmp_path)
    restored = _script(STATE_RUN, json.dumps({**spec, "state": "load", "start": {}}),
                       cwd=tmp_path)
    assert restored["next"] == original["next"]
    assert float.fromhex(original["next"][-1][OUTPUTS.index("asymmetry")]) != 0.0


def _state_bytes(slave) -> bytes:
    state = slave.getFMUstate()
    data = bytes(slave.serializeFMUstate(state))
    slave.freeFMUstate(state)
    return data


def _with_crc(body: bytes) -> bytes:
    return body + struct.pack("<I", zlib.crc32(body))


def _crafted(good: bytes) -> dict[str, bytes]:
    payload = json.loads(good[HEAD:-4])
    payload["values"]["m_platen"] = "__import__('os').system('true')"
    text = json.dumps(payload).encode()
    return {
        "pickle": pickle.dumps({"values": {}}),
        "truncated": good[:-10],
        "flipped": good[:40] + bytes([good[40] ^ 1]) + good[41:],
        "wrong version": _with_crc(good[:8] + struct.pack("<I", 99) + good[12:-4]),
        "string for a number": _with_crc(good[:HEAD - 4] + struct.pack("<I", len(text)) + text),
    }


def test_crafted_or_damaged_states_are_refused_with_an_error(unzipped: Path):
    log: list[tuple[int, str]] = []
    slave, refs = start_slave(unzipped, "crafted", {"x_cmd": X_OPEN, **IDEAL},
                              log=lambda status, text: log.append((status, text)), logging=False)
    try:
        good = _state_bytes(slave)
        for name, data in _crafted(good).items():
            with pytest.raises(FMICallException) as refused:
                state = slave.deSerializeFMUstate(data)
                slave.setFMUstate(state)  # reached only by content that passes the checks
            assert refused.value.status == fmi2Error, name
        assert len([s for s, text in log if s == fmi2Error and "state refused" in text]) == 5, log
        slave.setReal([refs["x_cmd"]], [X_OPEN + 1e-4])
        slave.doStep(0.0, 1e-3)  # the instance is intact
        assert slave.getReal([refs["x"]])[0] == X_OPEN + 1e-4
    finally:
        slave.terminate()
        slave.freeInstance()


# ---- FMI rules ------------------------------------------------------------------------------


def test_fixed_parameters_outputs_and_unknown_references_cannot_be_set(unzipped: Path):
    log: list[tuple[int, str]] = []
    slave, refs = start_slave(unzipped, "rules", {"x_cmd": X_OPEN, **IDEAL},
                              log=lambda status, text: log.append((status, text)), logging=False)
    try:
        for vr, value in ((refs["m_platen"], 9.0), (refs["input_force"], 1.0), (9999, 1.0)):
            with pytest.raises(FMICallException) as refused:
                slave.setReal([vr], [value])
            assert refused.value.status == fmi2Error
        with pytest.raises(FMICallException) as refused:
            slave.getReal([9999])
        assert refused.value.status == fmi2Error
        assert slave.getReal([refs["m_platen"]])[0] == 2.5  # unchanged
        messages = " | ".join(text for _, text in log)
        assert "m_platen is a fixed parameter" in messages
        assert "input_force is an output" in messages
        assert "value reference 9999" in messages
        slave.setReal([refs["x_cmd"]], [X_OPEN + 1e-4])
        slave.doStep(0.0, 1e-3)  # still usable: no fmi2Fatal, no freed instance
    finally:
        slave.terminate()
        slave.freeInstance()


def test_a_rejected_step_does_not_terminate_the_simulation(unzipped: Path):
    slave, refs = start_slave(unzipped, "terminated", {"x_cmd": X_OPEN, **IDEAL})
    try:
        slave.setReal([refs["x_cmd"]], [0.5])  # far outside the stroke
        with pytest.raises(FMICallException) as refused:
            slave.doStep(0.0, 1e-3)
        assert refused.value.status == fmi2Error
        slave.setReal([refs["x_cmd"]], [X_OPEN + 1e-4])
        slave.doStep(0.0, 1e-3)
        assert slave.getBooleanStatus(fmi2Terminated) is False
        assert slave.getReal([refs["x"]])[0] == X_OPEN + 1e-4
    finally:
        slave.terminate()
        slave.freeInstance()


def test_outputs_in_initialization_mode_follow_the_values_set(unzipped: Path):
    md = read_model_description(str(unzipped))
    refs = _refs(unzipped)
    from fmpy.fmi2 import FMU2Slave

    slave = FMU2Slave(guid=md.guid, unzipDirectory=str(unzipped),
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName="init")
    slave.instantiate(loggingOn=False)
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    x = X_TOGGLE - 1e-4
    slave.setReal([refs["x_cmd"], refs["x_contact"]], [x, X_CONTACT])
    force, clamp = slave.getReal([refs["input_force"], refs["clamp_force"]])
    slave.exitInitializationMode()
    after = slave.getReal([refs["input_force"], refs["clamp_force"]])
    slave.terminate()
    slave.freeInstance()
    want = plant_outputs(x, 0.0, 0.0, configure("chang2021", x_contact=X_CONTACT))
    assert (force, clamp) == pytest.approx((float(want.input_force), float(want.clamp_force)),
                                           rel=1e-12)
    assert clamp > 0 and list(after) == [force, clamp]


@pytest.mark.parametrize(("logging", "categories", "delivered"),
                         [(True, [], True), (True, ["logAll"], True),
                          (True, ["logStatusError"], False), (False, [], False)])
def test_log_categories_filter_information_messages(unzipped: Path, logging: bool,
                                                    categories: list[str], delivered: bool):
    md = read_model_description(str(unzipped))
    from fmpy.fmi2 import FMU2Slave

    from fmu_src.host import log_callbacks

    log: list[tuple[int, str]] = []
    slave = FMU2Slave(guid=md.guid, unzipDirectory=str(unzipped),
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName="log")
    callbacks = log_callbacks(lambda status, text: log.append((status, text)))
    slave.instantiate(callbacks=callbacks, loggingOn=logging)
    if categories:
        slave.setDebugLogging(logging, categories)
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    slave.exitInitializationMode()
    slave.terminate()
    slave.freeInstance()
    infos = [text for status, text in log if status == fmi2OK]
    assert bool(infos) == delivered, log
    if delivered:
        assert any("initialised: preset = 'chang2021'" in text for text in infos), infos


@pytest.mark.parametrize("closing", [False, True])
def test_fmi_compliance_checker_finds_no_problem(fmu: Path, tmp_path: Path, closing: bool):
    """The default experiment, and a closing stroke from an input file, in the checker
    built from modelica-tools/FMUComplianceChecker (FMUCHECK=path; docs/fmu.md), run with
    PATH and VIRTUAL_ENV only: no LD_PRELOAD, no PYTHONPATH."""
    checker = os.environ.get("FMUCHECK")
    if not checker:
        pytest.skip("set FMUCHECK to an fmuCheck.linux64 built from "
                    "modelica-tools/FMUComplianceChecker (see docs/fmu.md)")
    log, out, inputs = tmp_path / "check.log", tmp_path / "out.csv", tmp_path / "in.csv"
    t = np.linspace(0.0, 1.0, 1001)
    s = np.clip(t / 0.4, 0.0, 1.0)  # smoothstep from x_open to the toggle in 0.4 s, hold
    x = X_OPEN + (X_TOGGLE - X_OPEN) * s**2 * (3 - 2 * s)
    inputs.write_text('"time","x_cmd"\n' + "".join(f"{float(a)!r},{float(b)!r}\n"
                                                   for a, b in zip(t, x)))
    args = ["-h", "1e-3", "-s", "1.0", "-i", str(inputs)] if closing else []
    run = subprocess.run([checker, "-l", "3", "-e", str(log), "-o", str(out), *args, str(fmu)],
                         capture_output=True, text=True, timeout=300, env=BARE_ENV)
    text = log.read_text()
    assert run.returncode == 0, text
    assert "0 warning(s) and error(s)" in text and "0 Warning(s)" in text and "0 Error(s)" in text
    result = np.genfromtxt(out, delimiter=",", names=True)
    drive = DriveState.at_rest(X_OPEN)  # the default drive lag, x_cmd(t) set before each step
    for x_cmd in x[:-1] if closing else ():
        drive = drive_step(drive, float(x_cmd), 1e-3, DEFAULT_BANDWIDTH, 0.7)
    assert result["x"][-1] == pytest.approx(drive.x, abs=1e-9)
    assert result["x"][-1] == pytest.approx(X_TOGGLE if closing else X_OPEN, abs=1e-4)


def test_one_fmu_per_preset_with_its_values_as_start_values(tmp_path: Path,
                                                           capsys: pytest.CaptureFixture):
    from toggle_cli import main

    assert main(["build-fmu", "--preset", "lin2003_sm55", "--out", str(tmp_path)]) == 0
    assert capsys.readouterr().out == f"results in {tmp_path}/ (ToggleClamp.fmu)\n"
    md = read_model_description(str(tmp_path / "ToggleClamp.fmu"))
    start = {v.name: v.start for v in md.modelVariables}
    dyn = configure("lin2003_sm55").dynamics
    assert start["preset"] == "lin2003_sm55" and float(start["m_platen"]) == dyn.platen
    assert main(["build-fmu", "--preset", "li_micro", "--out", str(tmp_path / "li")]) == 2
    assert "no [dynamics] section" in capsys.readouterr().err
