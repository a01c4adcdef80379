"""The rig firmware's host build (hil/emulators/firmware.py): the C core on the simulated rig.

The simulated rig (firmware/sim/) is an FMI 2.0 master of the native FMU's C code with the
sensor model of hil.emulators.rig_hardware.Sensors. Its physics is checked against the Python model:
the same protocol session (HELLO, CONFIG, streamed chunks, START, heartbeats) drives
FirmwareMcu and McuModel over a stroke of the default RigSetup and back, and every
telemetry sample's steps, enc and load_raw are compared (the protocol fields are
tests/test_mcu_conformance.py's).

Tolerances. enc must be equal. load_raw may differ by LOAD_RAW_TOLERANCE counts: the native
FMU's outputs equal the Python plant's to 1e-9 relative (tests/test_native_fmu.py), which
at the stroke's largest input force (84 N, accelerating at its start) is below 1e-7 N, 1e-3 of
a count (1e-4 N): only a value that lands that close to a rounding boundary can round the
other way, by one count. Measured here: 0 counts of difference in every sample of both
runs (the plant's outputs agree to the bit on this machine).
"""

from __future__ import annotations

import random
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest

from hil.emulators.firmware import FirmwareMcu, build_host_firmware, split_frames
from hil.emulators.mcu_model import McuModel, RigHardware
from hil.emulators.rig_physics import ClampPhysics
from hil.host.backends import RigSetup
from hil.host.experiment import stroke_positions
from hil.link import protocol as p

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None,
                                reason="gcc is missing: the rig firmware's host build needs it")

LOAD_RAW_TOLERANCE = 1  # ADC counts (see the module's docstring)
SPEED = 0.04  # m/s: 200 steps per period, within the CONFIG's max_step_delta
CONFIG = p.Config(force_limit_n=400.0, steps_min=-50_000, steps_max=400_000,
                  enc_min=-500_000, enc_max=500_000, following_error_counts=1_000,
                  max_step_delta=p.MAX_STEP_DELTA, heartbeat_timeout_ms=250, stuck_samples=200)
PREFILL = 1800  # points sent before START; the host keeps this many ahead


@pytest.fixture(scope="module")
def library() -> Path:
    return build_host_firmware("chang2021")


def decode(frames: list[bytes]) -> list[p.Message]:
    """Wire frames (each with its delimiter) -> messages."""
    out = []
    for wire in frames:
        assert wire.endswith(b"\x00") and b"\x00" not in wire[:-1]
        out.append(p.parse_message(p.decode_frame(wire[:-1])))
    return out


@dataclass
class Twin:
    """The C firmware and the Python MCU model fed the same frames at the same ticks."""

    fw: FirmwareMcu
    model: McuModel
    now: float = 0.0
    seq: int = 100
    tel_c: list[p.Telemetry] = field(default_factory=list)
    tel_py: list[p.Telemetry] = field(default_factory=list)

    def send(self, msg: p.Message, ack: bool = True) -> tuple[list[p.Message], list[p.Message]]:
        self.seq += 1
        wire = p.encode_message(msg, self.seq, p.FLAG_ACK_REQ if ack else 0)
        c = decode(self.fw.receive(wire, self.now))
        py = [m for f in p.FrameDecoder().feed(wire) for m in self.model.handle(f, self.now)]
        return c, py

    def tick(self) -> None:
        self.tel_c += [m for m in decode(self.fw.tick(self.now)) if isinstance(m, p.Telemetry)]
        self.tel_py += [m for m in self.model.tick(self.now)
                        if isinstance(m, p.Telemetry)]
        self.now += 1e-3


def stroke_steps(setup: RigSetup) -> list[int]:
    """A stroke of ``setup`` from its open position to the toggle and back, in steps."""
    x_open, x_toggle = setup.stroke
    forward = stroke_positions(x_open, x_toggle, SPEED, setup.period, setup.limits)
    x = np.concatenate([forward, forward[-2::-1]])
    return [round((xi - x_open) / 200e-9) for xi in x]


