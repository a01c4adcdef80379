"""The panel's security battery (issue 44) and what a closed tab or a dead web server does.

Against ``hil panel --real`` on the model MCU's emulator: no token, a wrong token, a
cross-origin request with the right token, another Host name, a websocket from another
Origin, each refused; 1000 forged action requests (a seeded generator: each carries at
least one defect that must refuse it) give 4xx and move nothing (the emulator counts the
motion commands it received); a second page only watches. A page that closes its websocket
mid-run leaves the run going (the rig service's watchdog and the MCU's heartbeat guard
it), frees the command, and another page STOPs it. A killed web server: the rig service
stops the rig and samples.csv holds every sample up to the standstill.
"""

from __future__ import annotations

import asyncio
import contextlib
import http.client
import json
import os
import random
import signal
from pathlib import Path
from typing import Any

import pytest

from hil.panel import access
from hil.panel.access import RefusedError
from tests.panel_support import PanelProcess, recorded, sent_until_standstill, wait_until
from tests.test_panel_browser import ModelRig

aiohttp = pytest.importorskip("aiohttp")


# --- the checks alone (no server) --------------------------------------------------------

@pytest.mark.parametrize("body, status, words", [
    ([], 400, "JSON object"),
    ({"action": "launch", "client": "x" * 32, "seq": 1}, 400, "unknown action"),
    ({"action": "jog", "args": {"by": "1"}, "client": "x" * 32, "seq": 1, "confirm": True},
     400, "must be a number"),
    ({"action": "jog", "args": {"by": True}, "client": "x" * 32, "seq": 1, "confirm": True},
     400, "must be a number"),
    ({"action": "jog", "args": {"by": 1e300}, "client": "x" * 32, "seq": 1, "confirm": True},
     400, "within"),
    ({"action": "jog", "args": {"by": 1e-3, "to": 0.0}, "client": "x" * 32, "seq": 1,
      "confirm": True}, 400, "one of to"),
    ({"action": "home", "client": "x" * 32, "seq": 1}, 400, "confirm"),
    ({"action": "run", "args": {"job": "speed", "cycles": 2}, "client": "x" * 32, "seq": 1,
      "confirm": True}, 400, "needs speed"),
    ({"action": "stop", "client": "x" * 32, "seq": 1.5}, 400, "seq"),
    ({"action": "stop", "client": "x" * 32, "seq": 1, "admin": 1}, 400, "unknown field"),
])
def test_a_malformed_action_is_refused_with_one_message(body: Any, status: int,
                                                       words: str) -> None:
    with pytest.raises(RefusedError) as caught:
        access.parse_action(body)
    assert caught.value.status == status and words in caught.value.message


def test_the_lease_and_the_sequence() -> None:
    clients = access.Clients()
    a, b = clients.join(), clients.join()
    clients.take_lease(a)
    with pytest.raises(RefusedError, match="another page"):
        clients.take_lease(b)
    home = access.parse_action({"action": "home", "client": b, "seq": 1, "confirm": True})
    with pytest.raises(RefusedError, match="only watches"):
        clients.admit(home)
    clients.admit(access.parse_action({"action": "stop", "client": b, "seq": 2}))  # anyone
    clients.admit(access.parse_action({"action": "home", "client": a, "seq": 1,
                                       "confirm": True}))
    with pytest.raises(RefusedError, match="replayed"):
        clients.admit(access.parse_action({"action": "home", "client": a, "seq": 1,
                                           "confirm": True}))
    clients.leave(a)  # the page closed: the command is free
    clients.take_lease(b)


def test_host_origin_and_token_checks() -> None:
    hosts = access.allowed_hosts("127.0.0.1", 8044)
    access.check_host("localhost:8044", hosts)
    for bad in ("evil.example:8044", "127.0.0.1:8045", None):
        with pytest.raises(RefusedError):
            access.check_host(bad, hosts)
    access.check_origin("http://127.0.0.1:8044", hosts)
    for bad in ("http://evil.example", "https://127.0.0.1:8044", "null"):
        with pytest.raises(RefusedError):
            access.check_origin(bad, hosts)
    with pytest.raises(RefusedError) as caught:
        access.check_token("a" * 43, "b" * 43)
    assert caught.value.status == 403


# --- against the server on the emulator ----------------------------------------------------

def _request(panel: PanelProcess, method: str, path: str, body: bytes = b"",
             headers: dict[str, str] | None = None) -> tuple[int, dict[str, Any]]:
    conn = http.client.HTTPConnection("127.0.0.1", panel.port, timeout=30)
    try:
        conn.putrequest(method, path, skip_host=True, skip_accept_encoding=True)
        sent = {"Host": f"127.0.0.1:{panel.port}", "X-Panel-Token": panel.token,
                "Content-Type": "application/json", **(headers or {})}
        for key, value in sent.items():
            if value is not None:
                conn.putheader(key, value)
        conn.putheader("Content-Length", str(len(body)))
        conn.endheaders(body)
        response = conn.getresponse()
        data = response.read()
        try:
            return response.status, json.loads(data)
        except ValueError:
            return response.status, {"raw": data[:100]}
    finally:
        conn.close()


