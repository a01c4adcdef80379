"""Forged FMU states (issue 28): a checksum proves nothing, every field is checked.

States are forged from the genuine states of every phase (instantiated, in
initialisation, failed initialisation, stepping, stepping with a NaN input,
terminated), with valid checksums: random field values and types, NaN and
infinities written into the bytes, 100 000-deep nesting, 5000-digit integers,
truncations inside valid frames, wrong and relabelled phases, other presets,
missing and extra keys, garbage. 1e5 of them go through the validator in-process
and about 1000 through the built FMU (fmpy, through the guard).

The criterion for each: refused with a one-line ``FMU state refused: ...`` error
(fmi2Error from the binary, never fmi2Fatal), the instance unchanged; or restored,
and then an instance in Step Mode takes its next steps (100 through the binary)
holding the state's last command: each step passes with finite outputs, or is
refused by the plant's own bounds (a forged drive state may claim a motion the held
command cannot stop within 10 m/s and 10 000 m/s^2: the step is then refused with
that message and the instance is unchanged and usable, as after any refused step).
"""

from __future__ import annotations

import json
import math
import os
import re
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import fmi2Error
from fmu_support import built_fmu, load_module
from pythonfmu.enums import Fmi2Status

from fmu_src import state as fmu_state
from fmu_src.build import DEFAULT_SLAVE
from fmu_src.host import start_slave
from toggle.kinematics import stroke_limits
from toggle.plant import configure

SLAVE = load_module(DEFAULT_SLAVE, "toggle_clamp_fmu_fuzz").ToggleClamp
X_OPEN, X_TOGGLE = stroke_limits(configure("chang2021").mechanism.lower)
START = {"x_cmd": X_OPEN, "drive_bandwidth": 20.0, "x_contact": X_TOGGLE - 1e-3,
         "delta_r8": 0.3e-3}
REAL_PARAMETERS = [v for v in SLAVE.VARIABLES if v.causality == "parameter" and not v.is_string]
PARAMETER_RANGES = {v.name: (v.min, v.max) for v in REAL_PARAMETERS}
#: forged states in-process (STATE_FUZZ_N), and every 100th of them also through the binary
N_FORGED, EVERY_BINARY = int(os.environ.get("STATE_FUZZ_N", 100_000)), 100
PLANT_REFUSAL = re.compile(r"^step at t=\S+ s rejected: (the command x_cmd = .* asks for "
                           r"|input position x = .* outside the assemblable range)")
_NUMBER = re.compile(r"(?<=[:\[,])-?\d[\d.eE+-]*")


def _errors(slave) -> list[str]:
    """Error messages the in-process slave logged since the last call."""
    errors = [m.msg for m in slave.log_queue if m.status == Fmi2Status.error]
    slave.log_queue.clear()
    return errors


def _vr(slave, name: str) -> int:
    return next(vr for vr, v in slave.vars.items() if v.name == name)


def _fingerprint(slave) -> dict:
    """What the instance holds: its attributes, compared by identity with
    :func:`_unchanged` (a refused state puts back the very objects it had)."""
    return dict(slave.__dict__)


def _unchanged(slave, before: dict) -> bool:
    after = slave.__dict__
    return after.keys() == before.keys() and all(after[k] is before[k] for k in before)


def genuine_states() -> dict[str, bytes]:
    """The serialised states an instance hands out in every phase."""
    states = {}
    fresh = SLAVE(instance_name="genuine")
    states["instantiated"] = fresh._fmu_state_to_bytes(fresh._get_fmu_state())
    failed = SLAVE(instance_name="failed")
    failed.enter_initialization_mode()
    failed._set("m_platen", -3.0)
    failed.exit_initialization_mode()
    states["initialising, failed"] = failed._fmu_state_to_bytes(failed._get_fmu_state())
    slave = SLAVE(instance_name="genuine")
    slave.enter_initialization_mode()
    for name, value in START.items():
        slave._set(name, value)
    slave.get_real([_vr(slave, "input_force")])  # outputs in Initialization Mode
    states["initialising"] = slave._fmu_state_to_bytes(slave._get_fmu_state())
    slave.exit_initialization_mode()
    for k in range(1, 41):
        slave._set("x_cmd", X_OPEN + 2.5 * (k * 1e-3) ** 2)
        assert slave.do_step(k * 1e-3, 1e-3)
    states["stepping"] = slave._fmu_state_to_bytes(slave._get_fmu_state())
    slave._set("x_cmd", math.nan)  # a master may set it; the next step would refuse it
    states["stepping, NaN input"] = slave._fmu_state_to_bytes(slave._get_fmu_state())
    slave.terminate()
    states["terminated"] = slave._fmu_state_to_bytes(slave._get_fmu_state())
    failed.terminate()
    states["terminated, failed"] = failed._fmu_state_to_bytes(failed._get_fmu_state())
    assert not _errors(slave) and len(_errors(failed)) == 1
    return states


