"""Bring-up on the emulator (hil/host/bringup.py, docs/bring-up.md): the emulated rig's cell
has a true offset and gain of its own, its encoder may count backwards and its drive may
lose steps (hil emulate --cell-offset --cell-gain --reverse-encoder --drop-every); tare and
span recover the cell, the stored calibration survives a reboot, the sensor check names
the faults. On the Python MCU model and on the C firmware's host build.
"""

from __future__ import annotations

import math
import shutil
import statistics
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from hil.emulators.mcu_model import RigHardware
from hil.emulators.rig_emulator import RigEmulator
from hil.emulators.rig_physics import ClampPhysics
from hil.host import bringup
from hil.host.backends import RigSetup
from hil.host.homing import home
from hil.link import protocol as p
from hil.link.serial_link import SerialLink

pytestmark = pytest.mark.real_time  # emulators on ptys, against the wall clock

X_OPEN = RigSetup().stroke[0]
#: The host's telemetry watchdog in these tests, s: a soft bound (the MCU's are the hard
#: ones) widened so that a loaded test machine's scheduling is not taken for a rig stall.
WATCHDOG = 0.5
CELL_OFFSET, CELL_GAIN = -23_456, 1.2e-4
HAVE_GCC = shutil.which("gcc") is not None
KINDS = ["model", pytest.param("firmware", marks=pytest.mark.skipif(
    not HAVE_GCC, reason="the firmware's host build needs gcc"))]


@contextmanager
def rig(kind: str, nvm: Path | None = None, **hw: object) -> Iterator[tuple[RigEmulator,
                                                                          SerialLink]]:
    """An emulated rig with the given RigHardware fields, homed, in an open session."""
    hardware = RigHardware(x_origin=X_OPEN, cell_offset=CELL_OFFSET, cell_gain_n=CELL_GAIN,
                           **hw)  # type: ignore[arg-type]
    with RigEmulator(ClampPhysics("chang2021"), hardware, firmware=kind == "firmware",
                     nvm=nvm) as emu:
        port = emu.start()
        with SerialLink(port, telemetry_timeout=WATCHDOG) as link:
            link.open()
            home(link)
            yield emu, link


def rest_force(emu: RigEmulator) -> float:
    """The plant's true input force at rest (N; the clamp's own, without the cell's noise):
    the tare's zero is the cell's offset plus this."""
    mcu = emu.mcu
    if hasattr(mcu, "sim_status"):
        return float(mcu.sim_status()["input_force"])
    return float(mcu.model.sensors.force)


@pytest.mark.parametrize("kind", KINDS)
def test_tare_and_span_recover_the_cells_offset_and_gain(kind: str) -> None:
    """Within the mean's noise (4 sigma of the mean of N readings); implausible spans refused."""
    with rig(kind) as (emu, link):
        tare = bringup.tare(link, 500)
        sigma_counts = tare.noise / link.scaling.load_gain_n  # one reading, counts
        zero = CELL_OFFSET + rest_force(emu) / CELL_GAIN
        assert abs(tare.offset - zero) <= 4 * sigma_counts / math.sqrt(500) + 1, (tare, zero)
        assert 0.15 < tare.noise * CELL_GAIN / 1e-4 < 0.25  # 0.2 N, read with gain 1e-4

        emu.mcu.force_spike(50.0, 10**9)  # a 50 N load on the cell, held
        span = bringup.span(link, 50.0, offset=tare.offset)
        signal = 50.0 / CELL_GAIN
        assert span.gain == pytest.approx(CELL_GAIN, rel=8 * sigma_counts / math.sqrt(500)
                                          / signal)
        assert span.noise == pytest.approx(0.2, rel=0.25)
        with pytest.raises(bringup.BringupError, match="implausible"):
            bringup.span(link, 500.0, offset=tare.offset)  # 10x the force: gain 10x
        with pytest.raises(bringup.BringupError, match="other way"):
            bringup.span(link, -50.0, offset=tare.offset)
        emu.mcu.force_spike(0.0, 0)
        with pytest.raises(bringup.BringupError, match="noise"):
            bringup.span(link, 50.0, offset=tare.offset)  # no load on the cell
        assert bringup.span_from_mass(5.0) == pytest.approx(49.03325)


