"""``hil rsm``: fit the response surfaces of section 5.2 to runs (or to the paper's tables)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from toggle.args import path
from toggle.files import atomic_path, check_writable, check_writable_dir, print_results
from toggle.params import load_preset

#: The fit's coefficients (SI and the paper's units) in ``--out``.
RSM_JSON = "rsm.json"


def add_parser(subparsers: Any) -> None:
    """Register ``rsm`` on the ``hil`` command's sub-parsers."""
    p = subparsers.add_parser(
        "rsm", help="fit the response surfaces (Eqs 44-47) to runs and draw contour maps",
        description="Least-squares fit of the modified cubic model in v and delta_r8 to the "
                    "summaries of reciprocating runs (>= 3 speeds x 3 link errors), as in "
                    "Chang, Lee & Hsu 2021, section 5.2. Coefficients are printed in the "
                    "paper's units (v in mm/s, delta_r8 in mm; mm or N); --json gives SI too.",
    )
    p.add_argument("runs", nargs="*", metavar="RUN", help="run directories or summary.json files")
    p.add_argument("--paper-tables", action="store_true",
                   help="fit the means of the paper's Tables 3-8 instead, and compare with "
                        "its Eqs 44-47")
    p.add_argument("--preset", default=None,
                   help="nominal mechanism: plot against the platen error at the toggle "
                        "dL_TP (as the paper's Figures 17-20) instead of delta_r8")
    p.add_argument("--out", type=path, default=None, metavar="DIR",
                   help="results folder for rsm.json and the contour maps (PNG), named on "
                        "the last line")
    p.add_argument("--json", action="store_true", help="print machine-readable JSON")
    p.set_defaults(handler=run, checks_outputs=True)


def _printed_comparison(fit_paper: dict[str, tuple[float, ...]]) -> dict[str, Any]:
    """Each printed coefficient of Eqs 44-47 next to the fitted one and whether they agree
    to the printed digits (half a unit in the last printed place)."""
    from hil.host.rsm import load_paper_tables

    printed = load_paper_tables().equations
    out = {}
    for name, coefs in fit_paper.items():
        rows = []
        for text, value in zip(printed[name], coefs):
            decimals = len(text.split(".")[1]) if "." in text else 0
            rows.append({"printed": float(text), "printed_text": text, "fitted": value,
                         "agrees": abs(value - float(text)) <= 0.5 * 10.0**-decimals})
        out[name] = rows
    return out


def _outputs(out: Path) -> list[Path]:
    """The files ``--out`` may get: rsm.json and a contour map per response."""
    from hil.host.rsm import RESPONSES, RSM_FIGURE

    return [out / RSM_JSON, *(out / RSM_FIGURE.format(name) for name in RESPONSES)]


def run(args: argparse.Namespace) -> int:
    """Fit, print and write the response surfaces (numpy and the fit load here, not with the
    parser)."""
    from hil.host.rsm import (
        RESPONSES,
        TERMS,
        RsmError,
        fit_rsm,
        load_paper_tables,
        load_summaries,
        plot_rsm,
        toggle_cos_theta8,
    )
    from toggle.json_text import json_text

    if args.paper_tables == bool(args.runs):
        raise RsmError("give run directories or --paper-tables (one of the two)")
    if args.out is not None:  # before the work: an earlier fit's files only with --force
        check_writable_dir(args.out, "--out")
        for target in _outputs(args.out):
            check_writable(target, "--out")
    fit = fit_rsm(load_paper_tables() if args.paper_tables else load_summaries(args.runs))
    payload = fit.to_dict()
    paper = {name: r.paper_coefficients for name, r in fit.responses.items()}
    if args.paper_tables:
        payload["printed_equations"] = _printed_comparison(paper)
    cos8 = toggle_cos_theta8(load_preset(args.preset)) if args.preset else None
    if args.out is not None:
        figures = plot_rsm(fit, args.out, cos_theta8=cos8)
        payload["figures"] = [str(p) for p in figures]
        with atomic_path(args.out / RSM_JSON) as tmp:
            tmp.write_text(json_text(payload) + "\n", encoding="utf-8")
    if args.json:
        print(json_text(payload))
        _results(args, payload)
        return 0
    print(f"modified cubic model fitted to {len(fit.speed)} points "
          "(v in mm/s, delta_r8 = D in mm; coefficients in mm or N)")
    for name, r in fit.responses.items():
        eq, unit, _ = RESPONSES[name]
        print(f"\n{name} [{unit}] ({eq} model): residual norm "
              f"{r.residual_norm * RESPONSES[name][2]:.4g} {unit}, R^2 {r.r_squared:.4f}")
        rows = payload.get("printed_equations", {}).get(name)
        for i, term in enumerate(TERMS):
            line = f"  {term:>6}  {r.paper_coefficients[i]:>14.6g}"
            if rows:
                mark = "agrees" if rows[i]["agrees"] else "differs"
                line += f"   printed {rows[i]['printed_text']:>12}  {mark}"
            print(line)
    _results(args, payload)
    return 0


def _results(args: argparse.Namespace, payload: dict[str, Any]) -> None:
    if args.out is not None:
        print_results([args.out / RSM_JSON, *map(Path, payload["figures"])],
                      to_stderr=args.json)
