"""The panel's web server (aiohttp): the page, its websocket, the actions, the past runs.

It owns no rig: it starts the rig service (:mod:`hil.panel.service`) as a child process,
relays its events to every page and forwards the actions that pass
:mod:`hil.panel.access`. If this process dies, the service sees its stdin close, stops the
rig and closes the run's record (every sample kept). A page that closes or loses its
websocket gives up the command lease at once; a motion in progress goes on under the
service's host-side watchdog and the MCU's heartbeat (another page can take the command
and STOP it), exactly as a ``hil run`` with nobody watching.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json
import secrets
import sys
import tempfile
from importlib import resources
from pathlib import Path
from typing import Any

from aiohttp import WSMsgType, web

from hil.panel import access, runs
from hil.panel.access import RefusedError

STATIC = Path(__file__).with_name("static")
#: Events a slow page may have queued before newer ones are dropped for it.
PAGE_QUEUE = 256
#: Seconds the server waits for the rig service to accept or refuse an action.
REPLY_TIMEOUT = 5.0


def plotly_js() -> bytes:
    """plotly.min.js as the installed ``plotly`` package ships it (no CDN)."""
    return resources.files("plotly").joinpath("package_data/plotly.min.js").read_bytes()


class Panel:
    """The server's state: token, allowed hosts, pages, the service's pipe."""

    def __init__(self, token: str, bind: str, port: int, service_args: list[str],
                 runs_dir: Path) -> None:
        self.token, self.bind, self.port = token, bind, port
        self.hosts = access.allowed_hosts(bind, port)
        self.service_args, self.runs_dir = service_args, runs_dir
        self.clients = access.Clients()
        self.pages: dict[str, asyncio.Queue[str]] = {}
        self.replies: dict[int, asyncio.Future[dict[str, Any]]] = {}
        self.ids = itertools.count(1)
        self.proc: asyncio.subprocess.Process | None = None
        self.plans = Path(tempfile.mkdtemp(prefix="hil_panel_plans_"))
        self.plotly = plotly_js()
        self.status_line = json.dumps({"type": "status", "connected": False,
                                       "state": "STARTING"})

    # --- the rig service -------------------------------------------------------------------

    async def start_service(self) -> None:
        self.proc = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "hil.panel.service", *self.service_args,
            stdin=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.PIPE, limit=1 << 24)
        asyncio.get_running_loop().create_task(self._read_service())

    async def _read_service(self) -> None:
        assert self.proc is not None and self.proc.stdout is not None
        async for raw in self.proc.stdout:
            line = raw.decode().strip()
            try:
                event = json.loads(line)
            except json.JSONDecodeError:
                continue
            if event.get("type") == "reply":
                future = self.replies.pop(event.get("id"), None)
                if future is not None and not future.done():
                    future.set_result(event)
                continue
            if event.get("type") == "status":
                self.status_line = line
            self.broadcast(line)
        code = await self.proc.wait()
        self.broadcast(json.dumps({"type": "notice", "message": f"the rig service ended "
                                   f"(exit code {code}); restart hil panel"}))
        self.status_line = json.dumps({"type": "status", "connected": False,
                                       "state": "SERVICE ENDED"})

    async def send(self, action: str, args: dict[str, Any], **extra: Any) -> dict[str, Any]:
        """Forward an action to the service; its reply (accepted or refused)."""
        if self.proc is None or self.proc.returncode is not None or self.proc.stdin is None:
            raise RefusedError(503, "the rig service is not running")
        ident = next(self.ids)
        future = self.replies[ident] = asyncio.get_running_loop().create_future()
        self.proc.stdin.write((json.dumps({"id": ident, "action": action, "args": args,
                                           **extra}) + "\n").encode())
        await self.proc.stdin.drain()
        try:
            return await asyncio.wait_for(future, REPLY_TIMEOUT)
        except asyncio.TimeoutError:
            raise RefusedError(503, "the rig service did not answer") from None
        finally:
            self.replies.pop(ident, None)

    def broadcast(self, line: str) -> None:
        for queue in self.pages.values():
            if queue.full():
                with contextlib.suppress(asyncio.QueueEmpty):
                    queue.get_nowait()  # the oldest goes: a slow page, never a slow server
            queue.put_nowait(line)

    def lease_events(self) -> None:
        for client, queue in self.pages.items():
            queue.put_nowait(json.dumps({"type": "lease", "mine": self.clients.holder == client,
                                         "taken": self.clients.holder is not None}))


def _refusal(exc: RefusedError) -> web.Response:
    return web.json_response({"error": exc.message}, status=exc.status)


@web.middleware
async def guard(request: web.Request, handler: Any) -> web.StreamResponse:
    """Host, Origin and token on every request, before anything else runs."""
    panel: Panel = request.app["panel"]
    try:
        access.check_host(request.headers.get("Host"), panel.hosts)
        access.check_origin(request.headers.get("Origin"), panel.hosts)
        access.check_token(request.headers.get("X-Panel-Token")
                           or request.query.get("token"), panel.token)
        return await handler(request)
    except RefusedError as exc:
        return _refusal(exc)


async def index(request: web.Request) -> web.Response:
    panel: Panel = request.app["panel"]
    html = (STATIC / "index.html").read_text(encoding="utf-8")
    return web.Response(text=html.replace("{{TOKEN}}", panel.token), content_type="text/html",
                        headers={"Cache-Control": "no-store", "Referrer-Policy": "no-referrer"})


async def static(request: web.Request) -> web.Response:
    name = request.match_info["name"]
    if name == "plotly.min.js":
        body = request.app["panel"].plotly
    elif name in ("panel.js", "panel.css"):
        body = (STATIC / name).read_bytes()
    else:
        raise web.HTTPNotFound()
    kind = "text/css" if name.endswith(".css") else "application/javascript"
    return web.Response(body=body, content_type=kind)


async def page_socket(request: web.Request) -> web.WebSocketResponse:
    """A page's live feed: hello (its client id), status, samples, done, lease."""
    panel: Panel = request.app["panel"]
    ws = web.WebSocketResponse(heartbeat=5.0, max_msg_size=4096)
    await ws.prepare(request)
    client = panel.clients.join()
    queue: asyncio.Queue[str] = asyncio.Queue(PAGE_QUEUE)
    panel.pages[client] = queue
    await ws.send_str(json.dumps({"type": "hello", "client": client}))
    await ws.send_str(panel.status_line)
    panel.lease_events()

    async def pump() -> None:
        while True:
            await ws.send_str(await queue.get())

    sender = asyncio.get_running_loop().create_task(pump())
    try:
        async for msg in ws:  # the page sends nothing; reading notices the close
            if msg.type == WSMsgType.ERROR:
                break
    finally:
        sender.cancel()
        panel.pages.pop(client, None)
        panel.clients.leave(client)  # the lease goes with the page
        panel.lease_events()
    return ws


