"""Deepest stack of a board image, from GCC's per-function stack usage.

Reads the .ci files (-fcallgraph-info=su: the call graph with each function's frame, the
same numbers as the .su files of -fstack-usage) of build/firmware/board-*/obj/, and prints
the deepest call chain from main and from each interrupt handler, and the worst case of
main with every interrupt nested on top (each exception adds its hardware frame: 26 words
with the FPU's lazy state, 104 bytes). Functions without a frame size are library code
(newlib, libgcc): they are listed, not counted, and the report says so.

    python firmware/board/stack_report.py build/firmware/board-nucleo
"""

from __future__ import annotations

import re
import sys
from functools import cache
from pathlib import Path

EXCEPTION_FRAME = 104  # bytes pushed on exception entry with an active FP context
ROOTS = ("main", "rig_tick", "rig_rx")
HANDLERS = ("SysTick_Handler", "TIM5_IRQHandler", "USART1_IRQHandler", "USART2_IRQHandler",
            "DMA1_Stream6_IRQHandler", "TIM1_UP_TIM10_IRQHandler")

NODE = re.compile(r'node: \{ title: "([^"]+)" label: "([^"]*)"')
EDGE = re.compile(r'edge: \{ sourcename: "([^"]+)" targetname: "([^"]+)"')


def load(obj: Path) -> tuple[dict[str, tuple[str, int | None, str]], dict[str, set[str]]]:
    """{title: (name, bytes or None, qualifier)}, {title: callee titles} of every .ci."""
    nodes: dict[str, tuple[str, int | None, str]] = {}
    edges: dict[str, set[str]] = {}
    for ci in sorted(obj.glob("*.ci")):
        text = ci.read_text()
        for title, label in NODE.findall(text):
            parts = label.split("\\n")
            size = re.match(r"(\d+) bytes \((\w+)", parts[-1]) if len(parts) > 2 else None
            if size:
                nodes[title] = (parts[0], int(size.group(1)), size.group(2))
            else:
                nodes.setdefault(title, (parts[0], None, "library"))
        for src, dst in EDGE.findall(text):
            edges.setdefault(src, set()).add(dst)
    return nodes, edges


def report(folder: Path) -> str:
    nodes, edges = load(folder / "obj")
    by_name = {name: title for title, (name, size, _) in nodes.items() if size is not None}
    uncounted: set[str] = set()
    dynamic: set[str] = set()

    @cache
    def deepest(title: str, depth: int = 0) -> tuple[int, tuple[str, ...]]:
        name, size, kind = nodes.get(title, (title, None, "library"))
        if size is None:
            resolved = by_name.get(name)
            if resolved is None or resolved == title:
                uncounted.add(name)
                return 0, (f"{name} (library: not counted)",)
            return deepest(resolved, depth)
        if kind != "static":
            dynamic.add(name)
        if depth > 64:
            return 0, (f"{name} (recursion?)",)
        best: tuple[int, tuple[str, ...]] = (0, ())
        for callee in sorted(edges.get(title, ())):
            found = deepest(callee, depth + 1)
            if found[0] > best[0] or not best[1]:
                best = found
        return size + best[0], (f"{name} {size}",) + best[1]

    lines = [f"stack of {folder.name} (bytes; frame sizes from -fstack-usage):"]
    totals = {}
    for root in (*ROOTS, *HANDLERS):
        if root not in by_name:
            continue
        total, chain = deepest(by_name[root])
        totals[root] = total
        lines.append(f"  {root}: {total}  <- " + " > ".join(chain))
    handlers = [h for h in HANDLERS if h in totals]
    worst = totals.get("main", 0) + sum(totals[h] + EXCEPTION_FRAME for h in handlers)
    lines.append(f"  worst case, main with {', '.join(handlers) or 'no handler'} nested: "
                 f"{worst} bytes (+{EXCEPTION_FRAME} per exception frame)")
    if uncounted:
        lines.append("  not counted (no frame size: newlib/libgcc): "
                     + ", ".join(sorted(uncounted)))
    if dynamic:
        lines.append("  dynamic or bounded frames: " + ", ".join(sorted(dynamic)))
    return "\n".join(lines)


if __name__ == "__main__":
    for arg in sys.argv[1:]:
        print(report(Path(arg)))
