"""Rig emulator: the MCU's side of the rig protocol on a pseudo-terminal, with fault injection.

:class:`RigEmulator` opens a pty (``os.openpty``), runs an MCU at the telemetry rate and
speaks the protocol of docs/rig-protocol.md to whoever opens the pty's device path
(``SerialLink(emulator.port)``). The MCU is the Python model
(:class:`~hil.emulators.mcu_model.ModelMcu`, the default) or the C firmware's host build
(:class:`~hil.emulators.firmware.FirmwareMcu`, ``firmware=True``): both take bytes and return wire
frames, so the emulator's link faults and its log are the same for both. The mechanics
are a pluggable :class:`~hil.emulators.rig_hardware.RigPhysics` (the firmware's is the native
FMU of a :class:`~hil.emulators.rig_physics.ClampPhysics`); :class:`FaultPlan` injects link
and rig faults. Run it in a thread (:meth:`RigEmulator.start`) or in a process of its own
(:func:`spawn_emulator`).
"""

from __future__ import annotations

import contextlib
import math
import multiprocessing as mp
import os
import random
import select
import threading
import time
import tty
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from hil.emulators.mcu_model import ModelMcu, RigHardware, RigPhysics
from hil.link import protocol as p
from hil.link.realtime import set_realtime

#: s behind schedule up to which missed ticks are caught up (a late wake-up of this
#: process). A longer lag (a loaded or paused machine that descheduled the emulator) is
#: not caught up: the MCU's clock, its tick count, pauses with the emulator, as a real
#: MCU's never would; catching up would run its watchdogs over host frames that were
#: already waiting, all read before the first of the caught-up ticks (HEARTBEAT_LOST).
CATCH_UP_MAX = 0.02
TX_BACKLOG_MAX = 16_384  # bytes queued for a host that does not read; further frames drop
#: Periods a controlled stop may take after a disconnect before the emulator gives up on it
#: (a stop from 50 mm/s at 1 m/s^2 takes 50).
STOP_PERIODS_MAX = 10_000


@dataclass(frozen=True)
class FaultPlan:
    """Faults to inject. Probabilities are per frame; times are s after the first START."""

    seed: int = 1
    drop_byte: float = 0.0  # remove one byte of an outgoing frame
    flip_bit: float = 0.0  # flip one bit of an outgoing frame
    truncate: float = 0.0  # cut an outgoing frame short (its delimiter still follows)
    split: float = 0.0  # write an outgoing frame in two parts, 0.3 ms apart (harmless)
    junk: float = 0.0  # random bytes and a delimiter before an outgoing frame
    drop_frame: float = 0.0  # an outgoing frame is not sent at all
    duplicate: float = 0.0  # an outgoing frame is sent twice
    noise_until: float = math.inf  # the probabilities above apply until then (s after START)
    rx_drop_byte: float = 0.0  # remove one byte of an incoming read
    rx_flip_bit: float = 0.0  # flip one bit of an incoming read
    stall_at: float | None = None  # the MCU hangs: no telemetry, no input processing
    stall_for: float = 0.05
    estop_at: float | None = None  # the rig's stop input latches ESTOP (operator's button)
    disconnect_at: float | None = None  # the link vanishes (pty closed)
    reconnect_after: float | None = None  # then a new pty appears after this many s (re-plug)
    reset_at: float | None = None  # the MCU resets: new boot id, no session, counts at 0
    force_spike_at: float | None = None  # add force_spike_n to the load cell
    force_spike_n: float = 1000.0
    force_spike_samples: int = 3
    stuck_load_at: float | None = None  # the load-cell reading freezes
    stuck_encoder_at: float | None = None  # the encoder reading freezes
    stuck_for: float | None = None  # a stuck reading recovers after this many s (None: never)


#: A fault plan without link noise (what the link is once FaultPlan.noise_until has passed).
CLEAN_LINK = FaultPlan()


