"""The settings of ``hil run``: command line, ``--config`` file and profile, merged and checked.

Precedence: the command line, then the --config file, then the settings a planned
profile carries, then the defaults. Every --config key is applied or refused by name
(unknown keys and wrong types are errors); a profile's settings that disagree with an
explicit option are refused rather than silently replaced. Every check lives here, so
a value is judged the same whether it was typed or read from a file. The back-ends, the
profile reader and the model load in the functions that need them: the `hil` parser takes
its defaults and options from here without numpy, SciPy or CasADi.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import math
import os
import stat
import sys
import zipfile
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

from toggle.args import length
from toggle.files import InputError, check_writable, check_writable_dir, read_text, read_toml
from toggle.params import ParameterError, load_preset

#: Built-in defaults of every setting a --config file may hold.
RUN_DEFAULTS: dict[str, Any] = {
    "backend": "fmu", "port": None, "preset": "chang2021", "profile": None, "cycles": 3,
    "speed": None, "delta_r8": 0.0, "mu": None, "x_contact": None, "force_limit": 400.0,
    "out": None, "watchdog_ms": None, "max_duration": 3600.0, "fmu": None, "as_built": True,
    "ack_ms": None, "heartbeat_ms": None,
}
#: The real rig's load cell's range, N: a force limit above it could never trip there.
LOAD_CELL_RANGE = 500.0
#: Bytes of one samples.csv row (for the file-size estimate).
BYTES_PER_SAMPLE = 52
#: Profile settings that hil run applies to the simulated (or emulated) clamp.
PROFILE_KEYS = ("preset", "x_contact", "mu", "delta_r8")

_TEXT = ("backend", "port", "preset", "profile", "out", "fmu")
_INTEGER = ("cycles",)
_BOOLEAN = ("as_built",)


@dataclass(frozen=True)
class RunSettings:
    """Everything that shapes a ``hil run``, SI units."""

    backend: str
    port: str | None
    preset: str
    profile: Path | None
    cycles: int
    speed: float | None
    delta_r8: float
    mu: float | None
    x_contact: float | None
    force_limit: float
    out: Path | None
    watchdog_ms: float | None
    max_duration: float
    fmu: Path | None
    #: the simulated rig carries the prototype's as-built errors (toggle.rig_tables)
    as_built: bool
    ack_ms: float | None = None  # the host's wait for an ACK (docs/rig-protocol-behaviour.md §6)
    #: the MCU's heartbeat watchdog (docs/rig-protocol-behaviour.md §7)
    heartbeat_ms: float | None = None
    json: bool = False
    quiet: bool = False
    force: bool = False  # --force: replace the files of an earlier run in --out
    profile_sha256: str | None = None
    force_limit_given: bool = False  # by --force-limit or --config, not the default

    def record(self) -> dict[str, Any]:
        """JSON-ready copy for meta.json."""
        return {k: (str(v) if isinstance(v, Path) else v) for k, v in asdict(self).items()
                if k not in ("json", "quiet", "force")}


#: A length option of hil run: m, or with a unit (0.5mm); its range is :func:`check`'s.
_LENGTH = length(-math.inf, math.inf, "must be a finite length")


def add_number_options(p: argparse.ArgumentParser) -> None:
    """The numeric options of ``hil run`` (parsed as numbers; judged by :func:`check`)."""
    p.add_argument("--delta-r8", type=_LENGTH, default=None, dest="delta_r8",
                   help="length error of link 8, m or with a unit (0.5e-3, 0.5mm, 500um; "
                        "default 0 m): the simulated "
                        "clamp's; with --real, the setting of the rig's adjustable link as "
                        "made by hand (the default job plans for it, meta.json records it; "
                        "the host cannot check it: hil emulate takes its own --delta-r8)")
    p.add_argument("--mu", type=float, default=None,
                   help="pin friction of the simulated clamp (default: the preset's)")
    p.add_argument("--x-contact", type=_LENGTH, default=None, dest="x_contact",
                   help="crosshead position at mold contact, m or with a unit (-0.04, -40mm; "
                        "default: the planned mold "
                        "for the default job, none with --speed)")
    p.add_argument("--cycles", type=int, default=None,
                   help="forward-backward cycles (default 3)")
    p.add_argument("--speed", type=float, default=None,
                   help="constant input speed of the reciprocating experiment, m/s, e.g. 5e-3 "
                        "(default: the planned minimum-force profile)")
    p.add_argument("--force-limit", type=float, default=None, dest="force_limit",
                   help=f"stop when |input force| exceeds this, N (default "
                        f"{RUN_DEFAULTS['force_limit']:g} N, for the rig's load cell; with --real "
                        f"at most its {LOAD_CELL_RANGE:g}; without it the simulated rig of a "
                        f"larger clamp, such as lin2003_sm55, runs under 1.25 x its plan's "
                        f"peak; a given limit below the plan's peak is refused)")
    p.add_argument("--watchdog-ms", type=float, default=None, dest="watchdog_ms",
                   help="host watchdog on telemetry silence, ms (default: measured from the "
                        "link when the session opens, 100 on a rig's idle link, at most 1000; "
                        "the MCU's own limits and heartbeat watchdog are the hard stops)")
    p.add_argument("--ack-ms", type=float, default=None, dest="ack_ms",
                   help="with --real: the host's wait for each ACK before it retransmits, ms "
                        "(default: measured from the link when the session opens and followed "
                        "during it, 20 on a rig's UART or USB, at most 500)")
    p.add_argument("--heartbeat-ms", type=float, default=None, dest="heartbeat_ms",
                   help="with --real: the MCU's heartbeat watchdog, ms: it stops the rig when "
                        "the host is silent this long, from the first CONFIG (homing's) on "
                        "(default: measured from the link, 250 on a rig's idle link; at least "
                        "50, at most 1000; the host sends a heartbeat every 20 ms)")
    p.add_argument("--max-duration", type=float, default=None, dest="max_duration",
                   help=f"refuse runs longer than this, s (default "
                        f"{RUN_DEFAULTS['max_duration']:g} s)")


def read_config(path: Path) -> dict[str, Any]:
    """The keys of a --config TOML file; unknown keys and wrong types are refused by name."""
    table = read_toml(path, "--config")
    unknown = sorted(set(table) - set(RUN_DEFAULTS))
    if unknown:
        raise ParameterError(f"--config {path}: unknown key(s) {', '.join(unknown)}; known: "
                             f"{', '.join(RUN_DEFAULTS)}")
    for key, value in table.items():
        if key in _TEXT:
            ok, kind = isinstance(value, str), "text"
        elif key in _INTEGER:
            ok, kind = isinstance(value, int) and not isinstance(value, bool), "a whole number"
        elif key in _BOOLEAN:
            ok, kind = isinstance(value, bool), "true or false"
        else:
            ok = isinstance(value, (int, float)) and not isinstance(value, bool)
            kind = "a number"
        if not ok:
            raise ParameterError(f"--config {path}: {key} = {value!r} must be {kind}")
    return table


def _option(key: str) -> str:
    return "--" + key.replace("_", "-")


def check(v: dict[str, Any]) -> None:
    """Refuse a value that cannot run, naming its option."""
    from hil.host.backends import MAX_SPEED, simulated_speed_limit

    def bad(key: str, why: str) -> ParameterError:
        return ParameterError(f"{_option(key)} ({key}) {why}, got {v[key]!r}")

    if v["backend"] not in ("fmu", "real"):
        raise bad("backend", "must be 'fmu' or 'real'")
    if v["port"] is not None and v["backend"] != "real":
        raise ParameterError("--port needs --real (or backend = \"real\" in the config): "
                             "without it the simulated rig runs and the port is not used")
    if v["backend"] == "real" and not v["port"]:
        raise ParameterError("--real needs --port (a device, a pty, socket://host:port)")
    if v["backend"] == "real":
        check_port(v["port"])
    if v["fmu"] is not None and v["backend"] == "real":
        raise ParameterError("--fmu selects the simulated rig's FMU; it cannot go with --real")
    if v["cycles"] < 1:
        raise bad("cycles", "must be at least 1")
    top_speed = MAX_SPEED if v["backend"] == "real" else simulated_speed_limit(v["preset"])
    for key, lo, hi, why in (
        ("speed", 0.0, top_speed, f"must be > 0 and at most {top_speed:g} m/s"),
        ("force_limit", 0.0, LOAD_CELL_RANGE if v["backend"] == "real" else math.inf,
         f"must be > 0 and at most the rig's load cell's {LOAD_CELL_RANGE:g} N"
         if v["backend"] == "real" else "must be > 0 (N)"),
        ("watchdog_ms", 0.0, 10_000.0, "must be > 0 and at most 10000 ms"),
        ("ack_ms", 0.0, 1000.0, "must be > 0 and at most 1000 ms"),
        ("heartbeat_ms", 49.999, 1000.0, "must be at least 50 and at most 1000 ms"),
        ("max_duration", 0.0, math.inf, "must be > 0 s"),
    ):
        value = v[key]
        if value is not None and not (math.isfinite(value) and lo < value <= hi):
            raise bad(key, why)
    if v["mu"] is not None and not (math.isfinite(v["mu"]) and 0.0 <= v["mu"] <= 1.0):
        raise bad("mu", "must be between 0 and 1")
    if not (math.isfinite(v["delta_r8"]) and abs(v["delta_r8"]) < 5e-3):
        raise bad("delta_r8", "must be a finite error below 5 mm (in m)")
    if v["x_contact"] is not None:
        check_mold(v["preset"], v["x_contact"])


#: pyserial URLs that open a device path (``spy://PATH?options``): the path is checked.
_DEVICE_URLS = ("spy://", "alt://")
_PORT_HINT = "a serial device such as /dev/ttyACM0, the pty hil emulate printed, or socket://host:port"


def check_port(port: str) -> None:
    """Refuse a rig port that is no serial device, before the work, in words: a path where
    there is nothing, a folder, a regular file, a character device that is no terminal
    (/dev/null: Linux's /sys/dev/char says its subsystem). The device is not opened here
    (opening a serial port resets some boards); a URL such as socket://host:port is tried
    when the session opens."""
    path = port
    for scheme in _DEVICE_URLS:
        if port.startswith(scheme):
            path = port[len(scheme):].split("?")[0]
    if "://" in path:
        return
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        raise ParameterError(f"--port {port}: no such device ({_PORT_HINT})") from None
    except OSError as exc:
        raise ParameterError(f"--port {port}: cannot be used "
                             f"({(exc.strerror or 'unreadable').lower()}; {_PORT_HINT})") from None
    if stat.S_ISDIR(mode):
        raise ParameterError(f"--port {port}: is a folder, not a serial device ({_PORT_HINT})")
    if not stat.S_ISCHR(mode):
        raise ParameterError(f"--port {port}: is a file, not a serial device ({_PORT_HINT})")
    subsystem = _device_subsystem(os.stat(path).st_rdev)
    if subsystem not in (None, "tty"):
        raise ParameterError(f"--port {port}: is a {subsystem} device, not a serial port "
                             f"({_PORT_HINT})")


def _device_subsystem(rdev: int) -> str | None:
    """The Linux subsystem of a character device ("tty", "mem", ...), or None where sysfs
    does not say (a pty slave has no entry there; another system has no sysfs)."""
    link = Path(f"/sys/dev/char/{os.major(rdev)}:{os.minor(rdev)}/subsystem")
    try:
        return Path(os.readlink(link)).name
    except OSError:
        return None


def check_mold(preset: str, x_contact: float) -> None:
    """Refuse a mold position (m) outside the preset's stroke, where no mold is clamped
    (``hil run`` and ``hil emulate``)."""
    from toggle.elastics import clamp_stroke

    x_open, x_tp = clamp_stroke(load_preset(preset))
    if not (math.isfinite(x_contact) and x_open < x_contact < x_tp):
        raise ParameterError(f"--x-contact (x_contact) must lie inside the stroke "
                             f"({x_open:.6g}, {x_tp:.6g}) m, got {x_contact!r}")


def _apply_profile(values: dict[str, Any], explicit: set[str]) -> str:
    """Adopt the settings the profile was planned with; refuse a clash, a file that is not a
    profile and a truncated one (before any work). Returns the file's SHA-256."""
    from controllers.profiles import ProfileError, read_profile_settings
    from hil.host.backends import RigSetup
    from hil.host.samples import Trajectory, TrajectoryError

    path = Path(values["profile"])
    digest = hashlib.sha256(read_text(path, "--profile").encode("utf-8")).hexdigest()
    try:
        planned = read_profile_settings(path)
        trajectory = Trajectory.from_csv(path, period=RigSetup.period)
    except (ProfileError, TrajectoryError) as exc:  # "profile FILE is empty", ...
        why = str(exc).replace(f"profile {path}", "", 1).lstrip(": ")
        raise ParameterError(f"--profile {path}: {why}") from None
    _check_whole(path, planned, trajectory.duration)
    for key in PROFILE_KEYS:
        if key not in planned:
            continue
        if key in explicit and values[key] != planned[key]:
            raise ParameterError(
                f"--profile {path} was planned with {key} = {planned[key]!r}, but "
                f"{_option(key)} gives {values[key]!r}; drop the option or re-plan")
        values[key] = planned[key]
        explicit.add(key)  # chosen by the plan: an FMU built for another preset is refused
    return digest


#: The simulated rig's force limit over its plan's peak where no limit is given (as-built
#: errors and the FMU's dynamics add to the plan's force: 8 % measured on lin2003_sm55).
PLAN_MARGIN = 1.25


def limit_for_plan(s: RunSettings, peak: float, what: str) -> float:
    """The force limit (N) a run of a plan whose own peak input force is ``peak`` (N) runs
    under, decided before the run:

    * the peak within the limit: the limit;
    * a limit given (option or --config), or the real rig: refused (ParameterError, exit
      2), since the run would stop at the limit within milliseconds; the limit is a safety
      stop and is never raised past what the user said (on the rig: its load cell);
    * the simulated rig at the default (400 N: the prototype rig's load cell, which a
      simulated lin2003_sm55 does not have): :data:`PLAN_MARGIN` times the peak, said on
      stderr, as a simulation of that clamp needs."""
    if peak <= s.force_limit:
        return s.force_limit
    if s.force_limit_given or s.backend == "real":
        raise ParameterError(
            f"{what}: its planned peak input force is {peak:.4g} N, above --force-limit "
            f"{s.force_limit:g} N; the run would stop at the limit at once. Give a larger "
            f"--force-limit (at least {peak:.4g} N, with a margin for the as-built errors)"
            + ("; on the real rig, a plan within its load cell" if s.backend == "real" else ""))
    limit = float(f"{PLAN_MARGIN * peak:.3g}")
    print(f"hil run: force limit {limit:g} N, {PLAN_MARGIN:g} x the plan's peak {peak:.4g} N "
          f"(the default {s.force_limit:g} N is the prototype rig's load cell; give "
          "--force-limit to set it)", file=sys.stderr)
    return limit


def profile_peak(path: Path) -> float | None:
    """The peak |input force| (N) a profile was planned with (its ``input_force [N]``
    column); None for a bare profile of positions only."""
    from controllers.profiles import ProfileError, read_profile_columns

    try:
        return float(abs(read_profile_columns(path, ("input_force [N]",))[:, 0]).max())
    except ProfileError:
        return None


def _check_whole(path: Path, planned: dict[str, Any], duration: float) -> None:
    """Refuse a profile that ends before the time its header says the plan lasts
    (``duration`` of a stroke, ``cycle_time`` of a molding cycle): a file cut short would
    run part of a stroke and complete no cycle."""
    from controllers.profiles import truncation
    from hil.host.backends import RigSetup

    cut = truncation(planned, duration, 2 * RigSetup.period)
    if cut is not None:
        raise ParameterError(f"--profile {path}: {cut}; write it again (toggle plan --out)")


def _check_fmu(path: Path) -> None:
    """Refuse a --fmu that is not an FMU file (a zip archive holding modelDescription.xml)
    before the work, in words."""
    if not path.exists():
        raise InputError(f"--fmu {path}: no such file")
    if path.is_dir():
        raise InputError(f"--fmu {path}: is a folder, not a file")
    try:
        with zipfile.ZipFile(path) as archive:
            archive.getinfo("modelDescription.xml")
    except (zipfile.BadZipFile, KeyError):
        raise InputError(f"--fmu {path}: not an FMU (a zip archive with "
                         "modelDescription.xml); build one with toggle build-fmu") from None
    except OSError as exc:
        raise InputError(f"--fmu {path}: cannot be read ({(exc.strerror or '').lower()})"
                         ) from None


def _fmu_preset(values: dict[str, Any], explicit: set[str]) -> None:
    """The simulated rig's preset and its FMU agree, before the work: without a preset
    (option, --config or profile) the run takes the preset of --fmu, or of the build
    folder's ToggleClamp.fmu (the one ``toggle build-fmu`` wrote last); a --fmu built for
    another preset than the one given is refused."""
    from fmu_src.build import build_folder, fmu_preset

    if values["fmu"] is not None:
        fmu = Path(values["fmu"])
        _check_fmu(fmu)
    elif "preset" not in explicit:
        fmu = build_folder() / "ToggleClamp.fmu"
    else:
        return
    built_for = fmu_preset(fmu)
    if built_for is None:
        return
    if "preset" not in explicit:
        with contextlib.suppress(ParameterError, OSError):  # a preset file's FMU: its name
            load_preset(built_for)                            # is no preset: the default's
            values["preset"] = built_for
        return
    try:
        wanted = load_preset(values["preset"]).name
    except (ParameterError, OSError):
        return  # refused with its reason below
    if built_for != wanted:
        raise InputError(f"--fmu {fmu}: built for preset {built_for}, not {values['preset']}; "
                         f"drop --preset to run it, or drop --fmu to run {values['preset']}'s "
                         "own FMU (built when missing)")


def resolve_settings(args: argparse.Namespace) -> RunSettings:
    """Merge the command line, the --config file, a profile's settings and the defaults."""
    from hil.host.backends import RigSetup
    from hil.host.recording import RUN_FILES

    config = read_config(args.config) if args.config is not None else {}
    cli = {k: getattr(args, k) for k in RUN_DEFAULTS if getattr(args, k, None) is not None}
    values = {**RUN_DEFAULTS, **config, **cli}
    explicit = set(config) | set(cli)
    if values["profile"] is not None and values["speed"] is not None:
        raise ParameterError("give --profile or --speed, not both (a profile sets its speed)")
    digest = _apply_profile(values, explicit) if values["profile"] is not None else None
    if values["backend"] == "fmu":
        _fmu_preset(values, explicit)
    try:
        mech = load_preset(values["preset"])
    except (ParameterError, OSError) as exc:
        raise ParameterError(f"--preset (preset): {exc}") from exc
    if mech.dynamics is None:  # the rig's model needs masses; hil run has no option for them
        raise ParameterError(f"--preset (preset) {values['preset']}: hil run needs a preset "
                             "with [dynamics] masses (chang2021, or a TOML file that has them)")
    check(values)
    if values["profile"] is None and values["speed"] is None and values["x_contact"] is None:
        # the default job clamps a mold, which the simulated rig has too
        values["x_contact"] = RigSetup(preset=values["preset"], delta_r8=values["delta_r8"],
                                       mu=values["mu"], as_built=values["as_built"]).planned_mold
    for key in ("profile", "out", "fmu"):
        if values[key] is not None:
            values[key] = Path(values[key])
    if values["fmu"] is not None:
        _check_fmu(values["fmu"])
    if values["out"] is not None:  # an earlier run's files only with --force
        check_writable_dir(values["out"], "--out")
        for name in RUN_FILES:
            check_writable(values["out"] / name, "--out")
    s = RunSettings(**values, json=args.json, quiet=args.quiet, profile_sha256=digest,
                    force=getattr(args, "force", False),
                    force_limit_given="force_limit" in explicit)
    peak = profile_peak(s.profile) if s.profile is not None else None
    if peak is not None:  # before the run: the plan's own peak against the limit
        s = replace(s, force_limit=limit_for_plan(s, peak, f"--profile {s.profile}"))
    return s
