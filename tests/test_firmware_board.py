"""The rig firmware's board images (firmware/board/, docs/firmware.md).

The NUCLEO-F446RE image is built with -Werror and must link and fit the F446RE (it is not
run: no board here). The QEMU image (netduinoplus2, STM32F405) is the same core on the
simulated rig: it boots in qemu-system-arm and speaks the protocol over its pty.
"""

from __future__ import annotations

import re
import subprocess
import time
from pathlib import Path

import pytest

from hil import protocol as p
from hil.backends import RigSetup
from hil.firmware_qemu import BOARD_DIR, QemuRig, build_qemu_image, qemu_available
from hil.mcu_model import RigHardware

serial = pytest.importorskip("serial")

NUCLEO_OUT = Path(__file__).resolve().parent.parent / "build" / "firmware" / "board-nucleo"
FLASH_BYTES = 512 * 1024  # STM32F446RE
RAM_BYTES = 128 * 1024


def _skip_unless(need_qemu: bool) -> None:
    missing = qemu_available(need_qemu)
    if missing:
        pytest.skip(f"needs the Debian packages: {' '.join(missing)}")


def _section_sizes(elf: Path) -> dict[str, int]:
    out = subprocess.run(["arm-none-eabi-size", "-A", str(elf)], capture_output=True,
                         text=True, check=True).stdout
    sizes = {}
    for line in out.splitlines():
        parts = line.split()
        if len(parts) == 3 and parts[0].startswith("."):
            sizes[parts[0]] = int(parts[1])
    return sizes


def test_nucleo_image_links_and_fits() -> None:
    _skip_unless(need_qemu=False)
    result = subprocess.run(["make", "-s", "-C", str(BOARD_DIR), "nucleo"],
                            capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "warning" not in result.stderr.lower(), result.stderr
    elf = NUCLEO_OUT / "rig.elf"
    sizes = _section_sizes(elf)
    flash = sum(sizes.get(s, 0) for s in (".isr_vector", ".text", ".rodata", ".ARM.exidx",
                                          ".data"))
    ram = sum(sizes.get(s, 0) for s in (".data", ".bss", ".noinit"))
    assert 0 < flash < FLASH_BYTES
    assert 0 < ram < RAM_BYTES
    assert (NUCLEO_OUT / "rig.bin").stat().st_size > 0
    assert (NUCLEO_OUT / "rig.map").is_file()
    assert list((NUCLEO_OUT / "obj").glob("*.su")), "no -fstack-usage output"


class _Port:
    """The host's end of the pty: frames out, messages in."""

    def __init__(self, path: str) -> None:
        self.ser = serial.Serial(path, 921600, timeout=0.05)
        self.decoder = p.FrameDecoder()
        self.seq = 0x1234

    def send(self, msg: p.Message, flags: int = p.FLAG_ACK_REQ) -> int:
        self.seq = (self.seq + 1) & 0xFFFF
        self.ser.write(p.encode_message(msg, self.seq, flags))
        return self.seq

    def read(self) -> list[p.Message]:
        data = self.ser.read(4096)
        return [p.parse_message(f) for f in self.decoder.feed(data)]

    def close(self) -> None:
        self.ser.close()


@pytest.fixture(scope="module")
def qemu_elf() -> Path:
    _skip_unless(need_qemu=True)
    return build_qemu_image(RigSetup(), RigHardware(), seed=7)


def test_qemu_image_hello_and_telemetry(qemu_elf: Path) -> None:
    with QemuRig(qemu_elf) as rig:
        assert re.fullmatch(r"/dev/pts/\d+", rig.port)
        port = _Port(rig.port)
        try:
            # Bytes that arrive before the firmware enables its USART are lost (QEMU drops
            # them, as the real UART would): HELLO is sent again every 100 ms, as a host
            # retransmits an unanswered command.
            nonce = 0x5EED1234
            reply: p.HelloReply | None = None
            deadline = time.monotonic() + 5.0
            while reply is None and time.monotonic() < deadline:
                port.ser.write(b"\x00")
                seq = port.send(p.Hello(host_nonce=nonce))
                resend = time.monotonic() + 0.1
                while reply is None and time.monotonic() < resend:
                    for msg in port.read():
                        if isinstance(msg, p.HelloReply) and msg.acked_seq == seq:
                            reply = msg
            assert reply is not None, "no HELLO_REPLY within 5 s"
            assert reply.result == p.Result.OK
            assert (reply.acked_seq, reply.host_nonce) == (seq, nonce)
            assert reply.state == p.State.IDLE and reply.boot_id != 0
            assert (reply.load_offset, reply.load_gain_n) == (1500, pytest.approx(1e-4))
            # Telemetry over 1 s of wall time, heartbeats every 20 ms as a host sends them.
            samples: list[p.Telemetry] = []
            start = time.monotonic()
            last_beat = start
            while (now := time.monotonic()) - start < 1.0:
                if now - last_beat >= 0.02:
                    port.send(p.Heartbeat(host_ms=int(now * 1e3) & 0xFFFF_FFFF), flags=0)
                    last_beat = now
                samples += [m for m in port.read() if isinstance(m, p.Telemetry)]
            samples += [m for m in port.read() if isinstance(m, p.Telemetry)]
        finally:
            port.close()
    assert samples, "no telemetry"
    numbers = [s.sample for s in samples]
    assert numbers == list(range(numbers[0], numbers[0] + len(numbers))), "gap in sample"
    assert {s.boot_id for s in samples} == {reply.boot_id}
    assert all(s.t_us == s.sample * 1000 for s in samples)  # the period's scheduled time
    assert all(s.state == p.State.IDLE and s.flags & p.TelemetryFlag.SESSION for s in samples)
    # QEMU's SysTick follows the host's clock: 1000 samples in 1 s of wall time, within
    # 15 % (QEMU and this reader share two loaded cores; a tick that QEMU delivers late
    # is caught up, not lost, so the count stays near 1000).
    assert 850 <= len(samples) <= 1150, len(samples)