@dataclass
class EmulatorLog:
    """What the emulator did, for tests and benchmarks (times are time.monotonic())."""

    commands: list[tuple[float, p.MsgType]] = field(default_factory=list)
    injected: dict[str, float] = field(default_factory=dict)  # fault name -> time injected
    sent_telemetry: dict[tuple[int, int], p.Telemetry] = field(default_factory=dict)
    #: every telemetry frame written to the pty: (boot_id, sample, state, intact), in order;
    #: intact is False when the fault plan damaged the frame (the host cannot decode it)
    written: list[tuple[int, int, int, bool]] = field(default_factory=list)
    run_starts: list[tuple[int, int]] = field(default_factory=list)  # (boot_id, first sample)
    tx_frames: int = 0
    tx_dropped: int = 0  # frames dropped because the host did not read
    paused: float = 0.0  # s the emulator was descheduled beyond CATCH_UP_MAX (MCU time paused)

    def first_command(self, kind: p.MsgType, after: float = 0.0) -> float | None:
        """Time the first command of ``kind`` arrived at or after ``after``."""
        return next((t for t, k in self.commands if k == kind and t >= after), None)


class RigEmulator:
    """The rig's MCU on a pseudo-terminal; :attr:`port` is the path a host opens."""

    def __init__(
        self,
        physics: RigPhysics,
        hardware: RigHardware | None = None,
        faults: FaultPlan | None = None,
        *,
        record_telemetry: bool = False,
        realtime: bool = False,
        firmware: bool = False,
        nvm: Path | None = None,
        step_timing: str = "at-once",
    ) -> None:
        """``realtime`` asks for SCHED_FIFO scheduling of the serving thread, as a
        firmware's timer interrupt would have (best effort: ignored without the
        permission). ``firmware``: the MCU is the C firmware's host build on the
        simulated rig (``physics`` a :class:`~hil.emulators.rig_physics.ClampPhysics`), not the
        Python model; ``nvm``: with ``firmware``, the file that is the MCU's non-volatile
        memory (the stored calibration; default: memory only, which survives a reset);
        ``step_timing``: its table's timing (:data:`hil.emulators.firmware.STEP_TIMINGS`).
        """
        self.hw = hardware or RigHardware()
        self.faults = faults or FaultPlan()
        self._rng = random.Random(self.faults.seed)
        if firmware:
            from hil.emulators.firmware import FirmwareMcu

            self.mcu: ModelMcu | FirmwareMcu = FirmwareMcu(
                physics, self.hw, self.faults.seed + 1, nvm_path=nvm, step_timing=step_timing)
        else:
            self.mcu = ModelMcu(physics, self.hw, self.faults.seed + 1)
        self.log = EmulatorLog()
        self._record = record_telemetry
        self._realtime = realtime
        self._decoder = p.FrameDecoder()  # the host's frames, for the log
        # (release time, bytes, telemetry (boot_id, sample, state, intact) or None), in order
        self._backlog: list[tuple[float, bytes, tuple[int, int, int, bool] | None]] = []
        self._master = self._slave = -1
        self.port = ""
        self.on_port: Callable[[str], None] | None = None  # told the path of a re-plugged pty
        self._reconnect_at: float | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._run_tick: int | None = None  # tick of the first START
        self._tick = 0
        self._start_seq: int | None = None  # seq of the last START received
        self._recoveries: list[tuple[int, Callable[[bool], None]]] = []  # (tick, un-stick)
        self._pending = {
            name: at for name in ("stall", "disconnect", "reset", "force_spike", "stuck_load",
                                  "stuck_encoder", "estop")
            if (at := getattr(self.faults, f"{name}_at")) is not None
        }

    # --- lifecycle ------------------------------------------------------------------------

    def open(self) -> str:
        """Create the pseudo-terminal; return the device path for the host."""
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)  # no echo, no line editing, no CR/LF translation
        os.set_blocking(self._master, False)
        self.port = os.ttyname(self._slave)
        return self.port

    def start(self) -> str:
        """Open the pty and serve it from a daemon thread; return the device path."""
        port = self.open()
        self._thread = threading.Thread(target=self.serve, name="rig-emulator", daemon=True)
        self._thread.start()
        return port

    def close(self) -> None:
        """Stop serving and close the pty (idempotent)."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        self._close_fds()

    def __enter__(self) -> RigEmulator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _close_fds(self) -> None:
        for fd in (self._master, self._slave):
            if fd >= 0:
                os.close(fd)
        self._master = self._slave = -1

    # --- main loop ------------------------------------------------------------------------

    def serve(self) -> None:
        """Run the MCU until close() or an injected disconnect (without a re-plug)."""
        if self._master < 0:
            self.open()
        if self._realtime:
            set_realtime()
        period = self.hw.period
        next_tick = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            if self._master < 0:
                if self._reconnect_at is None:
                    return
                if now >= self._reconnect_at:
                    self._reconnect_at = None
                    self.open()
                    if self.on_port is not None:
                        self.on_port(self.port)
                    next_tick = now
                else:
                    time.sleep(1e-3)
                continue
            release = self._next_release()
            ready = release <= now  # something to write: wake when the pty can take it
            wait = max(0.0, min(next_tick, float("inf") if ready else release) - now)
            readable, _, _ = select.select([self._master], [self._master] if ready else [], [],
                                           wait)
            if readable:
                self._receive()
            now = time.monotonic()
            if now >= next_tick:
                if now - next_tick > CATCH_UP_MAX:
                    self.log.paused += now - next_tick
                    next_tick = now
                next_tick += self._on_tick(now, next_tick) + period
            self._flush()

    def _on_tick(self, now: float, nominal: float) -> float:
        """One MCU period at its nominal time; returns the time the MCU hung (a stall).

        The MCU stamps the period with its nominal time (since its boot), as a firmware's
        timer interrupt does: the emulator's own scheduling jitter is not the MCU's. A
        stall skips the periods it hangs through, so it shows as a jump of t_us between
        consecutive samples.
        """
        hung = self._inject_scheduled(now)
        if self._master < 0:
            return hung
        for due, unstick in [r for r in self._recoveries if r[0] <= self._tick]:
            self._recoveries.remove((due, unstick))
            unstick(False)
        for wire in self.mcu.tick(nominal + hung - self.log.paused):  # the MCU's clock
            self._send(wire)
        self._tick += 1
        return hung

    def _receive(self) -> None:
        try:
            data = os.read(self._master, 4096)
        except BlockingIOError:
            return
        except OSError:  # the host side vanished; a pty then reports EIO
            data = b""
        if self._noisy():
            data = self._corrupt(data, self.faults.rx_drop_byte, self.faults.rx_flip_bit)
        now = time.monotonic()
        for frame in self._decoder.feed(data):
            self.log.commands.append((now, _msg_type(frame.msg_type)))
            if frame.msg_type == p.MsgType.START:
                self._start_seq = frame.seq
                if self._run_tick is None:
                    self._run_tick = self._tick
        for wire in self.mcu.receive(data, now - self.log.paused):
            self._send(wire)

    # --- fault injection ------------------------------------------------------------------

    def _inject_scheduled(self, now: float) -> float:
        """Inject the faults that are due; return the time the MCU hung (0 without a stall)."""
        if self._run_tick is None:
            return 0.0
        elapsed = (self._tick - self._run_tick) * self.hw.period
        hung = 0.0
        for name, at in list(self._pending.items()):
            if elapsed >= at:
                del self._pending[name]
                self.log.injected[name] = now
                hung += getattr(self, f"_inject_{name}")() or 0.0
        return hung

    def _inject_stall(self) -> float:
        time.sleep(self.faults.stall_for)  # the whole MCU hangs, as a blocked firmware would
        return self.faults.stall_for

    def _inject_estop(self) -> None:
        self.mcu.press_stop()

    def _inject_disconnect(self) -> None:
        self._close_fds()
        self._backlog.clear()
        self.mcu.link_lost()
        t = time.monotonic()
        for _ in range(STOP_PERIODS_MAX):  # the firmware completes its stop alone
            if self.mcu.state != p.State.STOPPING:
                break
            t += self.hw.period
            self.mcu.tick(t)
        else:
            raise RuntimeError(f"the MCU did not come to a standstill in {STOP_PERIODS_MAX} "
                               "periods after the link was lost")
        if self.faults.reconnect_after is not None:
            self._reconnect_at = time.monotonic() + self.faults.reconnect_after

    def _inject_reset(self) -> None:
        self.mcu.reset()
        self._backlog.clear()

    def _inject_force_spike(self) -> None:
        self.mcu.force_spike(self.faults.force_spike_n, self.faults.force_spike_samples)

    def _inject_stuck_load(self) -> None:
        self.mcu.stick_load(True)
        self._schedule_recovery(self.mcu.stick_load)

    def _inject_stuck_encoder(self) -> None:
        self.mcu.stick_encoder(True)
        self._schedule_recovery(self.mcu.stick_encoder)

    def _schedule_recovery(self, stick: Callable[[bool], None]) -> None:
        """Free a stuck reading after FaultPlan.stuck_for, in the serving loop's time."""
        if self.faults.stuck_for is not None:
            self._recoveries.append((self._tick + round(self.faults.stuck_for
                                                        / self.hw.period), stick))

    def _noisy(self) -> bool:
        """Whether the per-frame link faults still apply (FaultPlan.noise_until)."""
        if self._run_tick is None:
            return True
        return (self._tick - self._run_tick) * self.hw.period < self.faults.noise_until

    def _corrupt(self, data: bytes, drop: float, flip: float) -> bytes:
        """Drop one byte and/or flip one bit of ``data`` with the given probabilities."""
        if not data or not (drop or flip):
            return data
        buf = bytearray(data)
        if self._rng.random() < drop:
            del buf[self._rng.randrange(len(buf))]
        if buf and self._rng.random() < flip:
            buf[self._rng.randrange(len(buf))] ^= 1 << self._rng.randrange(8)
        return bytes(buf)

    # --- transmit -------------------------------------------------------------------------

    def _send(self, original: bytes) -> None:
        """Queue one wire frame of the MCU's, through the fault plan's link faults."""
        self.log.tx_frames += 1
        if sum(len(b) for _, b, _ in self._backlog) > TX_BACKLOG_MAX:
            self.log.tx_dropped += 1
            return
        msg = _mcu_message(original)
        if isinstance(msg, p.Telemetry) and self._record:
            self.log.sent_telemetry[(msg.boot_id, msg.sample)] = msg
        if isinstance(msg, p.Ack) and msg.result == p.Result.OK and self._acks_start(msg):
            self.log.run_starts.append((self.mcu.boot_id, msg.sample))
        f, rng, now = self.faults, self._rng, time.monotonic()
        if not self._noisy():
            f = CLEAN_LINK
        if rng.random() < f.drop_frame:
            return
        if rng.random() < f.junk:
            self._backlog.append((now, rng.randbytes(rng.randrange(1, 40)) + b"\x00", None))
        body = self._corrupt(original[:-1], f.drop_byte, f.flip_bit)
        if rng.random() < f.truncate:
            body = body[: rng.randrange(len(body))]
        wire = body + b"\x00"
        tel = ((msg.boot_id, msg.sample, msg.state, wire == original)
               if isinstance(msg, p.Telemetry) else None)
        if len(wire) > 1 and rng.random() < f.split:  # a frame truncated to its 0 stays whole
            cut = rng.randrange(1, len(wire))
            self._backlog += [(now, wire[:cut], None), (now + 3e-4, wire[cut:], tel)]
        else:
            self._backlog.append((now, wire, tel))
        if rng.random() < f.duplicate:
            self._backlog.append((now, wire, None))

    def _acks_start(self, ack: p.Ack) -> bool:
        """Whether ``ack`` answers the last START the host sent."""
        return ack.acked_seq == self._start_seq and ack.state == p.State.RUNNING

    def _next_release(self) -> float:
        return self._backlog[0][0] if self._backlog else float("inf")

    def _flush(self) -> None:
        now = time.monotonic()
        while self._backlog and self._backlog[0][0] <= now and self._master >= 0:
            release, data, tel = self._backlog[0]
            try:
                written = os.write(self._master, data)
            except BlockingIOError:
                return
            except OSError:  # the host side closed the pty: nothing more gets out
                self._backlog.clear()
                return
            if written < len(data):
                self._backlog[0] = (release, data[written:], tel)
                return
            self._backlog.pop(0)
            if tel is not None:
                self.log.written.append(tel)