async def _json(request: web.Request) -> Any:
    if request.content_type != "application/json":
        raise RefusedError(415, "send the action as application/json")
    if request.content_length is None or request.content_length > access.MAX_ACTION_BYTES:
        raise RefusedError(413, f"an action is at most {access.MAX_ACTION_BYTES} bytes")
    try:
        return json.loads(await request.read())
    except (ValueError, UnicodeDecodeError):
        raise RefusedError(400, "the body is not JSON") from None


async def lease(request: web.Request) -> web.Response:
    panel: Panel = request.app["panel"]
    body = await _json(request)
    if not isinstance(body, dict) or not isinstance(body.get("client"), str) or \
            not isinstance(body.get("take"), bool) or set(body) - {"client", "take"}:
        raise RefusedError(400, "a lease request is {client: id, take: true|false}")
    if body["take"]:
        panel.clients.take_lease(body["client"])
    else:
        panel.clients.release(body["client"])
    panel.lease_events()
    return web.json_response({"mine": panel.clients.holder == body["client"]})


async def action(request: web.Request) -> web.Response:
    panel: Panel = request.app["panel"]
    body = await _json(request)
    act = access.parse_action(body)
    panel.clients.admit(act)
    args = dict(act.args)
    if act.name == "run" and args["job"] == "plan":
        path = panel.plans / f"{args['plan']}.csv"
        if not path.is_file():
            raise RefusedError(404, "no uploaded plan with this id")
        args["plan"] = str(path)
    click = body.get("t_click")  # the page's clock at the click (the STOP latency bench)
    extra = {"t_click": click} if isinstance(click, (int, float)) else {}
    reply = await panel.send(act.name, args, **extra)
    if not reply.get("ok"):
        raise RefusedError(409, str(reply.get("error")))
    return web.json_response({"ok": True, "action": act.name})


