"""``hil emulate``: a rig without hardware on a pseudo-terminal (the MCU model, the firmware's
host build, QEMU or the rehosted NUCLEO image), serving until a signal."""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from dataclasses import replace
from typing import Any

from hil.cli import rig as cli_rig
from hil.cli.interrupts import Interrupted, SignalGuard
from hil.host.backends import RigSetup
from hil.host.run_settings import check_mold
from toggle.files import atomic_path
from toggle.params import ParameterError


def emulate(args: argparse.Namespace) -> int:
    from hil.emulators.mcu_model import RigHardware
    from hil.emulators.rig_emulator import FaultPlan, RigEmulator
    from hil.emulators.rig_physics import ClampPhysics

    setup = RigSetup(preset=args.preset, delta_r8=args.delta_r8, mu=args.mu)
    if args.x_contact == "planned":
        setup = replace(setup, x_contact=setup.planned_mold)
    elif args.x_contact is not None:
        check_mold(args.preset, args.x_contact)
        setup = replace(setup, x_contact=args.x_contact)
    faults = FaultPlan(drop_byte=args.drop_byte, flip_bit=args.flip_bit, junk=args.junk,
                       stall_at=args.stall_at, reset_at=args.reset_at, estop_at=args.estop_at,
                       disconnect_at=args.disconnect_at, seed=args.seed,
                       reconnect_after=None if args.disconnect_at is None else 0.5)
    physics = ClampPhysics(setup.preset, setup.delta_r8, setup.mu, setup.x_contact)
    hardware = RigHardware(x_origin=setup.stroke[0], **cli_rig.bringup_hardware(args))
    if args.nvm is not None and (not args.firmware or args.qemu):
        raise ParameterError("--nvm is the memory of the host build (--firmware) or of the "
                             "rehosted board (--firmware --board nucleo); the Python model "
                             "keeps its calibration in memory, QEMU's board in RAM")
    if args.load_noise is not None:
        hardware = replace(hardware, load_noise_n=args.load_noise)
    if args.step_timing != "at-once" and (not args.firmware or args.qemu or args.board):
        raise ParameterError("--step-timing chooses the host build's table timing: give "
                             "--firmware without --board or --qemu (the board's is nucleo)")
    if args.board == "nucleo":
        return _emulate_nucleo(args, setup, hardware)
    if args.qemu:
        return _emulate_qemu(args, setup, hardware)
    # an MCU's timer interrupt is hard real time: SCHED_FIFO when the OS permits it
    emulator = RigEmulator(physics, hardware, faults, realtime=True, firmware=args.firmware,
                           nvm=args.nvm, step_timing=args.step_timing)
    print(emulator.open(), flush=True)
    emulator.on_port = lambda port: print(port, flush=True)  # after a re-plugged disconnect
    guard = SignalGuard()
    try:
        with guard:
            emulator.serve()
    except Interrupted as exc:  # the way a server is stopped: 130/143 as every command's
        return _stopped(exc)
    finally:
        emulator.close()
    return 0


def _stopped(exc: Interrupted) -> int:
    """``hil emulate`` stopped by a signal: one line, and 128 + the signal (130 SIGINT,
    143 SIGTERM), the shell's convention, as ``hil run`` and ``toggle`` exit."""
    print(f"hil emulate: {exc}; the emulated rig is closed", file=sys.stderr)
    return exc.exit_code


def serve_until(stopped: Callable[[], bool]) -> None:
    """Serve an emulated rig (its own threads do the work) until ``stopped()``; a signal
    meanwhile raises :class:`~hil.cli.interrupts.Interrupted` out of it."""
    while not stopped():
        time.sleep(0.2)


def _no_injection(args: argparse.Namespace, option: str) -> None:
    if not args.firmware:
        raise ParameterError(f"{option} runs the firmware: give --firmware too")
    injected = [n for n in ("drop_byte", "flip_bit", "junk", "stall_at", "reset_at",
                            "estop_at", "disconnect_at") if getattr(args, n)]
    if injected:
        raise ParameterError(f"{option} injects no faults: drop {', '.join(injected)}")


def _emulate_nucleo(args: argparse.Namespace, setup: RigSetup, hardware: Any) -> int:
    """The NUCLEO-F446RE image rehosted (hil/emulators/rehost/): print its pty, serve until a
    signal; on stderr the image's SHA-256 and, at the end, the emulated/wall time ratio."""
    if args.qemu:
        raise ParameterError("--board nucleo and --qemu are two ways to run the firmware: "
                         "give one")
    _no_injection(args, "--board nucleo")
    from hil.emulators.firmware_qemu import qemu_available
    from hil.emulators.rig_physics import ClampPhysics

    missing = qemu_available(need_qemu=False)
    if missing:
        raise OSError(f"--board nucleo needs the Debian packages {' '.join(missing)} "
                      f"(apt-get install {' '.join(missing)})")
    try:
        from hil.emulators.rehost.nucleo import NucleoBoard, NucleoRig, build_nucleo_image
    except ImportError as exc:
        raise OSError(f"--board nucleo needs the unicorn package: {exc}") from None
    elf = build_nucleo_image()
    physics = ClampPhysics(setup.preset, setup.delta_r8, setup.mu, setup.x_contact)
    board = NucleoBoard(elf, physics, hardware, seed=args.seed)
    if args.nvm is not None and args.nvm.exists():  # the board's flash sectors 5-7
        board.flash.memory[:] = args.nvm.read_bytes()[:len(board.flash.memory)]
        board.machine.reset("power-on")
    guard = SignalGuard()
    rig = NucleoRig(board)
    try:
        print(rig.port, flush=True)
        print(f"hil emulate: {elf} sha256 {board.elf_sha256}", file=sys.stderr, flush=True)
        with guard:
            serve_until(lambda: rig.error is not None)
        stopped: str | Interrupted = f"the rehosted board stopped: {rig.error}"
    except Interrupted as exc:
        stopped = exc
    finally:
        rig.close()
        if args.nvm is not None:
            with atomic_path(args.nvm) as tmp:
                tmp.write_bytes(bytes(board.flash.memory))
        print(f"hil emulate: emulated/wall time {rig.time_ratio:.3f}; {rig.summary()}",
              file=sys.stderr)
    if isinstance(stopped, Interrupted):
        return _stopped(stopped)
    print(f"hil emulate: error: {stopped}", file=sys.stderr)
    return 1


def _emulate_qemu(args: argparse.Namespace, setup: RigSetup, hardware: Any) -> int:
    """The firmware's Cortex-M build in QEMU: print its pty, serve until a signal."""
    _no_injection(args, "--qemu")
    from hil.emulators.firmware_qemu import QemuRig, build_qemu_image, qemu_available

    missing = qemu_available()
    if missing:
        raise OSError(f"--qemu needs the Debian packages {' '.join(missing)} "
                      f"(apt-get install {' '.join(missing)})")
    image = build_qemu_image(setup, hardware, args.seed)
    guard = SignalGuard()
    try:
        with guard, QemuRig(image) as rig:
            print(rig.port, flush=True)
            serve_until(lambda: not rig.running)
            print(f"hil emulate: error: QEMU ended: {' '.join(rig.output[-3:])}",
                  file=sys.stderr)
            return 1
    except Interrupted as exc:
        return _stopped(exc)
