"""Host link against the rig emulator over a pseudo-terminal: handshake, streaming, faults.

The emulator runs in a thread with a placeholder plant (platen = 2 x, force = k x), which
is enough for the protocol; the real plant is plugged into the emulator elsewhere. Where
timing is not the point, the host watchdog is generous so a loaded machine cannot trip it.
"""

from __future__ import annotations

import gc
import os
import threading
import time
from collections.abc import Callable, Iterator

import pytest
from hil_host import wait_for

from hil.emulators.mcu_model import RigHardware
from hil.emulators.rig_emulator import FaultPlan, RigEmulator
from hil.link import protocol as p
from hil.link.errors import (
    CommandError,
    HandshakeError,
    LinkLostError,
    LinkTimeoutError,
    RigError,
    RigFaultError,
    RigResetError,
    RigStalledError,
)
from hil.link.realtime import SESSION_NICE
from hil.link.serial_link import SerialLink

pytestmark = pytest.mark.real_time

PERIOD = 1e-3
STIFFNESS = 2e3  # N/m of the placeholder plant
RELAXED = 0.5  # s: host watchdog where timing is not under test
SCHEDULING_SLACK = 3e-3  # s: allowance for thread wake-up on a loaded 2-core machine


def placeholder_plant(x: float, t: float) -> tuple[float, float]:
    """Test-only plant: the platen moves twice the input; the force is a linear spring."""
    return 2.0 * x, STIFFNESS * x


def ramp(n: int, rate: int = 20) -> list[tuple[int, int]]:
    """n points at ``rate`` steps/ms from 0, with the placeholder's expected encoder counts."""
    return [(i * rate, round(2 * i * rate * 0.2)) for i in range(n)]


Rig = tuple[RigEmulator, SerialLink]


@pytest.fixture
def rig() -> Iterator[Callable[..., Rig]]:
    """Factory: an emulator thread and an open link to it; both closed afterwards."""
    opened: list[tuple[RigEmulator, SerialLink]] = []

    def make(faults: FaultPlan | None = None, hardware: RigHardware | None = None,
             config: p.Config | None = None, realtime: bool = False, **link_kw: object) -> Rig:
        emulator = RigEmulator(placeholder_plant, hardware, faults, record_telemetry=True,
                               realtime=realtime)
        link = SerialLink(emulator.start(), realtime=realtime,
                          **{"telemetry_timeout": RELAXED, **link_kw})
        opened.append((emulator, link))
        link.open(config)
        return emulator, link

    yield make
    for emulator, link in opened:
        link.close()
        emulator.close()


def run_until_failure(link: SerialLink, points: list[tuple[int, int]]) -> tuple[list, RigError]:
    """Run a trajectory that must fail; return the samples received and the error."""
    samples = []
    with pytest.raises(RigError) as info:
        samples.extend(link.run_trajectory(points))
    return samples, info.value


def fail_by_injection(make: Callable[..., Rig], faults: FaultPlan, name: str,
                      attempts: int = 3) -> tuple[RigEmulator, SerialLink, list, RigError]:
    """Run into the injected fault ``name`` with the default host watchdog.

    Both sides run SCHED_FIFO when permitted. If the watchdog trips before the injection
    (a genuine >100 ms silence caused by machine load) the attempt proves nothing about the
    injected fault and is repeated.
    """
    for _ in range(attempts):
        emulator, link = make(faults=faults, telemetry_timeout=None, realtime=True)
        samples, error = run_until_failure(link, ramp(1000))
        injected = emulator.log.injected.get(name)
        if injected is not None and link.stats.failed_at >= injected:
            return emulator, link, samples, error
    pytest.fail(f"the watchdog tripped before the injected {name} in {attempts} attempts")


