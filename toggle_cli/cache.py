"""``toggle cache``: what the compiled-code cache holds, and clearing it.

The planner's and the Monte Carlo kernel's functions are compiled once and kept in
``~/.cache/toggle-clamp`` (``TOGGLE_CACHE_DIR``), at most ``TOGGLE_CACHE_MAX_MB`` in all
(:mod:`toggle.c_library`); clearing it costs the next plan of each plant its compile.
"""

from __future__ import annotations

import argparse

from toggle_cli.common import add_json_argument, print_json, table


def _mb(size: int) -> float:
    return size / 1e6


def run(args: argparse.Namespace) -> int:
    from toggle.c_library import cache_report, clear_cache

    if args.action == "clear":
        files, freed = clear_cache()
        if args.json:
            print_json({"folder": str(cache_report().folder), "removed_files": files,
                        "removed_bytes": freed})
        else:
            print(f"removed {files} libraries and killed compiles' scratch, "
                  f"{_mb(freed):.1f} MB, from {cache_report().folder}")
        return 0
    report = cache_report()
    if args.json:
        print_json({"folder": str(report.folder), "total_bytes": report.total,
                    "cap_bytes": report.cap,
                    "libraries": {k: {"count": c, "bytes": b}
                                  for k, (c, b) in report.libraries.items()},
                    "stale_scratch": {"count": report.stale_scratch[0],
                                      "bytes": report.stale_scratch[1]}})
        return 0
    rows = [(name, count, _mb(size)) for name, (count, size) in report.libraries.items()]
    if report.stale_scratch[0]:
        rows.append(("killed compiles", report.stale_scratch[0], _mb(report.stale_scratch[1])))
    if rows:
        print(table(("kind", "files", "MB"), rows, fmt="{:>12.1f}"))
    print(f"{report.folder}: {_mb(report.total):.1f} MB of at most {_mb(report.cap):.0f} MB "
          "(TOGGLE_CACHE_MAX_MB); 'toggle cache clear' empties it")
    return 0


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("cache", help="show or clear the compiled-code cache",
                       description="Show (info) or empty (clear) the cache of compiled "
                                   "planner and Monte Carlo code (TOGGLE_CACHE_DIR).")
    p.add_argument("action", nargs="?", choices=("info", "clear"), default="info",
                   help="info: what it holds (default); clear: delete it")
    add_json_argument(p)
    p.set_defaults(handler=run)
