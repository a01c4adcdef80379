"""Who may talk to the panel and what an action may say: the token, the Host and Origin
checks, the command lease and the actions' schemas. Pure functions and small classes, no
web framework, so the security battery tests them directly and through the server.

Every check fails with :class:`RefusedError` (an HTTP status and one message); nothing is moved
before every check passed.
"""

from __future__ import annotations

import hmac
import math
import secrets
from dataclasses import dataclass, field
from typing import Any
from urllib.parse import urlsplit

#: Loopback names the panel answers to (with its port); any other Host is refused unless
#: the server was bound to that address on purpose (DNS rebinding, Jupyter's rule).
LOCAL_HOSTS = ("127.0.0.1", "localhost", "[::1]")
#: Largest action request body, bytes.
MAX_ACTION_BYTES = 4096
#: Largest uploaded plan CSV, bytes (a 10-minute plan at 1 kHz is about 0.3 MB).
MAX_PLAN_BYTES = 4 << 20
#: Longest cycle count the panel starts (the CLI's --max-duration guards the rest).
MAX_CYCLES = 1000


class RefusedError(Exception):
    """A request refused: ``status`` (4xx) and one message for the operator."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status, self.message = status, message


def new_token() -> str:
    """A random access token (256 bits, URL-safe), as Jupyter's."""
    return secrets.token_urlsafe(32)


def check_token(given: str | None, token: str) -> None:
    """The token, compared in constant time."""
    if not given:
        raise RefusedError(401, "no access token: open the URL the panel printed")
    if not hmac.compare_digest(given.encode(), token.encode()):
        raise RefusedError(403, "wrong access token")


def allowed_hosts(bind: str, port: int) -> frozenset[str]:
    """Host header values the panel answers: loopback names, and the bound address."""
    names = {*LOCAL_HOSTS, bind if ":" not in bind else f"[{bind}]"}
    return frozenset(f"{name}:{port}" for name in names)


def check_host(host: str | None, allowed: frozenset[str]) -> None:
    if host is None or host.lower() not in allowed:
        raise RefusedError(403, f"Host {host!r} is not this panel's (DNS rebinding is refused)")


def check_origin(origin: str | None, allowed: frozenset[str]) -> None:
    """A browser's Origin, when sent, must be the panel itself (cross-site refused)."""
    if origin is None:
        return  # not a browser (curl, the tests' client): the token alone
    parts = urlsplit(origin)
    if parts.scheme != "http" or parts.netloc.lower() not in allowed:
        raise RefusedError(403, f"cross-origin request from {origin!r} refused")


# --- actions -----------------------------------------------------------------------------

def _number(lo: float, hi: float) -> Any:
    def check(name: str, value: Any) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise RefusedError(400, f"{name} must be a number, got {type(value).__name__}")
        if not (math.isfinite(value) and lo <= value <= hi):
            raise RefusedError(400, f"{name} must be within [{lo:g}, {hi:g}], got {value!r}")
        return float(value)
    return check


def _integer(lo: int, hi: int) -> Any:
    def check(name: str, value: Any) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise RefusedError(400, f"{name} must be an integer, got {type(value).__name__}")
        if not lo <= value <= hi:
            raise RefusedError(400, f"{name} must be within [{lo}, {hi}], got {value}")
        return value
    return check


def _choice(*options: str) -> Any:
    def check(name: str, value: Any) -> str:
        if value not in options:
            raise RefusedError(400, f"{name} must be one of {', '.join(options)}")
        return value
    return check


def _plan_id(name: str, value: Any) -> str:
    if not (isinstance(value, str) and len(value) == 32 and value.isalnum()):
        raise RefusedError(400, f"{name} must be the id of an uploaded plan")
    return value


#: Every action: (its arguments: name -> (check, required), moves the rig).
ACTIONS: dict[str, tuple[dict[str, tuple[Any, bool]], bool]] = {
    "stop": ({}, False),
    "estop": ({}, False),
    "clear": ({}, False),
    "home": ({}, True),
    "jog": ({"to": (_number(-1.0, 1.0), False), "by": (_number(-0.1, 0.1), False),
             "speed": (_number(1e-4, 0.05), False)}, True),
    "run": ({"job": (_choice("default", "speed", "plan"), True),
             "cycles": (_integer(1, MAX_CYCLES), True), "speed": (_number(1e-3, 0.4), False),
             "plan": (_plan_id, False)}, True),
    "check": ({}, True),
    "tare": ({"samples": (_integer(10, 100_000), False)}, False),
    "span": ({"known_force": (_number(-5000.0, 5000.0), True),
              "samples": (_integer(10, 100_000), False)}, False),
    "store": ({"offset": (_number(-1e9, 1e9), True), "gain": (_number(-1e6, 1e6), True)},
              False),
}