def test_handshake_reports_identity_and_scalings(rig: Callable[..., Rig]) -> None:
    emulator, link = rig()
    info = link.info
    assert (info.proto_major, info.result, info.state) == (p.PROTO_MAJOR, 0, p.State.IDLE)
    assert info.boot_id == emulator.mcu.boot_id
    assert link.scaling.step_m == pytest.approx(0.2e-6) and link.scaling.enc_m == 1e-6
    assert link.telemetry_timeout == RELAXED
    assert emulator.mcu.session and emulator.mcu.state == p.State.IDLE


def test_telemetry_streams_at_1khz_without_loss(rig: Callable[..., Rig]) -> None:
    _, link = rig()
    link.drain()
    first = link.next_sample()
    time.sleep(0.4)
    samples = [first, *link.drain()]
    span = samples[-1].rx_time - first.rx_time
    assert [s.sample for s in samples] == list(range(first.sample, first.sample + len(samples)))
    assert len(samples) / span == pytest.approx(1000, rel=0.15)
    mcu_dt = (samples[-1].t_us - first.t_us) / (len(samples) - 1)
    assert mcu_dt == pytest.approx(1000, rel=0.15)
    assert link.stats.lost_samples == 0


def test_stream_trajectory_with_flow_control(rig: Callable[..., Rig]) -> None:
    emulator, link = rig(hardware=RigHardware(buffer_capacity=120, load_noise_n=0.0))
    points = ramp(1500)
    samples = list(link.run_trajectory(points))
    assert samples[-1].state == p.State.IDLE and samples[-1].exec_index == len(points)
    assert samples[-1].steps == points[-1][0] and emulator.mcu.steps == points[-1][0]
    assert max(s.buf_level for s in samples) <= 120  # never more than the MCU's buffer
    commanded = [s.steps for s in samples if s.state == p.State.RUNNING]
    assert commanded == [s for s, _ in points[: len(commanded)]]  # every point, in order
    assert len(commanded) >= len(points) - 1
    assert link.stats.lost_samples == 0
    last = samples[-1]
    x = link.scaling.x(last.steps)
    assert link.scaling.platen(last.enc) == pytest.approx(2 * x, abs=1e-6)
    assert link.scaling.force(last.load_raw) == pytest.approx(STIFFNESS * x, abs=1e-3)


def test_corrupted_link_never_delivers_a_corrupted_frame(rig: Callable[..., Rig]) -> None:
    faults = FaultPlan(seed=3, drop_byte=0.03, flip_bit=0.03, truncate=0.03, split=0.05,
                       junk=0.05, rx_drop_byte=0.02, rx_flip_bit=0.02)
    emulator, link = rig(faults=faults, retries=12)
    points = ramp(600)
    samples = list(link.run_trajectory(points))
    assert samples[-1].exec_index == len(points)
    assert link.decoder.stats.rejected > 20 and link.stats.lost_samples > 20
    sent = emulator.log.sent_telemetry
    assert all(sent[(s.boot_id, s.sample)] == s for s in samples)  # bit-exact or not at all


def test_retransmitted_commands_execute_once(rig: Callable[..., Rig]) -> None:
    faults = FaultPlan(seed=5, flip_bit=0.2, rx_flip_bit=0.2)
    emulator, link = rig(faults=faults, retries=15)
    points = ramp(300)
    for first in range(0, 300, 30):
        link.send_chunk(first, points[first : first + 30], final=first == 270)
    assert link.stats.retransmissions > 0
    assert emulator.mcu.next_index == 300 and list(emulator.mcu.points) == points


def test_short_stall_is_caught_by_the_mcu_clock_not_by_host_timing(
        rig: Callable[..., Rig]) -> None:
    # 50 ms is below the host's 100 ms silence watchdog: the MCU's own timestamps show it
    faults = FaultPlan(stall_at=0.05, stall_for=0.05)
    emulator, link, samples, error = fail_by_injection(rig, faults, "stall")
    assert link.telemetry_timeout >= 0.1  # measured at open: 100 ms on an idle machine
    assert isinstance(error, RigStalledError) and "stalled" in str(error)
    assert "50.0 ms" in str(error) or "51.0 ms" in str(error)
    stop_rx = emulator.log.first_command(p.MsgType.STOP, after=emulator.log.injected["stall"])
    assert stop_rx is not None  # executed as soon as the MCU woke up
    assert wait_for(lambda: emulator.mcu.state == p.State.IDLE)