async def upload_plan(request: web.Request) -> web.Response:
    """A plan CSV (toggle plan --out), checked as ``hil run --profile`` reads it."""
    from hil.host.experiment import DEFAULT_PERIOD
    from hil.host.samples import Trajectory, TrajectoryError

    panel: Panel = request.app["panel"]
    if request.content_length is None or request.content_length > access.MAX_PLAN_BYTES:
        raise RefusedError(413, f"a plan is at most {access.MAX_PLAN_BYTES >> 20} MB")
    data = await request.read()
    ident = secrets.token_hex(16)
    path = panel.plans / f"{ident}.csv"
    path.write_bytes(data)
    try:
        trajectory = Trajectory.from_csv(path, period=DEFAULT_PERIOD)  # as the service
    except (TrajectoryError, ValueError, OSError) as exc:
        path.unlink(missing_ok=True)
        raise RefusedError(400, f"not a plan CSV: {exc}") from None
    return web.json_response({"plan": ident, "duration_s": trajectory.duration,
                              "points": len(trajectory)})


async def run_list(request: web.Request) -> web.Response:
    return web.json_response(runs.list_runs(request.app["panel"].runs_dir))


async def run_open(request: web.Request) -> web.Response:
    try:
        return web.json_response(runs.open_run(request.app["panel"].runs_dir,
                                               request.match_info["name"]))
    except runs.RunNotFoundError as exc:
        raise RefusedError(404, str(exc)) from None


@web.middleware
async def refusals(request: web.Request, handler: Any) -> web.StreamResponse:
    try:
        return await handler(request)
    except RefusedError as exc:
        return _refusal(exc)


def build_app(panel: Panel) -> web.Application:
    app = web.Application(middlewares=[guard, refusals], client_max_size=access.MAX_PLAN_BYTES)
    app["panel"] = panel
    app.router.add_get("/", index)
    app.router.add_get("/static/{name}", static)
    app.router.add_get("/ws", page_socket)
    app.router.add_post("/api/lease", lease)
    app.router.add_post("/api/action", action)
    app.router.add_post("/api/plan", upload_plan)
    app.router.add_get("/api/runs", run_list)
    app.router.add_get("/api/runs/{name}", run_open)
    return app


async def serve(panel: Panel, announce: Any) -> None:
    """Start the service and the web server; announce the URL; serve until cancelled."""
    await panel.start_service()
    runner = web.AppRunner(build_app(panel), access_log=None)
    await runner.setup()
    site = web.TCPSite(runner, panel.bind, panel.port)
    await site.start()
    port = runner.addresses[0][1]
    if port != panel.port:  # --http-port 0: the port the system gave
        panel.port = port
        panel.hosts = access.allowed_hosts(panel.bind, port)
    host = panel.bind if ":" not in panel.bind else f"[{panel.bind}]"
    announce(f"http://{host}:{port}/?token={panel.token}")
    try:
        await asyncio.Event().wait()
    finally:
        if panel.proc is not None and panel.proc.stdin is not None:
            panel.proc.stdin.close()  # the service stops the rig and closes the record
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(panel.proc.wait(), 30.0)
        await runner.cleanup()