def _mcu_message(wire: bytes) -> p.Message | None:
    """The message of one of the MCU's wire frames (None if it is not one we know)."""
    try:
        return p.parse_message(p.decode_frame(wire[:-1]))
    except p.ProtocolError:
        return None


def _msg_type(code: int) -> p.MsgType | int:
    try:
        return p.MsgType(code)
    except ValueError:
        return code


# --- in a process of its own -------------------------------------------------------------


class EmulatorProcess:
    """An emulator served by a child process; :attr:`port` is its pty path."""

    def __init__(self, process: mp.process.BaseProcess, port: str, stop: mp.synchronize.Event,
                 pipe: mp.connection.Connection) -> None:
        self.process, self._port, self._stop, self._pipe = process, port, stop, pipe
        self.log: EmulatorLog | None = None

    @property
    def port(self) -> str:
        """The pty path a host opens (a new one after a re-plugged disconnect)."""
        while self.log is None and self._pipe.poll():
            self._take(self._pipe.recv())
        return self._port

    def _take(self, item: object) -> None:
        if isinstance(item, str):
            self._port = item
        elif isinstance(item, EmulatorLog):
            self.log = item

    def close(self) -> EmulatorLog | None:
        """Ask the child to stop, collect its :class:`EmulatorLog`, make sure it has ended."""
        self._stop.set()
        with contextlib.suppress(EOFError, OSError):
            while self.log is None and self._pipe.poll(5.0):
                self._take(self._pipe.recv())
        self.process.join(timeout=2.0)
        if self.process.is_alive():
            self.process.terminate()
            self.process.join(timeout=2.0)
        return self.log

    def __enter__(self) -> EmulatorProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _child(physics: RigPhysics, hardware: RigHardware | None, faults: FaultPlan | None,
           firmware: bool, realtime: bool, ports: mp.connection.Connection,
           stop: mp.synchronize.Event) -> None:
    emulator = RigEmulator(physics, hardware, faults, firmware=firmware, realtime=realtime)
    emulator.on_port = ports.send
    ports.send(emulator.start())
    stop.wait()
    emulator.close()
    ports.send(emulator.log)


def spawn_emulator(
    physics: RigPhysics,
    hardware: RigHardware | None = None,
    faults: FaultPlan | None = None,
    *,
    firmware: bool = False,
    realtime: bool = False,
    timeout: float = 30.0,
) -> EmulatorProcess:
    """Start an emulator in a new (spawned) process; ``physics`` must be picklable.
    ``firmware``: the C firmware's host build is the MCU (:class:`RigEmulator`)."""
    ctx = mp.get_context("spawn")
    here, there = ctx.Pipe()
    stop = ctx.Event()
    args = (physics, hardware, faults, firmware, realtime, there, stop)
    proc = ctx.Process(target=_child, args=args, name="rig-emulator", daemon=True)
    proc.start()
    if not here.poll(timeout):
        proc.terminate()
        raise RuntimeError("the emulator process did not report its port")
    return EmulatorProcess(proc, here.recv(), stop, here)