def test_long_stall_trips_the_host_watchdog(rig: Callable[..., Rig]) -> None:
    faults = FaultPlan(stall_at=0.05, stall_for=0.4)
    emulator, link, samples, error = fail_by_injection(rig, faults, "stall")
    assert isinstance(error, LinkTimeoutError) and "no telemetry" in str(error)
    silence = link.stats.failed_at - samples[-1].rx_time
    # the watchdog (measured at open: 100 ms or more), plus scheduling on a loaded machine
    assert 0.1 <= link.telemetry_timeout <= silence <= link.telemetry_timeout + 0.05
    assert wait_for(lambda: emulator.mcu.state in (p.State.IDLE, p.State.ESTOP))


def test_disconnect_is_detected_and_closes_cleanly(rig: Callable[..., Rig]) -> None:
    faults = FaultPlan(disconnect_at=0.05)
    emulator, link, samples, error = fail_by_injection(rig, faults, "disconnect")
    assert isinstance(error, LinkLostError)
    assert link.stats.failed_at - samples[-1].rx_time <= 3 * PERIOD + SCHEDULING_SLACK
    assert emulator.mcu.state == p.State.IDLE and not emulator.mcu.session  # MCU stopped alone
    link.close()
    assert link.info is None and not link._reader.is_alive()


def test_a_hang_up_met_by_a_write_is_a_disconnect(rig: Callable[..., Rig], monkeypatch) -> None:
    """A write can meet the hang-up before the reader does (two pytest workers timed it so:
    the run failed with "write to /dev/pts/1 failed: ... Input/output error" and never said
    disconnected); the link says the same either way."""
    import serial

    _, link = rig()

    def hung_up(data: bytes) -> int:
        raise serial.SerialException("write failed: [Errno 5] Input/output error")

    monkeypatch.setattr(link._ser, "write", hung_up)
    with pytest.raises(LinkLostError, match=r"disconnected: write failed: \[Errno 5\]"):
        link.stop()
    assert isinstance(link.failure, LinkLostError)  # the reader stops on it too


def test_reset_mid_run_is_reported_as_a_reset(rig: Callable[..., Rig]) -> None:
    emulator, link = rig(faults=FaultPlan(reset_at=0.05))
    old_boot = link.info.boot_id
    samples, error = run_until_failure(link, ramp(1000))
    assert isinstance(error, RigResetError)
    message = str(error)
    assert "reset" in message and f"{old_boot:#010x}" in message
    assert f"{emulator.mcu.boot_id:#010x}" in message
    assert samples and all(s.boot_id == old_boot for s in samples)
    assert 40 <= len(samples) <= 60


