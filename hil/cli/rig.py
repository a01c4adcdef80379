"""``hil rig status|clear|home|jog|tare|span|store|check``: the operator's actions on a rig,
and the emulator's options.

A fault latched before a session (the host died, the rig's stop input, an ESTOP) is
never cleared by ``hil run``: the operator looks at the rig and runs ``hil rig clear``.
The bring-up actions (docs/bring-up.md) are thin shells over :mod:`hil.host.bringup`,
which the web panel calls too.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from fractions import Fraction
from pathlib import Path
from typing import Any

from hil.host.run_settings import check_port
from hil.link import protocol as p
from hil.link.errors import CommandError, RigError
from hil.link.serial_link import SerialLink
from toggle.args import PROBABILITY, TIME, integer, length, number, positive


def mold_position(text: str) -> float | str:
    """argparse type of ``hil emulate --x-contact``: a position (m, or with a unit: 40mm),
    or ``planned``."""
    if text == "planned":
        return text
    try:
        return length(-1.0, 1.0, "must be a position within 1 m")(text)
    except argparse.ArgumentTypeError as exc:
        raise argparse.ArgumentTypeError(f"{exc} (or 'planned')") from None


def add_emulator_options(e: argparse.ArgumentParser) -> None:
    """Options of ``hil emulate``: the simulated clamp and the injected faults."""
    e.add_argument("--preset", default="chang2021", help="mechanism preset")
    e.add_argument("--delta-r8", type=length(-5e-3, 5e-3, "must be an error within 5 mm"),
                   default=0.0, dest="delta_r8",
                   help="length error of link 8, m or with a unit (0.5e-3, 0.5mm, 500um)")
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
    add_bringup_emulator_options(e)
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


def add_bringup_emulator_options(e: argparse.ArgumentParser) -> None:
    """The emulated rig's own cell and drive, for bring-up (docs/bring-up.md)."""
    e.add_argument("--cell-offset", type=integer(-8_388_607, 8_388_606, "must be ADC counts "
                   "inside the 24-bit ADC"), default=None, dest="cell_offset",
                   help="the load cell's true reading at zero force, ADC counts (default: "
                        "the firmware's default calibration, 1500)")
    e.add_argument("--cell-gain", type=positive("must be N per ADC count", hi=1.0),
                   default=None, dest="cell_gain",
                   help="the load cell's true gain, N per ADC count (default 1e-4)")
    e.add_argument("--reverse-encoder", action="store_true", dest="reverse_encoder",
                   help="the encoder counts against the steps (A and B swapped)")
    drop = e.add_mutually_exclusive_group()
    drop.add_argument("--drop-steps", type=number(0.0, 0.5, "must be a fraction in [0, 0.5]"),
                      default=None, dest="drop_steps",
                      help="the drive loses this fraction of the step pulses")
    drop.add_argument("--drop-every", type=integer(2, 10**9, "must be a whole number >= 2"),
                      default=None, dest="drop_every",
                      help="the drive loses every N-th step pulse")
    e.add_argument("--nvm", type=Path, default=None,
                   help="with --firmware: the file that is the MCU's non-volatile memory "
                        "(the stored calibration survives the emulator; default: memory); "
                        "with --board nucleo, the image of flash sectors 5-7, read at the "
                        "start and written at the end")


def bringup_hardware(args: argparse.Namespace) -> dict[str, Any]:
    """RigHardware fields of the bring-up options of ``hil emulate``."""
    out: dict[str, Any] = {"cell_offset": args.cell_offset, "cell_gain_n": args.cell_gain,
                           "encoder_sign": -1 if args.reverse_encoder else 1}
    if args.drop_every is not None:
        out["drop_steps"] = (1, args.drop_every)
    elif args.drop_steps:
        f = Fraction(args.drop_steps).limit_denominator(1_000_000)
        out["drop_steps"] = (f.numerator, f.denominator)
    return out


