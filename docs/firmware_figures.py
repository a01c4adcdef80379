"""The figures of the firmware's pages, measured, written between their marker comments.

Run from the repository: ``.venv/bin/python docs/firmware_figures.py`` rewrites every block
``<!-- figures:NAME -->`` ... ``<!-- /figures:NAME -->`` of docs/firmware.md and
docs/firmware-emulated.md (:data:`BLOCKS` names each block's page) with what it
measures now; ``--check`` writes nothing and exits 1 naming the blocks whose text differs
(stale); ``--cheap`` does only the blocks that take seconds (the NUCLEO image's memory and
its step pulses on the rehosted TIM1), leaving the QEMU image's (a build of the generated
model for the F405, about a minute) as they are. ``tests/test_firmware_figures.py`` runs
``--check --cheap``.

Blocks: ``nucleo-memory`` (``make -C firmware/board nucleo``: arm-none-eabi-size -A of the
ELF, firmware/board/stack_report.py's chains), ``nucleo-pulses``
(:func:`hil.emulators.rehost.pulses.full_rate_reversal` against
:data:`hil.emulators.rehost.pulses.TMC5160`),
``nucleo-tick`` (:func:`hil.emulators.rehost.tick_cost.measure`: the image's own longest
``rig_rx`` and ``rig_tick`` in instructions), ``qemu-memory`` (the QEMU image of the
default rig, the same two tools).
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "firmware" / "board"))

from stack_report import report as stack_report  # noqa: E402

from hil.emulators.firmware import section_sizes  # noqa: E402

DOCS = ROOT / "docs"
FLASH_SECTIONS = (".isr_vector", ".text", ".rodata", ".ARM.exidx", ".data")
RAM_SECTIONS = (".data", ".bss", ".noinit")
BLOCK = re.compile(r"(<!-- figures:(?P<name>[\w-]+) -->\n)(?P<body>.*?)"
                   r"(<!-- /figures:(?P=name) -->)", re.S)


def _grouped(n: int) -> str:
    """12345 -> '12 345' (the document's thousands separator)."""
    return f"{n:,}".replace(",", " ")


def stack(folder: Path) -> tuple[int, str, int]:
    """(deepest from main, its chain, worst case with every handler nested) of an image."""
    text = stack_report(folder)
    main = re.search(r"^  main: (\d+)  <- (.*)$", text, re.M)
    worst = re.search(r"nested: (\d+) bytes", text)
    if not main or not worst:
        raise RuntimeError(f"stack_report gave no main chain for {folder}:\n{text}")
    return int(main.group(1)), main.group(2), int(worst.group(1))


def memory_rows(elf: Path, flash_total: int) -> list[str]:
    """The memory table's rows of an image."""
    size = section_sizes(elf)
    flash = sum(size.get(s, 0) for s in FLASH_SECTIONS)
    ram = sum(size.get(s, 0) for s in RAM_SECTIONS)
    deepest, chain, worst = stack(elf.parent)
    return [f"| Flash ({' + '.join(s.lstrip('.') for s in FLASH_SECTIONS if s in size)}) | "
            f"**{_grouped(flash)} B** ({flash / 1024:.1f} KiB, {100 * flash / flash_total:.1f} % "
            f"of {flash_total // 1024} KiB) |",
            f"| RAM, static ({' + '.join(s.lstrip('.') for s in RAM_SECTIONS if s in size)}) | "
            f"**{_grouped(ram)} B** |",
            f"| Deepest stack from `main` (`-fstack-usage`) | **{_grouped(deepest)} B**: "
            f"`{chain}` |",
            f"| With every interrupt nested (+104 B exception frame each) | "
            f"**{_grouped(worst)} B** |"]


def nucleo_memory() -> str:
    from hil.emulators.rehost.nucleo import build_nucleo_image

    elf = build_nucleo_image()
    rows = memory_rows(elf, 512 * 1024)
    return "\n".join(["| NUCLEO-F446RE (`make -C firmware/board nucleo`) | |", "|---|---|",
                      *rows]) + "\n"


def qemu_memory() -> str:
    from hil.emulators.firmware_qemu import build_qemu_image
    from hil.emulators.mcu_model import RigHardware
    from hil.host.backends import RigSetup

    setup = RigSetup()
    elf = build_qemu_image(setup, RigHardware(x_origin=setup.stroke[0]), seed=0)
    rows = memory_rows(elf, 1024 * 1024)
    return "\n".join(["| QEMU F405 image (chang2021, `hil emulate --firmware --qemu`) | |",
                      "|---|---|", *rows]) + "\n"


def nucleo_pulses() -> str:
    from hil.emulators.rehost.nucleo import build_nucleo_image
    from hil.emulators.rehost.pulses import TMC5160, full_rate_reversal

    _, t, _ = full_rate_reversal(build_nucleo_image(), periods=12, steps=256)
    d = TMC5160
    if t.dir_setup_s is None or t.dir_hold_s is None:
        raise RuntimeError("the full-rate reversal had no reversal")
    rows = [("STEP high", t.step_high_s, d.step_high_s), ("STEP low", t.step_low_s,
                                                          d.step_low_s),
            ("DIR setup before STEP", t.dir_setup_s, d.dir_setup_s),
            ("DIR hold after STEP", t.dir_hold_s, d.dir_hold_s)]
    lines = [f"{t.bursts} bursts, {_grouped(t.pulses)} rising edges on PA8 (12 periods of 256 "
             f"steps out, 12 back at once):", "",
             f"| | Shortest on the modelled TIM1 | {d.name} minimum | Margin |",
             "|---|---|---|---|"]
    lines += [f"| {name} | {got * 1e6:.2f} µs | {need * 1e9:.0f} ns | {got / need:.0f}× |"
              for name, got, need in rows]
    return "\n".join(lines) + "\n"


def nucleo_tick() -> str:
    from hil.emulators.rehost.nucleo import build_nucleo_image
    from hil.emulators.rehost.tick_cost import CPU_HZ, STEP_ARM_DEADLINE_S, measure

    c = measure(build_nucleo_image())
    us = lambda n, cpi: n * cpi / CPU_HZ * 1e6  # noqa: E731
    rows = [("one `rig_rx` call of a CONFIG over the full 2048-point buffer", c.config_rx),
            ("longest `rig_rx` call (≤ 64 bytes: a frame's CRC, decoding, execution)",
             c.rx_max),
            ("longest `rig_tick` (RUNNING, STOPPING, a fault)", c.tick_max)]
    lines = [f"{c.ticks} ticks, {c.late_ticks} late, {c.step_errors} bursts armed late "
             "(`board_tick_stats` of the rehosted image, one DWT count per instruction):", "",
             "| | Instructions | at CPI 1 | at CPI 3 |", "|---|---|---|---|"]
    lines += [f"| {name} | {_grouped(n)} | {us(n, 1):.0f} µs | {us(n, 3):.0f} µs |"
              for name, n in rows]
    lines += ["", f"A tick due during the longest `rig_rx`, plus the longest tick: "
              f"{_grouped(c.rx_max + c.tick_max)} instructions, within the step generator's "
              f"{STEP_ARM_DEADLINE_S * 1e6:.0f} µs arming deadline up to a CPI of "
              f"{c.deadline_cpi():.1f}."]
    return "\n".join(lines) + "\n"


#: Block name -> (generator, cheap, the page under docs/ that holds it).
BLOCKS: dict[str, tuple[Callable[[], str], bool, str]] = {
    "nucleo-memory": (nucleo_memory, True, "firmware-emulated.md"),
    "nucleo-pulses": (nucleo_pulses, True, "firmware.md"),
    "nucleo-tick": (nucleo_tick, True, "firmware-emulated.md"),
    "qemu-memory": (qemu_memory, False, "firmware-emulated.md"),
}
PAGES = sorted({page for _, _, page in BLOCKS.values()})


def blocks_of(doc: Path, names: list[str]) -> list[str]:
    """Of ``names``, the blocks the page named like ``doc`` holds; all of them for a file
    named like no page."""
    mine = [n for n in names if BLOCKS[n][2] == doc.name]
    return mine if doc.name in PAGES else names


def update(text: str, names: list[str], where: str = "the document") -> tuple[str, list[str]]:
    """``text`` (of the file ``where``) with the blocks ``names`` regenerated, and the names
    whose body changed. ValueError naming a block the text lacks."""
    found = {m.group("name") for m in BLOCK.finditer(text)}
    missing = [n for n in names if n not in found]
    if missing:
        raise ValueError(f"{where} has no block {', '.join(missing)} "
                         f"(<!-- figures:NAME --> ... <!-- /figures:NAME -->)")
    bodies = {name: BLOCKS[name][0]() for name in names}
    stale: list[str] = []

    def replace(m: re.Match[str]) -> str:
        name = m.group("name")
        if name not in bodies:
            return m.group(0)
        if bodies[name] != m.group("body"):
            stale.append(name)
        return m.group(1) + bodies[name] + m.group(4)

    return BLOCK.sub(replace, text), stale


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true",
                        help="write nothing; exit 1 if a block is stale")
    parser.add_argument("--cheap", action="store_true",
                        help="only the blocks that take seconds")
    parser.add_argument("--doc", type=Path, help="one document, with the blocks of the page "
                        "of its name (default: every page, docs/" + ", docs/".join(PAGES) + ")")
    args = parser.parse_args(argv)
    names = [n for n, (_, cheap, _) in BLOCKS.items() if cheap or not args.cheap]
    docs = [args.doc] if args.doc else [DOCS / page for page in PAGES]
    written: dict[Path, tuple[str, str, list[str]]] = {}
    try:
        for doc in docs:
            text = doc.read_text()
            written[doc] = (text, *update(text, blocks_of(doc, names), doc.name))
    except (OSError, ValueError, RuntimeError, subprocess.CalledProcessError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if args.check:
        for doc, (_, _, stale) in written.items():
            for name in stale:
                print(f"{doc}: block {name} is stale (run docs/firmware_figures.py)")
        return 1 if any(stale for _, _, stale in written.values()) else 0
    from toggle.files import atomic_path

    for doc, (text, new, stale) in written.items():
        if new != text:
            with atomic_path(doc) as tmp:
                tmp.write_text(new)
        print(f"{doc}: {', '.join(stale) or 'nothing'} regenerated")
    return 0


if __name__ == "__main__":
    sys.exit(main())