def test_force_spike_trips_the_force_limit_and_recovers(rig: Callable[..., Rig]) -> None:
    emulator, link = rig(faults=FaultPlan(force_spike_at=0.05, force_spike_n=450.0),
                         config=p.Config(force_limit_n=300.0))
    samples, error = run_until_failure(link, ramp(1000))
    assert isinstance(error, RigFaultError) and error.faults == p.Fault.FORCE_LIMIT
    report = link.fault_reports[0]
    assert report.fault == p.Fault.FORCE_LIMIT and report.value > report.limit == 300
    assert emulator.mcu.state == p.State.FAULT
    steps_at_fault = emulator.mcu.steps
    time.sleep(0.02)
    assert emulator.mcu.steps == steps_at_fault  # halted at once, no deceleration ramp
    link.clear_fault()
    assert link.failure is None
    back = [(steps_at_fault - 20 * i, 0) for i in range(steps_at_fault // 20 + 1)]
    assert list(link.run_trajectory([(s, p.NO_CHECK) for s, _ in back]))[-1].steps == back[-1][0]


def test_stuck_load_cell_is_a_fault(rig: Callable[..., Rig]) -> None:
    _, link = rig(faults=FaultPlan(stuck_load_at=0.03), config=p.Config(stuck_samples=20))
    _, error = run_until_failure(link, ramp(1000))
    assert isinstance(error, RigFaultError) and error.faults == p.Fault.LOAD_STUCK


def test_stuck_encoder_is_a_following_error(rig: Callable[..., Rig]) -> None:
    _, link = rig(faults=FaultPlan(stuck_encoder_at=0.03),
                  config=p.Config(following_error_counts=50))
    _, error = run_until_failure(link, ramp(1000))
    assert isinstance(error, RigFaultError) and error.faults == p.Fault.FOLLOWING_ERROR
    assert abs(link.fault_reports[0].value) > 50


def test_buffer_underrun_decelerates_and_faults(rig: Callable[..., Rig]) -> None:
    emulator, link = rig(config=p.Config(decel_steps_s2=2e6))
    link.send_chunk(0, ramp(30))
    link.start()
    with pytest.raises(RigFaultError) as info:
        while True:
            link.next_sample()
    assert info.value.faults == p.Fault.BUFFER_UNDERRUN
    assert wait_for(lambda: emulator.mcu.state == p.State.FAULT)
    assert emulator.mcu.steps > ramp(30)[-1][0]  # it ramped down rather than halting


def test_mcu_watchdog_stops_a_run_without_heartbeats(rig: Callable[..., Rig]) -> None:
    emulator, link = rig(config=p.Config(heartbeat_timeout_ms=50), heartbeat_period=None)
    points = ramp(400)
    for first in range(0, 400, 30):
        link.send_chunk(first, points[first : first + 30], final=first + 30 >= 400)
    start = link.start().sample
    with pytest.raises(RigFaultError) as info:
        while True:
            last = link.next_sample()
    assert info.value.faults == p.Fault.HEARTBEAT_LOST
    assert 40 <= last.sample - start <= 150  # ~50 ms after the last host frame
    assert wait_for(lambda: emulator.mcu.state == p.State.FAULT)
    assert emulator.mcu.steps < points[-1][0]


def test_soft_travel_limit_refuses_points(rig: Callable[..., Rig]) -> None:
    emulator, link = rig(config=p.Config(steps_max=1000))
    points = ramp(60)  # up to 1180 steps
    link.send_chunk(0, points[:30])
    with pytest.raises(CommandError, match="OUT_OF_LIMITS"):
        link.send_chunk(30, points[30:])
    with pytest.raises(CommandError, match="BAD_VALUE"):  # faster than max_step_delta
        link.send_chunk(30, [(600, 0), (900, 0)])
    assert list(emulator.mcu.points) == points[:30]


def test_estop_halts_and_latches(rig: Callable[..., Rig]) -> None:
    emulator, link = rig()
    samples = []
    with pytest.raises(RigFaultError) as info:
        for tel in link.run_trajectory(ramp(1000)):
            samples.append(tel)
            if len(samples) == 50:
                assert link.estop()
    assert info.value.faults & p.Fault.ESTOP
    assert emulator.mcu.state == p.State.ESTOP and not emulator.mcu.driver_enabled
    with pytest.raises(RigFaultError) as refused:
        link.start()
    assert "FAULT_ACTIVE" in str(refused.value.__cause__)


def test_loop_url_without_a_rig_fails_the_handshake_cleanly() -> None:
    link = SerialLink("loop://", ack_timeout=0.01, retries=2)
    start = time.monotonic()
    with pytest.raises(HandshakeError, match="HELLO"):
        link.open()
    assert time.monotonic() - start < 1.0
    assert link._ser is None
    link.close()  # idempotent


def test_config_keeps_or_replaces_the_load_cell_calibration(rig: Callable[..., Rig]) -> None:
    emulator, link = rig(config=p.Config(force_limit_n=300.0))  # gain 0: keep the MCU's
    assert (emulator.mcu.cfg.load_offset, link.scaling.load_offset) == (1500, 1500)
    link.configure(p.Config(load_offset=-20, load_gain_n=0.000244140625))
    assert emulator.mcu.cfg.load_offset == -20 == link.scaling.load_offset
    assert link.scaling.load_gain_n == emulator.mcu.cfg.load_gain_n == 0.000244140625
    with pytest.raises(CommandError, match="BAD_VALUE"):
        link.configure(p.Config(steps_min=10, steps_max=0))


@pytest.mark.parametrize("given", [None, 777])
def test_homing_runs_under_the_sessions_heartbeat_timeout(given: int | None,
                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    """Issue 35: homing sent its CONFIG with the default 250 ms and the run's came after it,
    so `hil run --heartbeat-ms 1000` did not cover homing. Every CONFIG of the session, the
    first (homing's) included, carries the session's timeout: as given, else as measured."""
    from hil.emulators.rig_physics import ClampPhysics
    from hil.host.backends import RigPlant, RigSetup

    sent: list[p.Config] = []
    configure = SerialLink.configure
    monkeypatch.setattr(SerialLink, "configure",
                        lambda link, cfg: (sent.append(cfg), configure(link, cfg))[1])
    setup = RigSetup()
    emulator = RigEmulator(ClampPhysics(setup.preset), RigHardware(x_origin=setup.stroke[0]))
    try:
        plant = RigPlant(emulator.start(), realtime=False, heartbeat_ms=given)
        plant.configure(setup)
        with plant:
            assert plant.homed_distance is not None  # it booted unreferenced: it homed
            expected = given or plant.link.timing.heartbeat_timeout_ms
            assert plant.link.heartbeat_timeout_ms == expected
            assert emulator.mcu.cfg.heartbeat_timeout_ms == expected
    finally:
        emulator.close()
    assert len(sent) == 2 and [c.heartbeat_timeout_ms for c in sent] == [expected] * 2


def test_a_frame_truncated_to_nothing_is_sent_as_its_delimiter_even_when_split() -> None:
    # seed 3 once truncated a frame to no bytes and then tried to split the lone delimiter:
    # the serving thread died and the host saw "TRAJ_CHUNK not acknowledged"
    emulator = RigEmulator(placeholder_plant, faults=FaultPlan(truncate=1.0, split=1.0))
    ack = p.encode_message(p.Ack(acked_seq=1, result=p.Result.OK, state=p.State.IDLE,
                                 sample=0), 0, 0)
    for _ in range(200):  # randrange(len(body)) gives 0 about once in len(body) draws
        emulator._send(ack)
    assert all(wire for _, wire, _ in emulator._backlog)
    assert any(wire == b"\x00" for _, wire, _ in emulator._backlog)


def test_a_realtime_session_raises_its_thread_until_it_closes(rig: Callable[..., Rig]) -> None:
    """The thread that runs a session holds the interpreter lock the reader's heartbeats
    need: it runs at SESSION_NICE while the session is open (where permitted)."""
    tid = threading.get_native_id()
    before = os.getpriority(os.PRIO_PROCESS, tid)
    _, link = rig(realtime=True)
    during = os.getpriority(os.PRIO_PROCESS, tid)
    assert gc.get_freeze_count() > 0  # the heap kept out of collections meanwhile
    link.close()
    assert os.getpriority(os.PRIO_PROCESS, tid) == before and gc.get_freeze_count() == 0
    assert during in (before, min(before, SESSION_NICE))
    if os.geteuid() == 0:
        assert during == min(before, SESSION_NICE)