def make_twin(setup: RigSetup, library: Path, noise: float = 0.0, seed: int = 7) -> Twin:
    hw = RigHardware(load_noise_n=noise, x_origin=setup.stroke[0])
    physics = dict(preset=setup.preset, delta_r8=setup.delta_r8, mu=setup.mu,
                   x_contact=setup.x_contact)
    return Twin(FirmwareMcu(ClampPhysics(**physics), hw, seed, library=library),
                McuModel(ClampPhysics(**physics), hw, random.Random(seed)))


def run_session(twin: Twin, steps: list[int]) -> None:
    """HELLO, CONFIG, prefilled chunks, START, then chunks and heartbeats to the end."""
    points = [(s, p.NO_CHECK) for s in steps]
    for _ in range(3):
        twin.tick()
    for msg in (p.Hello(host_nonce=0x1234), CONFIG):
        c, py = twin.send(msg)
        assert [type(m) for m in c] == [type(m) for m in py]
        assert c[0].result == py[0].result == p.Result.OK
    sent = 0

    def chunk() -> None:
        nonlocal sent
        part = tuple(points[sent:sent + p.MAX_CHUNK_POINTS])
        final = p.TrajChunk.FINAL if sent + len(part) == len(points) else 0
        c, py = twin.send(p.TrajChunk(sent, final, part))
        assert c[0].result == py[0].result == p.Result.OK, (c, py)
        sent += len(part)

    while sent < min(PREFILL, len(points)):
        chunk()
    assert twin.send(p.Start())[0][0].result == p.Result.OK
    running = True
    ticks = 0
    while running or ticks < 5:
        twin.tick()
        last = twin.tel_c[-1]
        if sent < len(points) and sent - last.exec_index < PREFILL:
            chunk()
        elif ticks % 50 == 0:
            twin.send(p.Heartbeat(), ack=False)
        running = last.state in (p.State.RUNNING, p.State.STOPPING)
        ticks = ticks + 1 if not running else 0
        assert len(twin.tel_c) < len(points) + 100, "the run does not end"


@pytest.mark.parametrize("mold", [False, True], ids=["no-mold", "planned-mold"])
def test_sim_physics_matches_python_model(library: Path, mold: bool) -> None:
    base = RigSetup()
    setup = RigSetup(x_contact=base.planned_mold) if mold else base
    twin = make_twin(setup, library)
    steps = stroke_steps(setup)
    run_session(twin, steps)
    c, py = twin.tel_c, twin.tel_py
    assert len(c) == len(py)
    final = c[-1]
    assert final.state == p.State.IDLE and final.faults == 0
    assert final.exec_index == len(steps)
    c_steps = np.array([t.steps for t in c])
    assert set(steps) <= set(c_steps.tolist())  # the whole stroke was executed
    assert np.array_equal(c_steps, [t.steps for t in py])
    enc_c, enc_py = np.array([t.enc for t in c]), np.array([t.enc for t in py])
    raw_c, raw_py = np.array([t.load_raw for t in c]), np.array([t.load_raw for t in py])
    assert np.ptp(enc_c) > 40_000  # the platen travelled (45 mm)
    assert np.array_equal(enc_c, enc_py), np.flatnonzero(enc_c != enc_py)[:10]
    worst = int(np.abs(raw_c - raw_py).max())
    assert worst <= LOAD_RAW_TOLERANCE, f"load_raw differs by up to {worst} counts"
    status = twin.fw.sim_status()
    assert status["fmu_failures"] == 0 and status["arena_used"] == 0
    assert status["hw_steps"] == steps[-1]