@dataclass(frozen=True)
class Action:
    name: str
    args: dict[str, Any]
    client: str
    seq: int
    moves: bool


def parse_action(body: Any) -> Action:
    """A validated action from a request's JSON body, or :class:`RefusedError` (400)."""
    if not isinstance(body, dict):
        raise RefusedError(400, "an action is a JSON object")
    unknown = set(body) - {"action", "args", "client", "seq", "confirm", "t_click"}
    if unknown:
        raise RefusedError(400, f"unknown field {sorted(unknown)[0]!r}")
    name = body.get("action")
    if not isinstance(name, str) or name not in ACTIONS:
        raise RefusedError(400, f"unknown action {str(name)[:40]!r}")
    schema, moves = ACTIONS[name]
    raw = body.get("args", {})
    if not isinstance(raw, dict):
        raise RefusedError(400, "args must be a JSON object")
    extra = set(raw) - set(schema)
    if extra:
        raise RefusedError(400, f"{name} takes no argument {sorted(extra)[0]!r}")
    args = {}
    for key, (check, required) in schema.items():
        if key in raw and raw[key] is not None:
            args[key] = check(key, raw[key])
        elif required:
            raise RefusedError(400, f"{name} needs {key}")
    if name == "jog" and ("to" in args) == ("by" in args):
        raise RefusedError(400, "jog takes one of to (m) or by (m)")
    if name == "run" and args["job"] == "speed" and "speed" not in args:
        raise RefusedError(400, "a constant-speed job needs speed (m/s)")
    if name == "run" and args["job"] == "plan" and "plan" not in args:
        raise RefusedError(400, "a plan job needs the id of an uploaded plan")
    client, seq = body.get("client"), body.get("seq")
    if not isinstance(client, str) or not 8 <= len(client) <= 64:
        raise RefusedError(400, "client must be the id the panel's websocket gave")
    if isinstance(seq, bool) or not isinstance(seq, int) or not 0 < seq < 2**53:
        raise RefusedError(400, "seq must be a positive integer, one more per action")
    if moves and body.get("confirm") is not True:
        raise RefusedError(400, f"{name} moves the rig: confirm it (confirm: true)")
    return Action(name, args, client, seq, moves)


@dataclass
class Clients:
    """The connected pages and the command lease: one page commands, the others watch.

    A page's client id is a secret it gets on its websocket; each action carries the next
    sequence number of its client, so a replayed or reordered request is refused. STOP and
    ESTOP are taken from any page, as a stop button on the rig's frame is anyone's.
    """

    seqs: dict[str, int] = field(default_factory=dict)
    holder: str | None = None

    def join(self) -> str:
        client = secrets.token_hex(16)
        self.seqs[client] = 0
        return client

    def leave(self, client: str) -> None:
        self.seqs.pop(client, None)
        if self.holder == client:
            self.holder = None

    def take_lease(self, client: str) -> None:
        self._known(client)
        if self.holder not in (None, client):
            raise RefusedError(409, "another page has the command; it must release it first")
        self.holder = client

    def release(self, client: str) -> None:
        self._known(client)
        if self.holder == client:
            self.holder = None

    def _known(self, client: str) -> None:
        if client not in self.seqs:
            raise RefusedError(403, "unknown client: reload the page")

    def admit(self, action: Action) -> None:
        """Sequence (replay) and lease checks of a parsed action."""
        self._known(action.client)
        if action.seq <= self.seqs[action.client]:
            raise RefusedError(409, f"replayed action: seq {action.seq} was used "
                               f"(last {self.seqs[action.client]})")
        self.seqs[action.client] = action.seq
        if action.name not in ("stop", "estop") and self.holder != action.client:
            raise RefusedError(403, "this page only watches: take the command first")
