"""The screenshots of docs/panel.md: the page during a run, and two runs overlaid.

``hil panel --real`` on the model MCU's emulator, driven by headless Chromium: a
constant-speed job at 25 mm/s (a Tables 3-8 speed) shot mid-run, then a second at 15 mm/s;
both opened from the past runs and overlaid. Run: python docs/panel_screenshots.py
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.hil_host import spawn  # noqa: E402
from tests.panel_support import PanelProcess, chromium, quit_browser, wait_until  # noqa: E402

OUT = ROOT / "docs" / "panel"


def main() -> None:
    emulator = spawn()
    panel = PanelProcess(Path(tempfile.mkdtemp(prefix="panel_shots_")), "--real", "--port",
                         emulator.port)
    driver = chromium(1400, 1180)
    page = lambda script: driver.execute_script(f"return {script}")  # noqa: E731
    try:
        driver.get(panel.url)
        wait_until(lambda: page("panel.mine") and page(
            "document.getElementById('state').textContent") == "IDLE", 120,
            lambda: f"the page: {page('document.body.innerText.slice(0, 300)')}")
        for speed, cycles, shot in ((25, 3, "run.png"), (15, 2, None)):
            driver.execute_script(
                f"document.getElementById('job').value = 'speed';"
                f"document.getElementById('speed').value = '{speed}';"
                f"document.getElementById('cycles').value = '{cycles}';")
            driver.find_element("id", "btn-run").click()
            driver.switch_to.alert.accept()
            if shot:
                wait_until(lambda: page("panel.drawn") > 7000, 120, "a cycle and a half")
                driver.save_screenshot(str(OUT / shot))
            wait_until(lambda: "complete" in page(
                "document.getElementById('message').textContent"), 300, "the run's end")
            time.sleep(1.0)
        driver.find_element("id", "btn-refresh").click()
        time.sleep(1.0)
        boxes = driver.find_elements("css selector", "#runs input")[:2]
        for box in boxes:
            box.click()
        driver.find_element("id", "btn-open").click()
        wait_until(lambda: page("document.getElementById('stats').rows.length") > 5, 30,
                   "the statistics")
        driver.execute_script("document.querySelector('.past').scrollIntoView()")
        time.sleep(1.0)
        driver.save_screenshot(str(OUT / "overlay.png"))
    finally:
        quit_browser(driver)
        panel.close()
        emulator.close()
    print(f"wrote {OUT / 'run.png'} and {OUT / 'overlay.png'}")


if __name__ == "__main__":
    main()