@pytest.mark.parametrize("physics, extra, named", [
    (ClampPhysics(), {"delta_r99": 0.0}, "delta_r99"),
    (ClampPhysics(), {"platen_position": 0.1}, "platen_position"),
    (ClampPhysics(), {"drive_bandwidth": float("nan")}, "drive_bandwidth"),
    (ClampPhysics(mu=2.0), {}, "mu"),
    (ClampPhysics(delta_r8=0.0049), {"delta_r1U": 0.0052}, "delta_r1U"),
    (ClampPhysics(), {"x_contact": 1.0}, "x_contact"),
])
def test_bad_parameter_is_refused_by_name(library: Path, physics: ClampPhysics,
                                          extra: dict[str, float], named: str) -> None:
    hw = RigHardware(x_origin=RigSetup().stroke[0])
    with pytest.raises(ValueError, match=rf"refused its setup: .*\b{named}\b"):
        FirmwareMcu(physics, hw, 1, library=library, parameters=extra)


def test_reset_gives_new_boot_id_and_counts_at_zero(library: Path) -> None:
    setup = RigSetup()
    twin = make_twin(setup, library)
    run_session(twin, stroke_steps(setup)[:400])  # a short move out: counts away from 0
    fw = twin.fw
    steps, enc, _, hw_steps = fw.counts()
    assert steps != 0 and enc != 0 and hw_steps == steps
    before = fw.sim_status()
    boot_ids = {fw.boot_id}
    fw.reset()
    assert fw.boot_id not in boot_ids and fw.boot_id != 0
    assert fw.state == p.State.BOOT
    assert fw.counts()[:2] == (0, 0)
    # no session after the reset: no telemetry (docs/rig-protocol.md, section 5)
    assert not [m for m in decode(fw.tick(10.0)) if isinstance(m, p.Telemetry)]
    after = fw.sim_status()  # the rig did not move: a reset is the MCU's, not the rig's
    assert after["hw_steps"] == before["hw_steps"]
    assert after["platen_position"] == pytest.approx(before["platen_position"], abs=1e-9)
    (reply,) = [m for m in decode(fw.receive(p.encode_message(p.Hello(host_nonce=9), 1,
                                                              p.FLAG_ACK_REQ), 10.0005))
                if isinstance(m, p.HelloReply)]
    assert reply.boot_id == fw.boot_id and reply.state == p.State.IDLE
    (tel,) = [m for m in decode(fw.tick(10.001)) if isinstance(m, p.Telemetry)]
    assert (tel.boot_id, tel.steps, tel.enc) == (fw.boot_id, 0, 0)
    assert tel.t_us == 1000  # the first tick after the reset is the boot's time
    assert tel.state == p.State.IDLE and tel.flags & p.TelemetryFlag.SESSION
    boot_ids.add(fw.boot_id)
    for _ in range(20):
        previous = fw.boot_id
        fw.reset()
        assert fw.boot_id not in (0, previous)
        boot_ids.add(fw.boot_id)
    assert len(boot_ids) == 22  # 32 random bits: a repeat has odds of 1e-7


def test_sensor_faults_and_seeded_noise(library: Path) -> None:
    setup = RigSetup()

    def idle_raws(seed: int, n: int, fw: FirmwareMcu | None = None) -> list[int]:
        if fw is None:  # a session: telemetry flows only in one
            fw = make_twin(setup, library, noise=0.2, seed=seed).fw
            fw.receive(p.encode_message(p.Hello(host_nonce=1), 1, p.FLAG_ACK_REQ), 0.0)
        out = []
        for i in range(n):
            out += [m.load_raw for m in decode(fw.tick(i * 1e-3)) if isinstance(m, p.Telemetry)]
        return out

    a, b, other = idle_raws(5, 400), idle_raws(5, 400), idle_raws(6, 400)
    assert a == b and a != other  # deterministic, seeded
    hw = RigHardware()
    force = (np.array(a) - hw.load_offset) * hw.load_gain_n
    assert force.std() == pytest.approx(0.2, rel=0.15)  # load_noise_n rms
    fw = make_twin(setup, library, noise=0.2, seed=5).fw
    fw.receive(p.encode_message(p.Hello(host_nonce=1), 1, p.FLAG_ACK_REQ), 0.0)
    idle_raws(0, 10, fw)
    fw.force_spike(50.0, 3)
    spiked = idle_raws(0, 5, fw)
    assert [r > hw.load_offset + 400_000 for r in spiked] == [True] * 3 + [False] * 2
    fw.stick_load(True)
    stuck = idle_raws(0, 5, fw)
    assert len(set(stuck)) == 1
    fw.stick_load(False)
    assert len(set(idle_raws(0, 5, fw))) > 1


