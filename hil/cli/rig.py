"""``hil rig status|clear|home``: the operator's actions on a rig, and the emulator's options.

A fault latched before a session (the host died, the rig's stop input, an ESTOP) is
never cleared by ``hil run``: the operator looks at the rig and runs ``hil rig clear``.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from hil.host.run_settings import check_port
from hil.link import protocol as p
from hil.link.serial_link import CommandError, RigError, SerialLink
from toggle.args import PROBABILITY, TIME, number


def mold_position(text: str) -> float | str:
    """argparse type of ``hil emulate --x-contact``: a position in m, or ``planned``."""
    if text == "planned":
        return text
    try:
        return number(-1.0, 1.0, "must be a position in m")(text)
    except argparse.ArgumentTypeError as exc:
        raise argparse.ArgumentTypeError(f"{exc} (or 'planned')") from None


def add_emulator_options(e: argparse.ArgumentParser) -> None:
    """Options of ``hil emulate``: the simulated clamp and the injected faults."""
    e.add_argument("--preset", default="chang2021", help="mechanism preset")
    e.add_argument("--delta-r8", type=number(-5e-3, 5e-3, "must be an error below 5 mm (m)"),
                   default=0.0, dest="delta_r8", help="length error of link 8, m (e.g. 0.5e-3)")
    e.add_argument("--mu", type=number(0.0, 1.0, "must be between 0 and 1"), default=None,
                   help="pin friction (default: the preset's)")
    e.add_argument("--x-contact", type=mold_position, default=None, dest="x_contact",
                   help="crosshead position at mold contact, m, or 'planned': the mold hil "
                        "run's default job plans for this preset and --delta-r8 (default: no "
                        "mold, as in the paper's experiments and hil run --speed)")
    e.add_argument("--drop-byte", type=PROBABILITY, default=0.0,
                   help="fault: P(drop a byte) per frame")
    e.add_argument("--flip-bit", type=PROBABILITY, default=0.0,
                   help="fault: P(flip a bit) per frame")
    e.add_argument("--junk", type=PROBABILITY, default=0.0,
                   help="fault: P(junk before a frame)")
    for name, what in (("stall", "the MCU hangs for 50 ms"), ("reset", "the MCU resets"),
                       ("estop", "the rig's stop input latches ESTOP"),
                       ("disconnect", "the link vanishes")):
        e.add_argument(f"--{name}-at", type=TIME, default=None, dest=f"{name}_at",
                       help=f"fault: {what}, s after the first START (default: never)")
    e.add_argument("--seed", type=int, default=1, help="seed of the injected faults")
    e.add_argument("--firmware", action="store_true",
                   help="the MCU is the C firmware (firmware/), built for this machine, on "
                        "the simulated rig whose physics is the native FMU (default: the "
                        "Python MCU model, hil/emulators/mcu_model.py)")
    e.add_argument("--qemu", action="store_true",
                   help="with --firmware: the Cortex-M build of the firmware in "
                        "qemu-system-arm (netduinoplus2), its UART on a pty; no fault "
                        "injection (needs gcc-arm-none-eabi, libnewlib-arm-none-eabi, "
                        "qemu-system-arm)")
    e.add_argument("--board", choices=("nucleo",), default=None,
                   help="with --firmware: the NUCLEO-F446RE image (make -C firmware/board "
                        "nucleo, bytes unchanged) rehosted on the unicorn CPU emulator with "
                        "models of its peripherals, on the simulated rig; paced so its time "
                        "never runs ahead of the wall clock; prints its pty, then the image's "
                        "SHA-256 and the time ratio on stderr (needs gcc-arm-none-eabi, "
                        "libnewlib-arm-none-eabi and the unicorn package)")
    e.add_argument("--step-timing", choices=("at-once", "nucleo"), default="at-once",
                   dest="step_timing",
                   help="with --firmware (the host build): when the simulated table takes a "
                        "period's steps: at once at the tick (as the Python model), or "
                        "spread over the period as the NUCLEO board's TIM1 emits them "
                        "(firmware/core/step_burst.h; what --board nucleo does)")
    e.add_argument("--load-noise", type=number(0.0, 1e3, "must be an rms force in N"),
                   default=None, dest="load_noise",
                   help="rms noise of the load cell, N (default: the emulated hardware's, "
                        "0.2 N); 0 makes two emulators' forces comparable sample by sample")


def add_parser(subparsers: Any) -> None:
    """Register ``rig`` on the ``hil`` command's sub-parsers."""
    r = subparsers.add_parser("rig", help="the operator's actions on a rig: status, clear, home")
    actions = r.add_subparsers(dest="action", required=True, metavar="ACTION")
    for name, handler, text in (
        ("status", status, "print the rig's state, latched faults, position and versions"),
        ("clear", clear, "clear the rig's latched faults (after checking the rig)"),
        ("home", home_rig, "reference the rig at its home switch (after a reset)"),
    ):
        a = actions.add_parser(name, help=text, description=text)
        a.add_argument("--port", required=True, help="serial URL of the rig")
        a.set_defaults(handler=handler)