def _frame(payload: bytes, phase: int) -> bytes:
    body = struct.pack("<8sIII", fmu_state.MAGIC, fmu_state.VERSION, phase, len(payload))
    return body + payload + struct.pack("<I", zlib.crc32(body + payload))


def _paths(node, prefix=()) -> list[tuple]:
    """Every key path of a parsed state, containers included."""
    items = node.items() if isinstance(node, dict) else enumerate(node) \
        if isinstance(node, list) else ()
    out = [prefix] if prefix else []
    for key, child in items:
        out += _paths(child, (*prefix, key))
    return out


def _weird(rng: np.random.Generator, old):
    """A replacement value: nearby floats, extremes, other types, bad text."""
    pool = [0.0, -0.0, 1e308, -1e308, 5e-324, 7, 10 ** 40, True, None, "nan", "inf", "1.0",
            "x" * 5000, "\x00", "\ud800", [], {}, [1.0] * 6, float(rng.normal() * 10.0 **
                                                                  rng.uniform(-6, 3))]
    if isinstance(old, float) and math.isfinite(old):
        pool += [math.nextafter(old, math.inf), old * (1 + 1e-9), -old, old * 1e3] * 3
    return pool[rng.integers(len(pool))]


def forge(rng: np.random.Generator, bases: list[Base]) -> bytes:
    """One forged state with a valid frame and checksum, from a random genuine one."""
    base = bases[rng.integers(len(bases))]
    text, phase = base.text, fmu_state.PHASES.index(base.state["phase"])
    kind = rng.integers(14)
    if kind == 0:  # a number of the genuine bytes made non-finite or 5000 digits long
        a, b = base.numbers[rng.integers(len(base.numbers))]
        bad = ["NaN", "Infinity", "-Infinity", "1e999", "-1e400", "9" * 5000][rng.integers(6)]
        return _frame((text[:a] + bad + text[b:]).encode(), phase)
    if kind == 1:  # truncated inside a valid frame
        return _frame(text.encode()[:rng.integers(len(text))], phase)
    if kind == 2:  # nested 100 000 deep
        return _frame(text.replace('"failure":', '"failure":' + "[" * 100_000 + "]" * 100_000
                                   + ',"x":', 1).encode(), phase)
    if kind == 3:  # another phase in the header than in the payload
        return _frame(text.encode(), (phase + 1 + rng.integers(3)) % 4)
    if kind == 4:  # garbage
        return _frame(rng.bytes(rng.integers(1, 300)), phase)
    if kind == 5:  # relabelled phase, header and payload agreeing
        new = int(rng.integers(4))
        return _frame(base.replace("phase", fmu_state.PHASES[new]).encode(), new)
    if kind == 6:  # another preset's FMU or preset value
        key = ("fmu", "preset")[rng.integers(2)]
        return _frame(base.replace(key, "ToggleClamp lin2003_sm55" if key == "fmu"
                                   else "lin2003_sm55").encode(), phase)
    if kind in (7, 8) or kind == 9 and rng.random() < 0.003:
        return _frame(_reshaped(rng, base, kind).encode(), phase)
    # any scalar field, any value (a parameter of an initialised state: outside its range or
    # of a wrong type; within it, kind 9 builds a new plant)
    key, a, b = base.scalars[rng.integers(len(base.scalars))]
    value = _weird(rng, json.loads(text[a:b]))
    if base.state["model"] and key in PARAMETER_RANGES and isinstance(value, float):
        low, high = PARAMETER_RANGES[key]
        value = high + 1.0 + abs(value) if low <= value <= high else value
    return _frame((text[:a] + json.dumps(value) + text[b:]).encode(), phase)