class Page:
    """A page without a browser: its websocket (client id, events) and its actions."""

    def __init__(self, panel: PanelProcess) -> None:
        self.panel, self.events, self.seq = panel, [], 0
        self.loop = asyncio.new_event_loop()
        self.session = self.loop.run_until_complete(self._open())
        self.client = self._next("hello")["client"]

    async def _open(self) -> Any:
        session = aiohttp.ClientSession()
        self.ws = await session.ws_connect(
            f"{self.panel.base}/ws?token={self.panel.token}")
        return session

    def _next(self, kind: str, timeout: float = 30.0) -> dict[str, Any]:
        async def take() -> dict[str, Any]:
            while True:
                event = json.loads((await self.ws.receive(timeout)).data)
                self.events.append(event)
                if event["type"] == kind:
                    return event
        return self.loop.run_until_complete(take())

    def drain(self, seconds: float) -> None:
        async def take() -> None:
            end = self.loop.time() + seconds
            while self.loop.time() < end:
                try:
                    msg = await self.ws.receive(max(0.01, end - self.loop.time()))
                except asyncio.TimeoutError:
                    return
                if msg.type == aiohttp.WSMsgType.TEXT:
                    self.events.append(json.loads(msg.data))
        self.loop.run_until_complete(take())

    def act(self, action: str, **args: Any) -> tuple[int, dict[str, Any]]:
        self.seq += 1
        body = {"action": action, "args": args, "client": self.client, "seq": self.seq,
                "confirm": True if access.ACTIONS[action][1] else None}
        body = {k: v for k, v in body.items() if v is not None}
        return _request(self.panel, "POST", "/api/action", json.dumps(body).encode())

    def lease(self, take: bool = True) -> int:
        return _request(self.panel, "POST", "/api/lease", json.dumps(
            {"client": self.client, "take": take}).encode())[0]

    def close(self) -> None:
        with contextlib.suppress(OSError, aiohttp.ClientError, asyncio.TimeoutError):
            self.loop.run_until_complete(self.ws.close())
        self.loop.run_until_complete(self.session.close())
        self.loop.close()


@pytest.fixture
def rig_panel(tmp_path: Path) -> Any:
    rig = ModelRig()
    panel = PanelProcess(tmp_path / "runs", "--real", "--port", rig.port)
    try:
        yield rig, panel
    finally:
        panel.close()
        rig.close()


def _ws_refused(panel: PanelProcess, url: str, headers: dict[str, str]) -> int:
    async def attempt() -> int:
        async with aiohttp.ClientSession() as session:
            try:
                async with session.ws_connect(url, headers=headers):
                    return 101
            except aiohttp.WSServerHandshakeError as exc:
                status = exc.status
            await asyncio.sleep(0.05)  # the refused response's connection closes first
            return status
    return asyncio.run(attempt())


def _forged(rng: random.Random, client: str, last_seq: int) -> tuple[bytes, dict[str, str]]:
    """A moving action with at least one defect that must refuse it, and maybe more."""
    action = rng.choice(["home", "jog", "run", "check"])
    args = {"jog": {"by": 1e-3}, "run": {"job": "speed", "cycles": 2, "speed": 0.02}}.get(
        action, {})
    body: dict[str, Any] = {"action": action, "args": dict(args), "client": client,
                            "seq": last_seq + 1 + rng.randrange(1000), "confirm": True}
    headers: dict[str, str] = {}
    junk = [None, True, "1", [], {}, 1e308, -1, "NaN", 2**64, "x" * 300]

    def replay() -> None: body["seq"] = rng.randint(-3, last_seq)
    def unknown() -> None: body["action"] = rng.choice(["launch", "HOME", "", "run ", "stop!"])
    def wrong_type() -> None:
        key = rng.choice(["seq", "client", "args", "confirm", "action"])
        body[key] = rng.choice([v for v in junk if not (  # a value that is right there
            (key == "confirm" and v is True) or (key == "args" and v == {}))])
    def extra() -> None: body[rng.choice(["admin", "token", "lease", "__proto__"])] = 1
    def no_confirm() -> None: body.pop("confirm")
    def stranger() -> None: body["client"] = f"{rng.getrandbits(128):032x}"
    def bad_arg() -> None: body["args"] = {"by": rng.choice(junk[1:])} if action == "jog" \
        else {"bogus": rng.choice(junk)}
    def oversized() -> None: body["args"] = {"pad": "x" * access.MAX_ACTION_BYTES}
    def header() -> None:
        key, value = rng.choice([("X-Panel-Token", "wrong"), ("X-Panel-Token", ""),
                                 ("Host", "evil.example"), ("Origin", "http://evil.example"),
                                 ("Content-Type", "text/plain")])
        headers[key] = value

    defects = [replay, unknown, wrong_type, extra, no_confirm, stranger, bad_arg, oversized,
               header]
    for defect in rng.sample(defects, rng.randint(1, 3)):
        defect()
    text = json.dumps(body).encode()
    if rng.random() < 0.05:
        text = text[:rng.randrange(1, len(text))]  # cut: not JSON (the defects still hold)
    return text, headers