def add_parser(subparsers: Any) -> None:
    """Register ``rig`` on the ``hil`` command's sub-parsers."""
    r = subparsers.add_parser("rig", help="the operator's actions on a rig: status, clear, "
                                          "home, and bring-up (jog, tare, span, store, check)")
    actions = r.add_subparsers(dest="action", required=True, metavar="ACTION")
    parsers = {}
    for name, handler, text in (
        ("status", status, "print the rig's state, latched faults, position and versions"),
        ("clear", clear, "clear the rig's latched faults (after checking the rig)"),
        ("home", home_rig, "reference the rig at its home switch (after a reset)"),
        ("jog", jog_rig, "move the table to a position or by a distance (homed rig)"),
        ("tare", tare_rig, "the load cell's offset from samples at rest, no load on it"),
        ("span", span_rig, "the load cell's gain from a known force or mass on it"),
        ("store", store_rig, "store a calibration on the board (non-volatile) and read it "
                             "back; without values, print the stored one"),
        ("check", check_rig, "sensor check: a slow move; encoder direction, counts per step, "
                             "lost steps, cell noise, switches, stop chain"),
    ):
        a = parsers[name] = actions.add_parser(name, help=text, description=text)
        a.add_argument("--port", required=True, help="serial URL of the rig")
        if name not in ("status", "clear", "home"):
            a.add_argument("--json", action="store_true", help="print the result as JSON")
        a.set_defaults(handler=handler)
    where = parsers["jog"].add_mutually_exclusive_group(required=True)
    where.add_argument("--to", type=length(-1.0, 1.0, "must be a position within 1 m"),
                       help="target, m from step 0 (the home switch's edge), or with a unit "
                            "(12.5mm)")
    where.add_argument("--by", type=length(-1.0, 1.0, "must be a distance within 1 m"),
                       help="distance, m or with a unit (-2mm: back toward home)")
    parsers["jog"].add_argument("--speed", type=positive("must be a speed in m/s", hi=0.05),
                                default=None, help="m/s (default 5 mm/s)")
    samples = integer(10, 60_000, "must be a whole number of samples in 10..60000")
    for name in ("tare", "span"):
        parsers[name].add_argument("--samples", type=samples, default=500,
                                   help="readings averaged (1 kHz: 500 is 0.5 s)")
    force = parsers["span"].add_mutually_exclusive_group(required=True)
    force.add_argument("--force", type=number(-1e4, 1e4, "must be a force in N"),
                       help="the known force on the cell, N (positive: as the table pushes)")
    force.add_argument("--mass", type=positive("must be a mass in kg", hi=1e3),
                       help="a calibration mass hung on the cell, kg (standard gravity)")
    parsers["span"].add_argument("--offset", type=int, default=None,
                                 help="the tare's offset, counts (default: the one in use)")
    parsers["store"].add_argument("--offset", type=int, default=None,
                                  help="ADC counts at zero force (from hil rig tare)")
    parsers["store"].add_argument("--gain", type=positive("must be N per ADC count", hi=1.0),
                                  default=None, help="N per ADC count (from hil rig span)")


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


# --- bring-up (hil.host.bringup) ------------------------------------------------------------


def _bringup(args: argparse.Namespace, action: Callable[[SerialLink], Any],
             text: Callable[[Any], str]) -> int:
    """Run one bring-up action in a session; print its result (or JSON); 1 on a refusal."""
    from toggle.json_text import json_text

    with _session(args.port) as link:
        try:
            result = action(link)
        except RigError as exc:
            print(f"hil rig {args.action}: {exc}", file=sys.stderr)
            return 1
        print(json_text(result.to_dict()) if args.json else text(result))
        passed = getattr(result, "passed", True)
        return 0 if passed else 1


def jog_rig(args: argparse.Namespace) -> int:
    from hil.host import bringup

    return _bringup(args, lambda link: bringup.jog(link, to=args.to, by=args.by,
                                                   speed=args.speed),
                    lambda r: f"rig at {args.port}: table at {r.end * 1e3:.4f} mm (from "
                              f"{r.start * 1e3:.4f} mm at {r.speed * 1e3:g} mm/s)")


def tare_rig(args: argparse.Namespace) -> int:
    from hil.host import bringup

    return _bringup(args, lambda link: bringup.tare(link, args.samples),
                    lambda r: f"offset {r.offset} counts; noise {r.noise:.3f} N (1 sigma, "
                              f"{r.samples} samples); store it with hil rig store --offset "
                              f"{r.offset} --gain G")


def span_rig(args: argparse.Namespace) -> int:
    from hil.host import bringup

    force = args.force if args.mass is None else bringup.span_from_mass(args.mass)
    return _bringup(args, lambda link: bringup.span(link, force, args.samples,
                                                    offset=args.offset),
                    lambda r: f"gain {r.gain:.6g} N/count from {r.known_force:g} N over "
                              f"offset {r.offset}; noise {r.noise:.3f} N (1 sigma, "
                              f"{r.samples} samples); store it with hil rig store --offset "
                              f"{r.offset} --gain {r.gain:.7g}")


def store_rig(args: argparse.Namespace) -> int:
    from hil.host import bringup

    def action(link: SerialLink) -> bringup.StoredCalibration:
        if args.offset is None and args.gain is None:
            return bringup.read_calibration(link)
        if args.offset is None or args.gain is None:
            raise bringup.BringupError("give both --offset and --gain (or neither, to read)")
        return bringup.store_calibration(link, args.offset, args.gain)

    return _bringup(args, action,
                    lambda r: f"rig at {args.port}: stored calibration #{r.cal_seq}: offset "
                              f"{r.offset} counts, gain {r.gain:.7g} N/count"
                              + ("" if r.cal_seq else " (none stored: the firmware's default)"))


def check_rig(args: argparse.Namespace) -> int:
    from hil.host import bringup

    def text(report: bringup.SensorReport) -> str:
        lines = [f"{'PASS' if i.passed else 'FAIL'}  {i.name}: "
                 f"{'-' if i.figure is None else f'{i.figure:.6g}'} {i.unit}; {i.text}"
                 for i in report.items]
        return "\n".join([*lines, "sensor check: " + ("passed" if report.passed else "FAILED")])

    return _bringup(args, bringup.sensor_check, text)
