"""The rig's firmware in C, built for the host and driven from Python.

:func:`build_host_firmware` compiles the firmware's portable core (firmware/core/), the
simulated rig (firmware/sim/: the board whose hardware is the clamp plant, an FMI 2.0 master
of the native FMU's C code) and the host glue (firmware/host/rigfw_host.c) into
``librigfw.so``. :class:`FirmwareMcu` loads it: the byte-level MCU interface (frames in,
frames out, one tick per period) the rig emulator serves on its pseudo-terminal, with the
C firmware in place of :class:`hil.emulators.mcu_model.McuModel`.
"""

from __future__ import annotations

import ctypes
import fcntl
import hashlib
import math
import os
import re
import shutil
import subprocess
import tempfile
from collections.abc import Mapping
from pathlib import Path

from hil.emulators.mcu_model import RigHardware
from hil.emulators.rig_physics import ClampPhysics

ROOT = Path(__file__).resolve().parents[2]
FIRMWARE = ROOT / "firmware"
CORE_DIR, SIM_DIR, HOST_DIR = FIRMWARE / "core", FIRMWARE / "sim", FIRMWARE / "host"
BOARD_DIR = FIRMWARE / "board"
BUILD_DIR = ROOT / "build" / "firmware"
LIBRARY = "librigfw.so"
#: Flags of the firmware's own C (core, sim, host glue); the FMU's C gets fmu_src.native_build's.
FIRMWARE_CFLAGS = ("-std=c11", "-O2", "-fPIC", "-Wall", "-Wextra", "-Werror", "-Wconversion",
                   "-Wshadow", "-fvisibility=hidden")  # core.mk's CORE_CFLAGS and more
#: With RIGFW_SANITIZE=1 in the environment the host build is instrumented with
#: AddressSanitizer and UBSan (a process loading it preloads their runtimes:
#: tests/test_firmware_sanitized.py).
SANITIZE_FLAGS = ("-fsanitize=address,undefined", "-fno-sanitize-recover=all",
                  "-fno-omit-frame-pointer", "-g")
#: The library exports the rigfw_* API only (not the core's, the HAL's or the FMU's names).
VERSION_SCRIPT = "{ global: rigfw_*; local: *; };\n"
#: The plant alone (hil/emulators/rehost/): the sim's API and its rig_hal.h functions.
PLANT_LIBRARY = "librigsim.so"
PLANT_VERSION_SCRIPT = "{ global: sim_rig_*; hal_*; local: *; };\n"
#: The firmware's compile-time constants (rig_core.h) that a RigHardware must match.
CORE_CONSTANTS = {"telemetry_hz": 1000, "buffer_capacity": 2048, "step_nm": 200,
                  "enc_nm": 1000, "adc_min": -8_388_608, "adc_max": 8_388_607,
                  "fw_version": 0x0103}
TX_CHUNK = 4096  # RIG_TX_FIFO_BYTES: one call empties the FIFO


def core_sources() -> list[Path]:
    """The core's C files: CORE_SRC of firmware/core/core.mk if it exists, else core/*.c."""
    makefile = CORE_DIR / "core.mk"
    if makefile.is_file():
        text = makefile.read_text().replace("\\\n", " ")
        names: list[str] = []
        for match in re.finditer(r"^\s*CORE_SRC\s*(\+?:?=)\s*(.*)$", text, re.MULTILINE):
            words = [w for w in match.group(2).split() if w.endswith(".c")]
            names = [*names, *words] if match.group(1).startswith("+") else words
        if names:
            return [CORE_DIR / Path(n).name for n in names]
    return sorted(CORE_DIR.glob("*.c"))


def _safe_name(preset: str) -> str:
    """A folder-name form of a preset's name or file."""
    return re.sub(r"[^A-Za-z0-9_.-]", "_", Path(preset).stem if "/" in preset else preset)


def make_board(*targets: str) -> subprocess.CompletedProcess[str]:
    """``make -s -C firmware/board TARGETS``, one make at a time on this checkout: two
    processes making the same image (two test workers, two ``hil emulate --firmware``)
    wrote and linked the same object files at once, and one link failed on objects the
    other had half written (undefined references to tgc_geometry in a clean-clone run).
    The second waits, then finds the image up to date."""
    BUILD_DIR.mkdir(parents=True, exist_ok=True)
    with open(BUILD_DIR / ".make.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        return subprocess.run(["make", "-s", "-C", str(BOARD_DIR), *targets],
                              capture_output=True, text=True)