@pytest.mark.real_time
def test_security_battery(rig_panel: Any) -> None:
    rig, panel = rig_panel
    base = f"127.0.0.1:{panel.port}"
    assert _request(panel, "GET", "/api/runs", headers={"X-Panel-Token": None})[0] == 401
    assert _request(panel, "GET", "/api/runs", headers={"X-Panel-Token": "x" * 43})[0] == 403
    status, body = _request(panel, "GET", "/api/runs",
                            headers={"Origin": "http://evil.example"})
    assert status == 403 and "cross-origin" in body["error"]
    status, body = _request(panel, "GET", "/api/runs",
                            headers={"Host": f"evil.example:{panel.port}"})
    assert status == 403 and "DNS rebinding" in body["error"]
    assert _request(panel, "GET", "/", headers={"X-Panel-Token": None})[0] == 401
    assert _request(panel, "GET", "/api/runs")[0] == 200
    ws = f"{panel.base}/ws?token={panel.token}"
    assert _ws_refused(panel, ws, {"Origin": "http://evil.example"}) == 403
    assert _ws_refused(panel, f"{panel.base}/ws", {"Origin": f"http://{base}"}) == 401
    assert _ws_refused(panel, ws, {"Origin": f"http://{base}"}) == 101

    status, body = _request(panel, "POST", "/api/plan", b"time [s],x\n0,1\n",
                            {"Content-Type": "text/csv"})
    assert status == 400 and "not a plan CSV" in body["error"]
    page, watcher = Page(panel), Page(panel)
    try:
        assert page.lease() == 200 and watcher.lease() == 409
        status, body = watcher.act("home")
        assert status == 403 and "only watches" in body["error"]
        for _ in range(3):
            assert page.act("stop")[0] == 200  # sequence material for the replays
        wait_until(lambda: rig.sent(), 30, "telemetry")
        motions = rig.motions()
        rng = random.Random(44)
        statuses: dict[int, int] = {}
        for _ in range(1000):
            body, headers = _forged(rng, page.client, page.seq)
            status, answer = _request(panel, "POST", "/api/action", body, headers)
            statuses[status] = statuses.get(status, 0) + 1
            assert 400 <= status < 500 and isinstance(answer.get("error"), str), (body, answer)
        print(f"1000 forged actions: {dict(sorted(statuses.items()))}")
        assert panel.proc.poll() is None  # no crash
        page.drain(0.5)
        assert rig.motions() == motions == 0  # nothing moved, nothing was even sent
    finally:
        page.close()
        watcher.close()


def _speed_job(page: Page, rig: ModelRig) -> None:
    assert page.lease() == 200
    status, body = page.act("run", job="speed", speed=0.04, cycles=50)
    assert status == 200, body
    wait_until(lambda: any(e["type"] == "samples" for e in page.events) or page.drain(0.2),
               180, "the run's samples")
    # the page's message names the run once it moves, not the homing before it (stop 50)
    notices = [e["message"] for e in page.events if e["type"] == "notice"]
    assert notices and notices[-1].startswith("running: reciprocating at 40 mm/s, 50 cycles"), \
        notices


@pytest.mark.real_time
def test_a_closed_tab_leaves_the_run_guarded_and_another_page_stops_it(rig_panel: Any) -> None:
    rig, panel = rig_panel
    page = Page(panel)
    _speed_job(page, rig)
    page.close()  # the commanding tab closes mid-run
    before = len(rig.sent())
    other = Page(panel)
    try:
        other.drain(1.0)
        done = [e["message"] for e in other.events if e["type"] in ("done", "notice")]
        assert len(rig.sent()) > before and rig.sent()[-1][1] == 2, done  # RUNNING: going on
        assert other.lease() == 200  # the command was freed with the tab
        assert other.act("stop")[0] == 200
        wait_until(lambda: other.drain(0.2) or any(
            e["type"] == "done" and "STOP from the panel" in e["message"]
            for e in other.events), 60, "the stopped run")
    finally:
        other.close()


@pytest.mark.real_time
def test_a_killed_web_server_stops_the_rig_and_loses_no_sample(rig_panel: Any) -> None:
    rig, panel = rig_panel
    page = Page(panel)
    _speed_job(page, rig)
    run_dir = Path(next(e["run_dir"] for e in reversed(page.events)
                        if e["type"] == "status" and e.get("run_dir")))
    os.kill(panel.proc.pid, signal.SIGKILL)  # no cleanup at all in the web server
    wait_until(lambda: (run_dir / "summary.json").is_file(), 60,
               "the rig service to close the run")
    wait_until(lambda: rig.sent()[-1][1] == 1, 30,  # IDLE: at a standstill
               lambda: f"the rig at a standstill (IDLE), not {rig.sent()[-20:]}")
    rows = recorded(run_dir)
    assert [s for s, _ in rows] == sent_until_standstill(rig.sent(), rows[0][0])
    meta = json.loads((run_dir / "meta.json").read_text())
    assert meta["aborted"] and "web server went away" in meta["abort_reason"]
    page.close()