def _reshaped(rng: np.random.Generator, base: Base, kind: int) -> str:
    """Kind 7: a key missing or one too many; 8: "drive": null and friends; 9: a parameter
    within its range (a new plant)."""
    forged = json.loads(base.text)
    if kind == 7:
        path = base.paths[rng.integers(len(base.paths))]
        parent = _get(forged, path[:-1])
        if isinstance(parent, dict) and rng.random() < 0.5:
            del parent[path[-1]]
        elif isinstance(parent, dict):
            parent["extra"] = 1.0
        else:
            parent.append(0.0)
    elif kind == 8:
        if isinstance(forged["model"], dict):
            forged["model"][("drive", "slip")[rng.integers(2)]] = None
        else:
            forged["model"] = {"drive": None, "slip": None}
    else:
        var = REAL_PARAMETERS[rng.integers(len(REAL_PARAMETERS))]
        forged["values"][var.name] = float(rng.uniform(var.min, var.max))
    return json.dumps(forged, separators=(",", ":"))


def _get(node, path):
    for key in path:
        node = node[key]
    return node


_SCALAR = r'(-?\d[\d.eE+-]*|"(?:[^"\\]|\\.)*"|null|true|false)'
_MEMBER = re.compile(r'"(\w+)":' + _SCALAR)
_ELEMENT = re.compile(r"(?<=[\[,])" + _SCALAR + r"(?=[,\]])")


class Base:
    """A genuine state's payload: parsed, as text, and where its scalars and numbers are."""

    def __init__(self, text: str) -> None:
        self.text, self.state = text, json.loads(text)
        self.paths = _paths(self.state)
        self.scalars = [(m.group(1), *m.span(2)) for m in _MEMBER.finditer(text)] + [
            ("[]", *m.span(1)) for m in _ELEMENT.finditer(text)]
        self.numbers = [m.span() for m in _NUMBER.finditer(text)]

    def replace(self, key: str, value: str) -> str:
        """The text with the string member ``key`` set to ``value``."""
        _, a, b = next(row for row in self.scalars if row[0] == key)
        return self.text[:a] + json.dumps(value) + self.text[b:]


def _bases() -> list[Base]:
    return [Base(data[20:-4].decode()) for data in genuine_states().values()]


def _steps_in_process(slave, count: int) -> None:
    """Hold the last command for ``count`` steps: each passes with finite outputs or is
    refused by the plant's bounds, leaving the instance unchanged."""
    u = slave._drive.u
    for k in range(count):
        slave._set("x_cmd", u)
        before = _fingerprint(slave)
        if slave.do_step(k * 1e-3, 1e-3):
            assert all(math.isfinite(getattr(slave, n)) for n in slave._outputs)
        else:
            errors = _errors(slave)
            assert len(errors) == 1 and PLANT_REFUSAL.match(errors[0]), errors
            assert _unchanged(slave, before)


def test_every_state_the_fmu_hands_out_restores_as_it_was():
    """Whatever the phase (and a failed initialisation, a NaN input), a state handed out
    restores into a fresh instance, which then hands out the same bytes."""
    for name, data in genuine_states().items():
        slave = SLAVE(instance_name="restore")
        slave._set_fmu_state(slave._fmu_state_from_bytes(data))
        assert not _errors(slave), name
        assert slave._fmu_state_to_bytes(slave._get_fmu_state()) == data, name


def test_forged_states_are_refused_or_restore_to_a_working_instance(
        tmp_path_factory: pytest.TempPathFactory):
    rng = np.random.default_rng(28)
    bases = _bases()
    slave = SLAVE(instance_name="fuzz")
    slave._set_fmu_state(slave._fmu_state_from_bytes(genuine_states()["stepping"]))
    refused = restored = 0
    kept = []
    for i in range(N_FORGED):
        data = forge(rng, bases)
        before = _fingerprint(slave)
        slave._set_fmu_state(slave._fmu_state_from_bytes(data))
        errors = _errors(slave)
        if errors:
            assert len(errors) == 1 and errors[0].startswith("FMU state refused: "), errors
            assert "\n" not in errors[0] and len(errors[0]) < 600, errors[0]
            assert _unchanged(slave, before)
            refused += 1
        else:
            restored += 1
            assert all(math.isfinite(getattr(slave, n)) for n in slave._outputs)
            if slave._phase == "stepping":
                _steps_in_process(slave, 2)
        if i % EVERY_BINARY == 0:
            kept.append((data, not errors))
    assert refused > 0.5 * N_FORGED and restored > 0.02 * N_FORGED, (refused, restored)
    _through_the_binary(kept, tmp_path_factory)