def section_sizes(elf: Path) -> dict[str, int]:
    """Section sizes (bytes) of a board image by name (``arm-none-eabi-size -A``)."""
    out = subprocess.run(["arm-none-eabi-size", "-A", str(elf)], capture_output=True,
                         text=True, check=True).stdout
    sizes = {}
    for line in out.splitlines():
        parts = line.split()
        if len(parts) == 3 and parts[0].startswith(".") and parts[1].isdigit():
            sizes[parts[0]] = int(parts[1])
    return sizes


def _run(cmd: list[str], cwd: Path) -> None:
    result = subprocess.run(cmd, capture_output=True, text=True, cwd=cwd)
    if result.returncode:
        raise RuntimeError(f"building the rig firmware failed:\n{' '.join(cmd)}\n"
                           f"{result.stderr.strip()}")


def build_host_firmware(preset: str = "chang2021", plant_only: bool = False) -> Path:
    """Build (or reuse) build/firmware/host-<preset>-<hash>/librigfw.so; return its path.

    ``plant_only``: the simulated rig alone, without the core and the host glue,
    exporting sim_rig_* and the hal_* functions (plant-<preset>-<hash>/librigsim.so: the
    plant of the rehosted board image, hil/emulators/rehost/). The hash covers the firmware's C
    sources, the generated FMU code and the flags, so an
    edit rebuilds and an unchanged tree reuses the library. RuntimeError with gcc's stderr
    when a compilation fails.
    """
    from fmu_src.c_code import fmi2_headers
    from fmu_src.native_build import (
        CFLAGS,
        GENERATED,
        GENERATED_CFLAGS,
        generate_sources,
    )

    if shutil.which("gcc") is None:
        raise RuntimeError("building the rig firmware needs gcc, which is not on PATH")
    core = core_sources()
    if not core:
        raise RuntimeError(f"no firmware core sources in {CORE_DIR}")
    ours = ([SIM_DIR / "sim_rig.c"] if plant_only
            else [*core, SIM_DIR / "sim_rig.c", HOST_DIR / "rigfw_host.c"])
    library, exports = ((PLANT_LIBRARY, PLANT_VERSION_SCRIPT) if plant_only
                        else (LIBRARY, VERSION_SCRIPT))
    for path in ours:
        if not path.is_file():
            raise RuntimeError(f"firmware source {path} is missing")
    BUILD_DIR.mkdir(parents=True, exist_ok=True)
    work: Path | None = Path(tempfile.mkdtemp(prefix=".host-", dir=BUILD_DIR))
    try:
        gen = work / "gen"
        gen.mkdir()
        fmu_sources, _ = generate_sources(gen, preset)
        digest = hashlib.sha256()
        headers = fmi2_headers()
        inputs = [*ours, *sorted(p for d in (CORE_DIR, SIM_DIR, HOST_DIR)
                                 for p in d.iterdir() if p.suffix in (".h", ".mk")),
                  *sorted(gen.iterdir()), *sorted(headers.glob("fmi2*.h"))]
        for path in inputs:
            name = path.name if path.parent in (gen, headers) else path.relative_to(ROOT)
            digest.update(f"{name}\0".encode() + path.read_bytes() + b"\0")
        sanitize = SANITIZE_FLAGS if os.environ.get("RIGFW_SANITIZE") == "1" else ()
        digest.update(repr((FIRMWARE_CFLAGS, CFLAGS, GENERATED_CFLAGS, sanitize,
                            plant_only)).encode())
        kind = "plant" if plant_only else "host"
        out = BUILD_DIR / f"{kind}-{_safe_name(preset)}-{digest.hexdigest()[:12]}"
        if (out / library).is_file():
            return out / library
        includes = ["-I", str(CORE_DIR), "-I", str(SIM_DIR), "-I", str(gen), "-I", str(headers)]
        objects = []
        for i, src in enumerate([*ours, *(gen / name for name in fmu_sources)]):
            if src.parent == gen:
                flags = [*CFLAGS, *(GENERATED_CFLAGS if src.name.startswith(GENERATED) else ())]
            else:  # the plant's library exports the sim's own names (no -fvisibility)
                flags = [f for f in FIRMWARE_CFLAGS
                         if not (plant_only and f.startswith("-fvisibility"))]
            obj = work / f"{i:02d}-{src.stem}.o"
            _run(["gcc", *flags, *sanitize, *includes, "-c", str(src), "-o", str(obj)], work)
            objects.append(str(obj))
        (work / "exports.map").write_text(exports)
        _run(["gcc", "-shared", *sanitize, "-Wl,-z,defs", "-Wl,--version-script=exports.map",
              *objects, "-o", library, "-lm"], work)
        work.chmod(0o755)
        try:
            work.rename(out)  # atomic: a concurrent build of the same tree keeps its own
        except OSError:
            if not (out / library).is_file():
                raise
            return out / library
        work = None
        return out / library
    finally:
        if work is not None:
            shutil.rmtree(work, ignore_errors=True)