def _session(port: str) -> SerialLink:
    """An open session that leaves every latched fault as it found it."""
    check_port(port)
    link = SerialLink(port, clear_faults_on_close=False)
    try:
        link.open()
    except RigError as exc:
        raise RigCommandError(f"rig at {port}: {exc}") from exc
    return link


class RigCommandError(RuntimeError):
    """A ``hil rig`` action that could not be done."""


def _describe(link: SerialLink) -> str:
    from hil.host.backends import fault_names

    info, st, sc = link.info, link.status, link.scaling
    flags = p.TelemetryFlag(st.flags)
    return "\n".join((
        f"rig at {link.url}: protocol {info.proto_major}.{info.proto_minor}, firmware "
        f"{info.fw_version >> 8}.{info.fw_version & 0xFF}, boot id {info.boot_id:#010x}",
        f"  state {p.State(st.state).name}; latched faults: {fault_names(st.faults)}",
        f"  referenced: {'yes' if flags & p.TelemetryFlag.REFERENCED else 'no (home it)'}; "
        f"home switch {'active' if flags & p.TelemetryFlag.HOME_SWITCH else 'inactive'}",
        f"  table {st.steps} steps ({sc.x(st.steps) * 1e3:.4f} mm from step 0), platen "
        f"{st.enc} counts ({sc.platen(st.enc) * 1e3:.3f} mm), force "
        f"{sc.force(st.load_raw):.2f} N",
    ))


def status(args: argparse.Namespace) -> int:
    with _session(args.port) as link:
        print(_describe(link))
        return 1 if link.faults_at_open else 0


def clear(args: argparse.Namespace) -> int:
    from hil.host.backends import fault_names

    with _session(args.port) as link:
        faults = fault_names(link.faults_at_open)
        if not link.faults_at_open:
            print(f"rig at {args.port}: no latched fault")
            return 0
        try:
            link.clear_fault()
        except (CommandError, RigError) as exc:
            print(f"hil rig clear: {faults} not cleared: {exc} (the condition is still "
                  f"present)", file=sys.stderr)
            return 1
        print(f"rig at {args.port}: cleared {faults}")
        return 0


def home_rig(args: argparse.Namespace) -> int:
    from hil.host.backends import fault_names
    from hil.host.homing import home

    with _session(args.port) as link:
        if link.faults_at_open:
            print(f"hil rig home: the rig has latched faults ({fault_names(link.faults_at_open)})"
                  f"; clear them first", file=sys.stderr)
            return 1
        try:
            distance = home(link)
        except RigError as exc:
            print(f"hil rig home: {exc}", file=sys.stderr)
            return 1
        print(f"rig at {args.port}: referenced at its home switch ({distance * 1e3:.3f} mm "
              f"from where it was)")
        return 0
