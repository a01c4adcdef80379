"""Worst-case tick of the QEMU image (docs/firmware-emulated.md, "Measured").

Boots the image under ``-icount shift=0`` (one guest instruction per ns of virtual time),
opens a session, streams a run forward and back (enc_expected unchecked) with heartbeats,
then a STOP in motion, CLEAR_FAULT and an ESTOP, and reads board_tick_stats through QEMU's
monitor. SysTick counts at the emulated 168 MHz: one count is 1000/168 ns of virtual time,
that is 5.95 guest instructions.

    python firmware/board/measure_tick.py [build/firmware/board-qemu-.../rig.elf]
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import serial

from hil.emulators.firmware_qemu import QemuRig, build_qemu_image, symbol_address
from hil.emulators.mcu_model import RigHardware
from hil.host.backends import RigSetup
from hil.link import protocol as p

FIELDS = ("magic", "counts_per_ms", "ticks", "late_ticks", "tick_max", "sim_max", "core_max",
          "step_at_max", "rx_max", "rx_bytes", "tx_bytes", "tick_max_state")
INSTR_PER_COUNT = 1e9 / 168e6  # -icount shift=0: 1 instruction per ns; SysTick at 168 MHz


def trajectory(n: int = 3000, peak: int = 200) -> list[int]:
    """Steps of a smooth out-and-back move: speed up to ``peak`` steps per period."""
    out, pos = [], 0.0
    for i in range(n):
        speed = peak * math.sin(2 * math.pi * i / n)  # forward, then back
        pos += speed
        out.append(round(pos))
    return out


class Host:
    def __init__(self, port: str) -> None:
        self.ser = serial.Serial(port, 921600, timeout=0.01)
        self.dec = p.FrameDecoder()
        self.seq = 100
        self.last: p.Telemetry | None = None
        self.acks: dict[int, p.Message] = {}
        self.events: list[p.Message] = []
        self.beat = 0.0

    def send(self, msg: p.Message, flags: int = p.FLAG_ACK_REQ) -> int:
        self.seq = (self.seq + 1) & 0xFFFF
        self.ser.write(p.encode_message(msg, self.seq, flags))
        return self.seq

    def poll(self) -> None:
        for f in self.dec.feed(self.ser.read(8192)):
            m = p.parse_message(f)
            if isinstance(m, p.Telemetry):
                self.last = m
            elif isinstance(m, (p.Ack, p.HelloReply)):
                self.acks[m.acked_seq] = m
            else:
                self.events.append(m)
        if time.monotonic() - self.beat > 0.02:
            self.send(p.Heartbeat(), flags=0)
            self.beat = time.monotonic()

    def command(self, msg: p.Message, timeout: float = 2.0) -> p.Message:
        for _ in range(10):
            seq = self.send(msg)
            end = time.monotonic() + timeout / 10
            while time.monotonic() < end:
                self.poll()
                if seq in self.acks:
                    return self.acks.pop(seq)
        raise RuntimeError(f"no answer to {msg}")


def run(elf: Path) -> dict[str, int]:
    with QemuRig(elf, icount=True, monitor=True) as rig:
        host = Host(rig.port)
        assert host.command(p.Hello(host_nonce=1)).result == p.Result.OK
        assert host.command(p.Config(force_limit_n=490.0)).result == p.Result.OK
        steps = trajectory()
        sent = 0
        started = False
        while True:
            host.poll()
            done = host.last.exec_index if host.last and started else 0
            while sent < len(steps) and sent - done + 30 <= 2048:
                pts = tuple((s, p.NO_CHECK) for s in steps[sent:sent + 30])
                final = p.TrajChunk.FINAL if sent + len(pts) == len(steps) else 0
                ack = host.command(p.TrajChunk(sent, final, pts))
                if ack.result != p.Result.OK:
                    break
                sent += len(pts)
            if not started:
                assert host.command(p.Start()).result == p.Result.OK
                started = True
            t = host.last
            if t and t.state not in (p.State.RUNNING, p.State.STOPPING) and t.exec_index > 0:
                break
        print(f"run ended: state {p.State(host.last.state).name}, exec_index "
              f"{host.last.exec_index} of {len(steps)}, faults {host.last.faults:#x}")
        # a stop in motion, then clear, then ESTOP
        host.command(p.ClearFault())
        assert host.command(p.TrajChunk(0, 0, tuple((200 * (k + 1), p.NO_CHECK)
                                                     for k in range(30)))).result == p.Result.OK
        host.command(p.Start())
        time.sleep(0.05)
        host.command(p.Stop())
        end = time.monotonic() + 1.0
        while time.monotonic() < end:
            host.poll()
        host.command(p.EStop())
        host.command(p.ClearFault())
        end = time.monotonic() + 0.5
        while time.monotonic() < end:
            host.poll()
        words = rig.read_words(symbol_address(elf, "board_tick_stats"), len(FIELDS))
        brk = rig.read_words(symbol_address(elf, "brk.0"), 1)[0]
    stats = dict(zip(FIELDS, words))
    stats["heap_used_bytes"] = brk - symbol_address(elf, "__heap_start")
    return stats


def main() -> None:
    elf = Path(sys.argv[1]) if len(sys.argv) > 1 else build_qemu_image(
        RigSetup(), RigHardware(), seed=7)
    stats = run(elf)
    for name, value in stats.items():
        extra = ""
        if name.endswith("_max") and name != "tick_max_state":
            extra = f"  = {value * INSTR_PER_COUNT:9.0f} instructions (ns at -icount shift=0)"
        print(f"{name:15s} {value:10d}{extra}")


if __name__ == "__main__":
    main()