#: firmware/sim/sim_rig.h's step timings (sim_rig_hw.step_timing) by name.
STEP_TIMINGS = {"at-once": 0, "nucleo": 1}


class SimRigHw(ctypes.Structure):
    """firmware/sim/sim_rig.h: sim_rig_hw."""

    _fields_ = [("x_origin", ctypes.c_double), ("home_x", ctypes.c_double),
                ("load_gain_n", ctypes.c_double), ("load_noise_n", ctypes.c_double),
                ("period_s", ctypes.c_double), ("noise_seed", ctypes.c_uint64),
                ("load_offset", ctypes.c_int32), ("step_timing", ctypes.c_int32),
                ("enc_sign", ctypes.c_int32), ("drop_n", ctypes.c_uint32),
                ("drop_d", ctypes.c_uint32)]


class SimRigStatus(ctypes.Structure):
    """firmware/sim/sim_rig.h: sim_rig_status."""

    _fields_ = [("hw_steps", ctypes.c_int32), ("table_steps", ctypes.c_int32),
                ("driver_enabled", ctypes.c_bool),
                ("reads", ctypes.c_uint32), ("watchdog_kicks", ctypes.c_uint32),
                ("fmu_failures", ctypes.c_uint32), ("time_s", ctypes.c_double),
                ("x", ctypes.c_double), ("platen_position", ctypes.c_double),
                ("input_force", ctypes.c_double), ("arena_used", ctypes.c_size_t)]


def fmu_start_values(physics: ClampPhysics, x_cmd: float) -> dict[str, float]:
    """The native FMU's start values for ``physics``: those of :class:`hil.host.backends.FmuPlant`
    for a RigSetup with the same preset, delta_r8, mu and x_contact (without "preset"),
    with the input at ``x_cmd`` (the table's power-on position)."""
    from hil.host.backends import RigSetup
    from toggle.params import dynamics_parameters

    setup = RigSetup(preset=physics.preset, delta_r8=physics.delta_r8, mu=physics.mu,
                     x_contact=physics.x_contact, period=physics.period)
    start: dict[str, float] = {"x_cmd": x_cmd, "drive_bandwidth": 0.0,  # as FmuPlant's
                               **{f"delta_{name}": d for name, d in setup.errors.items()},
                               **dynamics_parameters(setup.dynamics)}
    if setup.mu is not None:
        start["mu"] = setup.mu
    if setup.x_contact is not None:
        start["x_contact"] = setup.x_contact
    return start


def check_hardware(hw: RigHardware, period: float) -> None:
    """ValueError unless ``hw`` is the rig the firmware is built for (CORE_CONSTANTS) and
    the plant's step ``period`` (s) is its telemetry period."""
    for name, value in CORE_CONSTANTS.items():
        if getattr(hw, name) != value:
            raise ValueError(f"RigHardware.{name} = {getattr(hw, name)!r}: the firmware "
                             f"is built for {value!r}")
    if not math.isclose(period, hw.period, rel_tol=1e-12):
        raise ValueError(f"the plant's period {period!r} s is not the rig's telemetry "
                         f"period {hw.period!r} s")


def split_frames(data: bytes) -> tuple[list[bytes], bytes]:
    """Wire bytes -> (whole frames, each with its 0x00 delimiter; the unfinished rest)."""
    *frames, rest = data.split(b"\x00")
    return [f + b"\x00" for f in frames], rest


