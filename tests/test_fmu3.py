"""FMI 3.0 details of the native FMU (issue 39): a NULL logger, the time in the saved
state, Event Mode and the step-finished flags as the standard has them, and fmusim
(Reference FMUs, FMUSIM=path, docs/fmu.md) on every FMI 3.0 build."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi3 import (
    FMU3Model,
    FMU3Slave,
    fmi3IntermediateUpdateCallback,
    fmi3LogMessageCallback,
)
from native_support import native_build

TIME_VR = 1001


def _slave(folder: str, md, logger: bool) -> FMU3Slave:
    """An FMI 3.0 Co-Simulation instance, its logMessage NULL unless ``logger``."""
    slave = FMU3Slave(guid=md.guid, unzipDirectory=folder,
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName="s")
    if logger:
        slave.instantiate()
    else:
        slave.component = slave.fmi3InstantiateCoSimulation(
            b"s", md.guid.encode(), b"", False, False, False, False, None, 0, None,
            fmi3LogMessageCallback(), fmi3IntermediateUpdateCallback())
        assert slave.component, "a NULL logMessage was refused"
    return slave


@pytest.fixture(scope="module")
def cs(tmp_path_factory):
    folder = extract(str(native_build(3, "cs")), str(tmp_path_factory.mktemp("fmi3cs")))
    return folder, read_model_description(folder)


def test_a_null_logger_is_accepted_and_errors_still_return_error(cs):
    folder, md = cs
    refs = {v.name: v.valueReference for v in md.modelVariables}
    slave = _slave(folder, md, logger=False)
    slave.enterInitializationMode(startTime=0.0)
    slave.exitInitializationMode()
    slave.doStep(0.0, 1e-3)
    slave.setFloat64([refs["x_cmd"]], [1.0])  # outside the assemblable range
    with pytest.raises(FMICallException):  # an error, logged to nobody, no crash
        slave.doStep(1e-3, 1e-3)
    slave.terminate()
    slave.freeInstance()


def test_the_saved_state_holds_the_time(cs):
    """After restoring the state taken at t = 0.05 s, time reads 0.05 s again (also through
    serialisation), and the next step's outputs are those of the first run."""
    folder, md = cs
    refs = {v.name: v.valueReference for v in md.modelVariables}
    slave = _slave(folder, md, logger=True)
    slave.enterInitializationMode(startTime=0.0)
    slave.exitInitializationMode()
    t = 0.0
    for _ in range(50):
        slave.setFloat64([refs["x_cmd"]], [-3.4386e-3 + 0.2 * t * t])
        slave.doStep(t, 1e-3)
        t += 1e-3
    state = slave.getFMUState()
    saved = slave.serializeFMUState(state)
    assert slave.getFloat64([TIME_VR])[0] == pytest.approx(0.05, abs=1e-12)
    first = []
    for _ in range(50):
        slave.setFloat64([refs["x_cmd"]], [-3.4386e-3 + 0.2 * t * t])
        slave.doStep(t, 1e-3)
        t += 1e-3
        first.append(slave.getFloat64([refs["input_force"]])[0])
    assert slave.getFloat64([TIME_VR])[0] == pytest.approx(0.10, abs=1e-12)
    for restore in (state, slave.deserializeFMUState(saved)):
        slave.setFMUState(restore)
        assert slave.getFloat64([TIME_VR])[0] == pytest.approx(0.05, abs=1e-12)
        t, again = 0.05, []
        for _ in range(50):
            slave.setFloat64([refs["x_cmd"]], [-3.4386e-3 + 0.2 * t * t])
            slave.doStep(t, 1e-3)
            t += 1e-3
            again.append(slave.getFloat64([refs["input_force"]])[0])
        np.testing.assert_allclose(again, first, rtol=1e-12)
    slave.terminate()
    slave.freeInstance()


def test_step_flags_and_no_event_mode_in_co_simulation(cs):
    """fmi3DoStep reports no event, no termination, no early return and the step's end as
    the last successful time (its start after a rejected step); hasEventMode is false, so
    fmi3EnterEventMode and eventModeUsed are refused."""
    folder, md = cs
    assert md.coSimulation.hasEventMode is not True
    refs = {v.name: v.valueReference for v in md.modelVariables}
    slave = _slave(folder, md, logger=True)
    slave.enterInitializationMode(startTime=0.0)
    slave.exitInitializationMode()
    flags = slave.doStep(0.0, 2e-3)
    assert tuple(flags) == (False, False, False, pytest.approx(2e-3))
    slave.setFloat64([refs["x_cmd"]], [1.0])
    with pytest.raises(FMICallException):
        slave.doStep(2e-3, 1e-3)
    with pytest.raises(FMICallException):
        slave.enterEventMode()
    slave.terminate()
    slave.freeInstance()
    refused = FMU3Slave(guid=md.guid, unzipDirectory=folder,
                        modelIdentifier=md.coSimulation.modelIdentifier, instanceName="e")
    with pytest.raises(Exception, match="instantiate"):
        refused.instantiate(eventModeUsed=True)


def test_model_exchange_modes(tmp_path):
    """After initialisation Model Exchange is in Event Mode: fmi3UpdateDiscreteStates there,
    fmi3CompletedIntegratorStep only in Continuous-Time Mode, and back again."""
    folder = extract(str(native_build(3, "me")), str(tmp_path))
    md = read_model_description(folder)
    model = FMU3Model(guid=md.guid, unzipDirectory=folder,
                      modelIdentifier=md.modelExchange.modelIdentifier, instanceName="m")
    model.instantiate()
    model.enterInitializationMode(startTime=0.0)
    model.exitInitializationMode()
    with pytest.raises(FMICallException):
        model.completedIntegratorStep()
    model.updateDiscreteStates()
    model.enterContinuousTimeMode()
    with pytest.raises(FMICallException):
        model.updateDiscreteStates()
    model.setTime(1e-3)
    model.completedIntegratorStep()
    model.enterEventMode()
    model.updateDiscreteStates()
    model.terminate()
    model.freeInstance()


@pytest.mark.parametrize(("interface", "as_"), [("cs", "cs"), ("me", "me"), ("both", "cs"),
                                                ("both", "me")])
def test_fmusim_runs_every_fmi3_build(interface, as_, tmp_path):
    fmusim = os.environ.get("FMUSIM")
    if not fmusim:
        pytest.skip("set FMUSIM to an fmusim binary (Reference FMUs, docs/fmu.md)")
    fmu, out = native_build(3, interface), tmp_path / "out.csv"
    run = subprocess.run([fmusim, "--interface-type", as_, "--stop-time", "0.5",
                          "--output-interval", "1e-3", "--output-file", str(out),
                          "--log-fmi-calls", "--log-file", str(tmp_path / "log.txt"),
                          *(["--solver", "cvode"] if as_ == "me" else []), str(fmu)],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr + Path(tmp_path / "log.txt").read_text()[-2000:]
    data = np.genfromtxt(out, delimiter=",", names=True)
    assert data.size == 501 and all(np.isfinite(data[n]).all() for n in data.dtype.names)
