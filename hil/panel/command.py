"""``hil panel``: the front panel in the browser (docs/panel.md).

Starts the rig service (the simulated rig, or ``--real --port P``: the rig or its emulator)
and a web server on loopback, and prints the page's URL once, with its access token.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import ipaddress
import sys
from pathlib import Path
from typing import Any

from hil.host.run_settings import check_port
from toggle.args import number
from toggle.files import check_writable_dir
from toggle.params import ParameterError, load_preset

DESCRIPTION = ("Start the rig service (the simulated rig, or --real --port P: the rig or its "
               "emulator) and a web server on loopback; print the page's URL once, with its "
               "access token. Ctrl-C stops the rig and closes the run's record first.")


def add_parser(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "panel", help="the front panel: live charts, operator actions, past runs, in the "
                      "browser", description=DESCRIPTION)
    p.add_argument("--real", action="store_const", const="rig", dest="backend", default=None,
                   help="the real rig (or an emulator) on --port instead of the FMU")
    p.add_argument("--port", default=None, help="serial URL of the rig (needs --real)")
    p.add_argument("--bind", default="127.0.0.1",
                   help="address to serve on; anything but loopback exposes the rig's "
                        "controls to the network (the token still guards them)")
    p.add_argument("--http-port", type=int, default=8044, dest="http_port",
                   help="TCP port of the page (0: any free one)")
    p.add_argument("--runs", type=Path, default=Path("runs"),
                   help="folder of the run directories (new runs go there, past ones are "
                        "listed from there)")
    p.add_argument("--preset", default="chang2021", help="clamp preset of the rig")
    p.add_argument("--force-limit", type=number(1.0, 5000.0, "must be a force in N"),
                   default=400.0, dest="force_limit",
                   help="host-side stop on |input force|, N (default 400 N, the rig's load cell)")
    for name, what in (("ack-ms", "the host's wait for an ACK"),
                       ("watchdog-ms", "the host's watchdog on telemetry silence"),
                       ("heartbeat-ms", "the MCU's heartbeat watchdog")):
        p.add_argument(f"--{name}", type=number(1.0, 10_000.0, "must be in ms, 1 to 10000"),
                       default=None, help=f"with --real: {what}, ms, as in hil run (default: "
                                          "measured from the link when the session opens)")
    p.set_defaults(handler=panel)


def panel(args: argparse.Namespace) -> int:
    from hil.panel.access import new_token
    from hil.panel.server import Panel, serve

    args.backend = args.backend or "fmu"
    if args.backend == "rig":
        if args.port is None:
            raise ParameterError("--real needs --port (the rig's serial URL)")
        check_port(args.port)
    elif args.port is not None:
        raise ParameterError("--port needs --real")
    load_preset(args.preset)  # an unknown or invalid preset: told before anything starts
    check_writable_dir(args.runs, "--runs")  # where every run's record goes: before the start
    if not 0 <= args.http_port <= 65535:
        raise ParameterError(f"--http-port must be a TCP port, got {args.http_port}")
    try:
        loopback = ipaddress.ip_address(args.bind).is_loopback
    except ValueError:
        raise ParameterError(f"--bind must be an IP address, got {args.bind!r}") from None
    if not loopback:
        print(f"hil panel: serving on {args.bind}: anyone who can reach it and has the token "
              "commands the rig", file=sys.stderr)
    service = ["--backend", args.backend, "--runs", str(args.runs), "--preset", args.preset,
               "--force-limit", repr(args.force_limit)]
    if args.port is not None:
        service += ["--port", args.port]
    for name in ("ack_ms", "watchdog_ms", "heartbeat_ms"):
        if getattr(args, name) is not None:
            service += [f"--{name.replace('_', '-')}", repr(getattr(args, name))]
    state = Panel(new_token(), args.bind, args.http_port, service, args.runs)
    with contextlib.suppress(KeyboardInterrupt):
        asyncio.run(serve(state, lambda url: print(f"hil panel: {url}", flush=True)))
    return 0