@pytest.mark.parametrize("kind", KINDS)
def test_the_stored_calibration_survives_a_reboot(kind: str, tmp_path: Path) -> None:
    """store_calibration writes and reads back; after an MCU reset (and, on the host build,
    a new emulator on the same memory file) the new session uses it."""
    nvm = tmp_path / "nvm.bin" if kind == "firmware" else None
    with rig(kind, nvm) as (emu, link):
        assert bringup.read_calibration(link).cal_seq == 0
        stored = bringup.store_calibration(link, -23_000, 1.19e-4)
        assert (stored.cal_seq, stored.offset) == (1, -23_000)
        assert stored.gain == pytest.approx(1.19e-4, rel=1e-7)
        assert link.scaling.load_offset == -23_000  # in use at once
        with pytest.raises(bringup.BringupError, match="gain"):
            bringup.store_calibration(link, 0, -1.0)
    if nvm is not None:  # power off: a new process image of the firmware, same memory
        with rig(kind, nvm) as (emu, link):
            assert bringup.read_calibration(link) == stored
            assert (link.info.load_offset, link.info.load_gain_n) == (stored.offset,
                                                                      stored.gain)
        return
    with rig(kind) as (emu, link):
        bringup.store_calibration(link, -23_000, 1.19e-4)
        link.close()
        emu.mcu.reset()
        with SerialLink(emu.port, telemetry_timeout=WATCHDOG) as again:
            again.open()
            assert bringup.read_calibration(again) == stored
            assert again.info.load_offset == -23_000


@pytest.mark.parametrize("kind", KINDS)
def test_the_sensor_check_names_a_reversed_encoder_and_lost_steps(kind: str) -> None:
    """A sound rig passes; a reversed encoder and a drive losing every 10th step fail on
    the items that name them, the other items passing."""
    check = {"distance": 1e-3, "speed": 2e-3}
    with rig(kind) as (_, link):
        report = bringup.sensor_check(link, **check)
        assert report.passed, report
        assert abs(report.item("lost steps").figure or 0) < 0.03 * 5000
    with rig(kind, encoder_sign=-1) as (_, link):
        report = bringup.sensor_check(link, **check)
        failed = {i.name for i in report.items if not i.passed}
        assert failed == {"encoder direction", "encoder counts per step", "lost steps"}
        assert "REVERSED" in report.item("encoder direction").text
    with rig(kind, drop_steps=(1, 10)) as (_, link):
        report = bringup.sensor_check(link, **check)
        failed = {i.name for i in report.items if not i.passed}
        assert failed == {"encoder counts per step", "lost steps"}, report
        lost = report.item("lost steps").figure
        assert lost == pytest.approx(500, abs=0.03 * 5000)  # 10 % of 5000 steps
        assert report.to_dict()["items"][2]["name"] == "lost steps"


def test_jog_moves_within_the_limits_and_refuses_outside(kind: str = "model") -> None:
    with rig(kind) as (_, link):
        result = bringup.jog(link, to=3e-3)
        assert result.end == pytest.approx(3e-3, abs=1e-9)
        assert bringup.jog(link, by=-1e-3).end == pytest.approx(2e-3, abs=1e-9)
        for kwargs in ({"to": 0.5}, {"to": 1e-3, "by": 1e-3}, {"by": 1e-3, "speed": 1.0},
                       {"to": math.nan}):
            with pytest.raises(bringup.BringupError):
                bringup.jog(link, **kwargs)  # type: ignore[arg-type]
        assert link.status.steps == round(2e-3 / 200e-9)  # nothing moved


def test_tare_refuses_a_rig_that_moves_or_is_faulted() -> None:
    with rig("model") as (emu, link):
        with pytest.raises(bringup.BringupError, match="samples"):
            bringup.tare(link, 3)
        link.estop()
        with pytest.raises(bringup.BringupError, match="ESTOP"):
            bringup.tare(link)
        link.clear_fault()
        raw = [link.next_sample().load_raw for _ in range(50)]
        assert statistics.stdev(raw) > 0  # a live cell
        assert p.State(link.status.state) == p.State.IDLE
