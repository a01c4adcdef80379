"""Test helpers of the panel: ``hil panel`` as a child process, headless Chromium driven by
Selenium, and the emulated rigs' own record of what they sent (tests/test_panel_*.py,
benchmarks/bench_panel.py)."""

from __future__ import annotations

import csv
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from hil.link import protocol as p

CHROMIUM, CHROMEDRIVER = "/usr/bin/chromium", "/usr/bin/chromedriver"
MOTION_COMMANDS = (p.MsgType.TRAJ_CHUNK, p.MsgType.START, p.MsgType.SET_POSITION)


def browser_missing() -> str | None:
    """Why the browser tests cannot run here (None when they can)."""
    try:
        import selenium  # noqa: F401
    except ImportError:
        return "selenium is not installed (pip install -e '.[test]')"
    for path in (CHROMIUM, CHROMEDRIVER):
        if not os.access(path, os.X_OK):
            return f"{path} is missing (apt-get install chromium chromium-driver)"
    return None


def chromium(width: int = 1400, height: int = 1250, *extra: str) -> Any:
    """Headless Chromium (Debian's) with a throw-away profile and ``extra`` flags; quit it
    with :func:`quit_browser`."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    profile = tempfile.mkdtemp(prefix="panel_chromium_")
    for flag in ("--headless", "--no-sandbox", "--disable-gpu",
                 "--disable-background-networking", "--disable-component-update",
                 "--disable-sync", "--no-first-run", f"--user-data-dir={profile}",
                 f"--window-size={width},{height}", *extra):
        options.add_argument(flag)
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)
    driver.profile_dir = profile
    return driver


def quit_browser(driver: Any) -> None:
    driver.quit()
    shutil.rmtree(driver.profile_dir, ignore_errors=True)


class PanelProcess:
    """``hil panel ARGS --http-port 0`` in a child process; its URL, token and port."""

    def __init__(self, runs: Path, *args: str, timeout: float = 60.0) -> None:
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "hil.cli", "panel", "--http-port", "0", "--runs", str(runs),
             *args], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self.stderr: list[str] = []
        threading.Thread(target=lambda: self.stderr.extend(self.proc.stderr), daemon=True).start()
        line = self.proc.stdout.readline()
        if not line.startswith("hil panel: http://"):
            self.proc.kill()
            raise AssertionError(f"no URL from hil panel: {line!r} {self.stderr}")
        self.url = line.split(": ", 1)[1].strip()
        parts = urlsplit(self.url)
        self.port, self.token = parts.port, parts.query.split("token=", 1)[1]
        self.base = f"http://127.0.0.1:{self.port}"
        self.others = threading.Thread(target=self.proc.stdout.read, daemon=True)
        self.others.start()

    def close(self, timeout: float = 40.0) -> int:
        """SIGTERM, as a user's Ctrl-C; the exit code."""
        if self.proc.poll() is None:
            self.proc.terminate()
        try:
            return self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            return self.proc.wait()


def wait_until(condition: Any, timeout: float, what: str, every: float = 0.1) -> Any:
    """``condition()`` once truthy (its value), else AssertionError naming ``what``."""
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            what = what() if callable(what) else what
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(every)


def recorded(run_dir: Path) -> list[tuple[int, str]]:
    """(MCU sample, status) of every row of a run's samples.csv."""
    with (run_dir / "samples.csv").open(newline="") as fh:
        return [(int(r["sample"]), r["status"]) for r in csv.DictReader(fh)]


class Tap:
    """What a rig wrote on its pty, decoded: (sample, state) of every telemetry frame, and
    the host's commands it read are counted by the emulator's own log."""

    def __init__(self) -> None:
        self.decoder = p.FrameDecoder()
        self.telemetry: list[tuple[int, int]] = []

    def feed(self, data: bytes) -> bytes:
        for frame in self.decoder.feed(bytes(data)):
            try:
                msg = p.parse_message(frame)
            except Exception:  # noqa: BLE001 - a damaged frame is not telemetry
                continue
            if isinstance(msg, p.Telemetry):
                self.telemetry.append((msg.sample, msg.state))
        return data


def sent_until_standstill(sent: list[tuple[int, int]], first: int) -> list[int]:
    """The samples a rig sent from ``first`` up to its first one at standstill."""
    out = []
    for sample, state in sent:
        if sample < first:
            continue
        out.append(sample)
        if state not in (p.State.RUNNING, p.State.STOPPING):
            break
    return out