def test_a_failed_build_names_gcc_and_its_complaint(monkeypatch: pytest.MonkeyPatch) -> None:
    import hil.emulators.firmware as firmware

    before = set(firmware.BUILD_DIR.iterdir())
    bad = (*firmware.FIRMWARE_CFLAGS, "-fno-such-option")
    monkeypatch.setattr(firmware, "FIRMWARE_CFLAGS", bad)
    with pytest.raises(RuntimeError, match=r"(?s)building the rig firmware failed:\n.*gcc"
                                           r".*-fno-such-option"):
        build_host_firmware("chang2021")
    assert set(firmware.BUILD_DIR.iterdir()) == before  # nothing left behind


def test_split_frames() -> None:
    assert split_frames(b"ab\x00\x00cd\x00ef") == ([b"ab\x00", b"\x00", b"cd\x00"], b"ef")


def _nucleo_rises(n: int, ticks: int) -> int:
    """firmware/core/step_burst.h's law, written out: rising edges of an n-step burst of
    TIM1 (60 MHz) within ``ticks`` of its start."""
    period = (60_000 - 60) // n
    first = period - min(period // 2, 150)
    return 0 if ticks < first else min(n, (ticks - first) // period + 1)


@pytest.mark.parametrize("timing", ["at-once", "nucleo"])
def test_the_step_timing_moves_the_table_when_the_pulses_leave(library: Path,
                                                              timing: str) -> None:
    """"nucleo": a tick's steps leave in a burst from 300 us after it over the period, so the
    table trails the count by the armed burst and the running one's unemitted pulses; a stop
    (the stop input: a halt) gives the unemitted back and the count is where the table is.
    "at-once": the table is at the count in every reading."""
    setup = RigSetup()
    fw = FirmwareMcu(ClampPhysics(), RigHardware(x_origin=setup.stroke[0]), 1,
                     library=library, step_timing=timing)
    now, seq = 0.0, 0

    def send(msg: p.Message) -> None:
        nonlocal seq
        seq += 1
        reply = decode(fw.receive(p.encode_message(msg, seq, p.FLAG_ACK_REQ), now))
        assert reply[0].result == p.Result.OK, reply

    send(p.Hello(host_nonce=1))
    send(CONFIG)
    deltas = [min(200, 5 * (i + 1)) for i in range(60)]  # up to 40 mm/s at 1 m/s^2
    points = [(sum(deltas[:i + 1]), p.NO_CHECK) for i in range(len(deltas))]
    for first in range(0, len(points), p.MAX_CHUNK_POINTS):
        final = p.TrajChunk.FINAL if first + p.MAX_CHUNK_POINTS >= len(points) else 0
        send(p.TrajChunk(first, final, tuple(points[first:first + p.MAX_CHUNK_POINTS])))
    send(p.Start())
    for _ in range(50):
        fw.tick(now)
        now += 1e-3
    st = fw.sim_status()
    lag = st["hw_steps"] - st["table_steps"]
    burst_to_next_tick = 60 * (1000 - 300)  # TIM1 ticks from a burst's start to the tick
    assert st["hw_steps"] > 0
    assert lag == (0 if timing == "at-once" else 200 + 200 - _nucleo_rises(200,
                                                                          burst_to_next_tick))
    fw.press_stop()
    fw.tick(now)
    st = fw.sim_status()
    steps, _, _, hw_steps = fw.counts()
    assert st["table_steps"] == st["hw_steps"] == hw_steps == steps  # nothing in flight


def test_an_unknown_step_timing_is_refused(library: Path) -> None:
    with pytest.raises(ValueError, match="step_timing 'tim1': expected one of at-once, nucleo"):
        FirmwareMcu(ClampPhysics(), RigHardware(x_origin=RigSetup().stroke[0]), 1,
                    library=library, step_timing="tim1")