class FirmwareMcu:
    """The C firmware on the simulated rig, one private copy of librigfw.so per instance.

    The byte-level MCU interface: :meth:`receive` host bytes, :meth:`tick` once per period;
    both return the wire frames the MCU sent (each ending in ``b"\\x00"``). The rig's
    mechanics are the native FMU of ``physics``' preset with the parameters
    :class:`hil.host.backends.FmuPlant` gives it; ``hw`` its sensors (as
    :class:`hil.emulators.rig_hardware.Sensors`); ``seed`` the load-cell noise's.
    """

    def __init__(self, physics: ClampPhysics, hw: RigHardware, seed: int,
                 library: Path | None = None,
                 parameters: Mapping[str, float] | None = None,
                 step_timing: str = "at-once", nvm_path: Path | None = None) -> None:
        """``library``: a built librigfw.so (default: :func:`build_host_firmware` of the
        physics' preset); ``parameters``: FMU start values beyond or replacing those of
        ``physics``; ``step_timing``: when the table takes a period's steps (one of
        :data:`STEP_TIMINGS`, firmware/sim/sim_rig.h: "at-once" as hil.emulators.mcu_model, "nucleo"
        as the NUCLEO board's TIM1 emits them); ``nvm_path``: the file that is the MCU's
        non-volatile memory (its stored calibration survives this object; default: memory
        only, which survives :meth:`reset`). ValueError naming a parameter the FMU refuses
        or an unknown step timing."""
        check_hardware(hw, physics.period)
        if step_timing not in STEP_TIMINGS:
            raise ValueError(f"step_timing {step_timing!r}: expected one of "
                             f"{', '.join(STEP_TIMINGS)}")
        self.physics, self.hw, self.seed = physics, hw, seed
        library = library or os.environ.get("RIGFW_LIBRARY")  # a prebuilt one (sanitized)
        built = Path(library) if library else build_host_firmware(physics.preset)
        self._lib = self._load_private(built)
        self._declare()
        self.parameters = {**fmu_start_values(physics, hw.x_origin), **(parameters or {})}
        cell_offset, cell_gain = hw.cell  # the rig's true cell; hw.load_*: the defaults
        self._hw = SimRigHw(
            x_origin=hw.x_origin, home_x=hw.x_origin if hw.home_x is None else hw.home_x,
            load_gain_n=cell_gain, load_noise_n=hw.load_noise_n, period_s=physics.period,
            noise_seed=seed & 0xFFFF_FFFF_FFFF_FFFF, load_offset=cell_offset,
            step_timing=STEP_TIMINGS[step_timing], enc_sign=hw.encoder_sign,
            drop_n=hw.drop_steps[0], drop_d=hw.drop_steps[1])
        self._lib.rigfw_set_nvm(str(nvm_path).encode() if nvm_path else None,
                                hw.load_offset, hw.load_gain_n)
        self._open(self.parameters)
        self._partial = b""
        self._release_stop = False
        self._buf = ctypes.create_string_buffer(TX_CHUNK)

    @staticmethod
    def _load_private(library: Path) -> ctypes.CDLL:
        """dlopen a private copy: the firmware's state is static, one MCU per loaded copy."""
        folder = tempfile.mkdtemp(prefix="rigfw_")
        copy = Path(folder) / LIBRARY
        try:
            shutil.copyfile(library, copy)
            return ctypes.CDLL(str(copy))
        finally:
            shutil.rmtree(folder, ignore_errors=True)  # the mapping outlives the file

    def _declare(self) -> None:
        lib, c = self._lib, ctypes
        sizes = {"rigfw_sizeof_hw": SimRigHw, "rigfw_sizeof_status": SimRigStatus}
        for fn, struct in sizes.items():
            getattr(lib, fn).restype = c.c_size_t
            if getattr(lib, fn)() != c.sizeof(struct):
                raise RuntimeError(f"{LIBRARY}: {struct.__name__} layout differs from the C's")
        lib.rigfw_open.argtypes = [c.POINTER(SimRigHw), c.POINTER(c.c_char_p),
                                   c.POINTER(c.c_double), c.c_int, c.c_char_p, c.c_size_t]
        lib.rigfw_open.restype = c.c_int
        lib.rigfw_set_nvm.argtypes = [c.c_char_p, c.c_int32, c.c_double]
        lib.rigfw_set_nvm.restype = None
        lib.rigfw_stored_seq.restype = c.c_uint32
        lib.rigfw_rx.argtypes = [c.c_char_p, c.c_size_t, c.c_double]
        lib.rigfw_rx.restype = None
        lib.rigfw_tick.argtypes = [c.c_double]
        lib.rigfw_tick.restype = None
        lib.rigfw_tx_take.argtypes = [c.c_char_p, c.c_size_t]
        lib.rigfw_tx_take.restype = c.c_size_t
        for fn in ("rigfw_reset", "rigfw_link_lost"):
            getattr(lib, fn).argtypes = []
            getattr(lib, fn).restype = None
        lib.rigfw_boot_id.restype = c.c_uint32
        lib.rigfw_state.restype = c.c_int
        lib.rigfw_counts.argtypes = [c.POINTER(c.c_int32)] * 4
        lib.rigfw_counts.restype = None
        lib.rigfw_sim_status.argtypes = [c.POINTER(SimRigStatus)]
        lib.rigfw_sim_status.restype = None
        lib.rigfw_sim_message.restype = c.c_char_p
        lib.rigfw_force_spike.argtypes = [c.c_double, c.c_uint32]
        lib.rigfw_force_spike.restype = None
        for fn in ("rigfw_stick_load", "rigfw_stick_encoder", "rigfw_press_stop"):
            getattr(lib, fn).argtypes = [c.c_bool]
            getattr(lib, fn).restype = None
        lib.rigfw_board_fault.argtypes = [c.c_uint16, c.c_int32]
        lib.rigfw_board_fault.restype = None

    def _open(self, parameters: dict[str, float]) -> None:
        """Start the rig with these FMU parameters; ValueError naming a refused one."""
        names = (ctypes.c_char_p * len(parameters))(*(n.encode() for n in parameters))
        values = (ctypes.c_double * len(parameters))(*(float(v) for v in parameters.values()))
        err = ctypes.create_string_buffer(512)
        if self._lib.rigfw_open(ctypes.byref(self._hw), names, values, len(parameters), err,
                                len(err)) != 0:
            raise ValueError(f"the simulated rig refused its setup: {err.value.decode()}")

    # --- the byte-level MCU interface -------------------------------------------------

    def _take(self) -> list[bytes]:
        data = bytearray(self._partial)
        while n := self._lib.rigfw_tx_take(self._buf, TX_CHUNK):
            data += self._buf.raw[:n]
        frames, self._partial = split_frames(bytes(data))
        return frames

    def receive(self, data: bytes, now: float) -> list[bytes]:
        """Feed bytes from the host received at ``now`` (s); the frames the MCU sent."""
        self._lib.rigfw_rx(data, len(data), now)
        return self._take()

    def tick(self, now: float) -> list[bytes]:
        """One period at ``now`` (s): the frames it queued (FAULT/STATE, then TELEMETRY)."""
        self._lib.rigfw_tick(now)
        if self._release_stop:
            self._lib.rigfw_press_stop(False)
            self._release_stop = False
        return self._take()

    def reset(self) -> None:
        """MCU reset: new boot id, no session, counts at 0 (the rig itself is untouched)."""
        self._lib.rigfw_reset()

    def link_lost(self) -> None:
        """The host vanished (USB detach, DTR dropped): controlled stop, session ended."""
        self._lib.rigfw_link_lost()

    def press_stop(self) -> None:
        """The operator presses the stop button: held for the next tick, then released."""
        self._lib.rigfw_press_stop(True)
        self._release_stop = True

    def board_fault(self, bits: int, detail: int = 0) -> None:
        """What a board's own checks report from the next reading on (0: none)."""
        self._lib.rigfw_board_fault(bits, detail)

    def force_spike(self, newtons: float, samples: int) -> None:
        """Add ``newtons`` to the next ``samples`` load-cell readings."""
        self._lib.rigfw_force_spike(newtons, samples)

    def stick_load(self, on: bool) -> None:
        """Freeze (True) or free the load-cell reading."""
        self._lib.rigfw_stick_load(on)

    def stick_encoder(self, on: bool) -> None:
        """Freeze (True) or free the encoder reading."""
        self._lib.rigfw_stick_encoder(on)

    @property
    def boot_id(self) -> int:
        """The present boot's id (non-zero)."""
        return int(self._lib.rigfw_boot_id())

    @property
    def state(self) -> int:
        """The MCU's state (hil.link.protocol.State's values)."""
        return int(self._lib.rigfw_state())

    # --- diagnostics ------------------------------------------------------------------

    def counts(self) -> tuple[int, int, int, int]:
        """(steps, enc, load_raw) as the core reports them, and the hardware's step count."""
        out = [ctypes.c_int32() for _ in range(4)]
        self._lib.rigfw_counts(*(ctypes.byref(v) for v in out))
        return tuple(v.value for v in out)  # type: ignore[return-value]

    def sim_status(self) -> dict[str, float | int | bool]:
        """The simulated rig's counters and true outputs (sim_rig_status)."""
        st = SimRigStatus()
        self._lib.rigfw_sim_status(ctypes.byref(st))
        return {name: getattr(st, name) for name, _ in SimRigStatus._fields_}

    def sim_message(self) -> str:
        """The FMU's last logged message ("" if none)."""
        return (self._lib.rigfw_sim_message() or b"").decode(errors="replace")


__all__ = ["STEP_TIMINGS", "FirmwareMcu", "build_host_firmware", "core_sources", "fmu_start_values",
           "split_frames"]