def _through_the_binary(cases: list[tuple[bytes, bool]],
                        tmp_path_factory: pytest.TempPathFactory) -> None:
    """The same forged bytes through the guard and pythonfmu: the same verdict as in-process,
    fmi2Error (never fmi2Fatal) when refused, 100 steps when restored into Step Mode."""
    fmu = built_fmu("clamp")
    unzipped = Path(extract(str(fmu), str(tmp_path_factory.mktemp("unzipped"))))
    log: list[tuple[int, str]] = []
    slave, refs = start_slave(unzipped, "fuzz", START, log=lambda *entry: log.append(entry),
                              logging=False)
    outputs = [refs[v.name] for v in SLAVE.VARIABLES if v.causality == "output"]
    try:
        good = slave.deSerializeFMUstate(genuine_states()["stepping"])
        for data, accepted in cases:
            log.clear()
            try:
                state = slave.deSerializeFMUstate(data)
                try:
                    slave.setFMUstate(state)
                finally:
                    slave.freeFMUstate(state)
            except FMICallException as refused:
                assert refused.status == fmi2Error and not accepted, log
                assert any(text.startswith("FMU state refused: ") for _, text in log), log
                continue
            assert accepted, data
            payload = json.loads(data[20:-4])
            if payload["phase"] == "stepping":
                _steps_through_the_binary(slave, refs, outputs, payload["model"]["drive"][3],
                                          log)
            if payload["phase"] != "initialising":  # (there: computed from the values)
                slave.getReal(outputs)
        slave.setFMUstate(good)  # still a working instance
        slave.setReal([refs["x_cmd"]], [X_OPEN + 1e-5])
        slave.doStep(0.0, 1e-3)
        slave.freeFMUstate(good)
    finally:
        slave.terminate()
        slave.freeInstance()


def _steps_through_the_binary(slave, refs, outputs, u: float, log) -> None:
    for k in range(100):
        before = slave.getReal(outputs)
        slave.setReal([refs["x_cmd"]], [u])
        log.clear()
        try:
            slave.doStep(k * 1e-3, 1e-3)
        except FMICallException as refused:
            assert refused.status == fmi2Error
            assert any(PLANT_REFUSAL.match(text) for _, text in log), log
            assert slave.getReal(outputs) == before
            continue
        assert all(map(math.isfinite, slave.getReal(outputs)))


def test_states_of_every_phase_restore_through_the_binary_in_their_phase(
        tmp_path_factory: pytest.TempPathFactory):
    """States handed out by the built FMU before, during and after initialisation and after
    fmi2Terminate restore into a stepping instance, and the guard takes their phase: a
    parameter can be set again before initialisation ends, a step needs Step Mode."""
    from fmpy import read_model_description
    from fmpy.fmi2 import FMU2Slave

    unzipped = Path(extract(str(built_fmu("clamp")), str(tmp_path_factory.mktemp("phases"))))
    md = read_model_description(str(unzipped))
    refs = {v.name: v.valueReference for v in md.modelVariables}
    source = FMU2Slave(guid=md.guid, unzipDirectory=str(unzipped),
                       modelIdentifier=md.coSimulation.modelIdentifier, instanceName="source")
    source.instantiate(loggingOn=False)
    saved = {}

    def save(phase: str) -> None:
        state = source.getFMUstate()
        saved[phase] = bytes(source.serializeFMUstate(state))
        source.freeFMUstate(state)

    save("instantiated")
    source.setupExperiment(startTime=0.0)
    source.enterInitializationMode()
    source.setReal([refs["x_cmd"], refs["m_platen"]], [X_OPEN, -3.0])  # refused at exit
    save("initialising")
    source.setReal([refs["m_platen"]], [2.5])
    source.exitInitializationMode()
    source.setReal([refs["x_cmd"]], [X_OPEN + 1e-4])
    source.doStep(0.0, 1e-3)
    save("stepping")
    source.terminate()
    save("terminated")
    source.freeInstance()
    slave, refs = start_slave(unzipped, "target", {"x_cmd": X_OPEN})
    try:
        for phase, data in saved.items():
            state = slave.deSerializeFMUstate(data)
            slave.setFMUstate(state)
            slave.freeFMUstate(state)
            settable = phase in ("instantiated", "initialising")
            try:
                slave.setReal([refs["m_platen"]], [2.5])
                assert settable, phase
            except FMICallException:
                assert not settable, phase
            if phase == "initialising":
                slave.exitInitializationMode()  # with m_platen = 2.5 set again
            try:
                slave.doStep(0.0, 1e-3)
                assert phase in ("initialising", "stepping"), phase
            except FMICallException as refused:
                assert refused.status == fmi2Error and phase in ("instantiated", "terminated")
    finally:
        slave.terminate()
        slave.freeInstance()
