"""The bench of the MCU conformance tests (test_mcu_conformance.py, test_mcu_config.py):
either MCU, the Python model (hil.emulators.mcu_model.ModelMcu) or the C firmware's host
build on the simulated rig (hil.emulators.firmware.FirmwareMcu), driven through the
byte-level interface the rig emulator uses: host frames in, wire frames out, one tick per
period in simulated time. The fixtures ``kind`` (each MCU in turn) and ``bench`` (a session
on it) are imported by those test files.
"""

from __future__ import annotations

import shutil
from collections.abc import Iterator

import pytest

from hil.emulators.mcu_model import ModelMcu, RigHardware
from hil.emulators.rig_physics import ClampPhysics
from hil.host.backends import RigSetup
from hil.link import protocol as p

X_OPEN = RigSetup().stroke[0]
QUIET = RigHardware(x_origin=X_OPEN, load_noise_n=0.0)  # noise off: both read alike
NOISY = RigHardware(x_origin=X_OPEN)
HAVE_GCC = shutil.which("gcc") is not None


def make_mcu(kind: str, hw: RigHardware = QUIET) -> ModelMcu:
    physics = ClampPhysics("chang2021")
    if kind == "model":
        return ModelMcu(physics, hw, 3)
    from hil.emulators.firmware import FirmwareMcu

    return FirmwareMcu(physics, hw, 3)  # type: ignore[return-value]


@pytest.fixture(params=["model", pytest.param("firmware", marks=pytest.mark.skipif(
    not HAVE_GCC, reason="the firmware's host build needs gcc (Debian package gcc)"))])
def kind(request: pytest.FixtureRequest) -> str:
    return request.param


class Bench:
    """An MCU driven in simulated time: frames in, decoded messages out."""

    def __init__(self, kind: str, hw: RigHardware = QUIET) -> None:
        self.mcu = make_mcu(kind, hw)
        self.now = 100.0
        self.seq = 1000
        self.tel: list[p.Telemetry] = []
        self.events: list[p.Message] = []  # FAULT and STATE frames, in order
        self.beating = True  # a HEARTBEAT after every period, as a host sends them

    def _decode(self, wires: list[bytes]) -> list[p.Message]:
        out = []
        for wire in wires:
            assert wire.endswith(b"\x00") and b"\x00" not in wire[:-1]
            frame = p.decode_frame(wire[:-1])  # a bad CRC raises: the test fails
            assert frame.flags == 0
            out.append(p.parse_message(frame))
        return out

    def raw(self, data: bytes) -> list[p.Message]:
        """Feed bytes; the replies (ACK, HELLO_REPLY) and events they caused."""
        msgs = self._decode(self.mcu.receive(data, self.now))
        self.events += [m for m in msgs if isinstance(m, (p.FaultReport, p.StateChange))]
        return [m for m in msgs if isinstance(m, (p.Ack, p.HelloReply, p.CalibrationReply))]

    def send(self, msg: p.Message, seq: int | None = None, flags: int = p.FLAG_ACK_REQ,
             extra: bytes = b"") -> list[p.Message]:
        if seq is None:
            self.seq = (self.seq + 1) & 0xFFFF
            seq = self.seq
        frame = p.Frame(msg.TYPE, flags, seq, msg.pack() + extra)
        return self.raw(p.encode_frame(frame))

    def ack(self, msg: p.Message, seq: int | None = None, extra: bytes = b"") -> p.Ack:
        replies = self.send(msg, seq, extra=extra)
        assert len(replies) == 1, replies
        return replies[0]  # type: ignore[return-value]

    def tick(self, n: int = 1) -> p.Telemetry:
        for _ in range(n):
            self.now += 1e-3
            msgs = self._decode(self.mcu.tick(self.now))
            assert isinstance(msgs[-1], p.Telemetry)
            self.events += msgs[:-1]
            self.tel.append(msgs[-1])
            if self.beating:
                self.beat()
        return self.tel[-1]

    def silent(self, n: int = 1) -> None:
        """``n`` periods without a session: no telemetry (docs/rig-protocol.md, section 5)."""
        for _ in range(n):
            self.now += 1e-3
            msgs = self._decode(self.mcu.tick(self.now))
            assert not [m for m in msgs if isinstance(m, p.Telemetry)], msgs
            self.events += msgs

    def session(self, **config: float) -> Bench:
        """HELLO and CONFIG (a noiseless load cell reads alike for long: stuck_samples is
        raised unless given)."""
        assert self.ack(p.Hello(1, 1, 42)).result == p.Result.OK
        config.setdefault("stuck_samples", 60_000)
        assert self.ack(p.Config(**config)).result == p.Result.OK
        self.tick()
        return self

    def faults(self) -> list[tuple[int, int, int]]:
        return [(m.fault, m.value, m.limit) for m in self.events
                if isinstance(m, p.FaultReport)]

    def states(self) -> list[tuple[int, int, int]]:
        return [(m.old, m.new, m.reason) for m in self.events if isinstance(m, p.StateChange)]

    def load(self, points: list[tuple[int, int]], final: bool = True) -> None:
        for i in range(0, len(points), 30):
            last = i + 30 >= len(points)
            assert self.ack(p.TrajChunk(i, p.TrajChunk.FINAL if final and last else 0,
                                        tuple(points[i:i + 30]))).result == p.Result.OK

    def beat(self) -> None:
        self.send(p.Heartbeat(0), flags=0)


def ramp(n: int, rate: int = 100, hold: int = 0) -> list[tuple[int, int]]:
    """n points moving forward at ``rate`` steps per period, then ``hold`` points still."""
    pts = [(rate * (i + 1), p.NO_CHECK) for i in range(n)]
    return pts + [(pts[-1][0] if pts else 0, p.NO_CHECK)] * hold


@pytest.fixture
def bench(kind: str) -> Iterator[Bench]:
    yield Bench(kind).session()
