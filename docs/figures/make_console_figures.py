"""Screenshots of the console (docs/figures/console_*.png) in Debian's headless Chromium.

Run: ``.venv/bin/python docs/figures/make_console_figures.py`` (about a minute; needs
``make browser``). The real controller on the digital twin (catheter seed 0, which tuned the
twin: a picture, not a result), with the anatomy, its labels and the twin's cardiac phase
for the ECG strip:

- ``console_1920.png`` / ``console_1400.png``: a full-HD and a 1400 x 900 window, the view
  "home" saved and the knobs jogged away from it;
- ``console_views.png``: the control panel scrolled to the end of the view list (the
  safety bar stays on top);
- ``console_estop.png``: after E-STOP during a go-to-view: the banner, every motion
  control disabled.
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import numpy as np

from icenav.apps.wiring import anatomy_labels, anatomy_meshes, make_sim_controller
from icenav.console import Console, ConsoleConfig
from icenav.control.controller import ControllerConfig
from icenav.control.state import Mode

HERE = Path(__file__).parent
SCROLL_JS = """to_end => {  // the control panel's own scroll area: the outermost that scrolls
  const estop = [...document.querySelectorAll('button')]
    .find(b => b.textContent.trim() === 'E-STOP');
  let vp = null;
  for (let n = estop.parentElement; n; n = n.parentElement) {
    if (n.hasAttribute && n.hasAttribute('data-scrollarea-viewport')
        && n.scrollHeight > n.clientHeight + 5) vp = n;
  }
  if (vp !== null) vp.scrollTo(0, to_end ? vp.scrollHeight : 0);
}"""
CHROMIUM = "/usr/bin/chromium"
ARGS = ["--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--no-first-run"]


def _wait(pred, what: str, timeout_s: float = 60.0) -> None:  # type: ignore[no-untyped-def]
    end = time.monotonic() + timeout_s
    while not pred():
        if time.monotonic() > end:
            raise TimeoutError(what)
        time.sleep(0.05)  # a script polling the controller, not a test


def _drive_away(ctl) -> None:  # type: ignore[no-untyped-def]
    """Save "home" and "septum", then jog the AP knob 25 deg away (as a script)."""
    _wait(lambda: ctl.latest_image() is not None, "first image")
    ctl.save_view("home")
    while ctl.snapshot().q_motor[2] < math.radians(35):
        ctl.jog(np.array([0.0, 0.0, 0.8, 0.0]), "knob")
        time.sleep(0.05)
    ctl.save_view("septum")
    while ctl.snapshot().q_motor[0] < math.radians(20):
        ctl.jog(np.array([0.5, 0.0, -0.3, 0.0]), "knob")
        time.sleep(0.05)
    ctl.stop()
    _wait(lambda: ctl.snapshot().mode is Mode.IDLE, "idle")
    ctl.release_control("script")


def main() -> int:
    try:
        from playwright.sync_api import expect, sync_playwright
    except ImportError:
        print("console figures skipped: no playwright package (scripts/install-browser.sh)")
        return 0
    if not Path(CHROMIUM).exists():
        print(f"console figures skipped: no {CHROMIUM} (scripts/install-browser.sh)")
        return 0

    session = make_sim_controller(seed=0, config=ControllerConfig(image_rate_hz=10.0))
    ctl = session.controller
    ctl.start()
    phase = session.renderer.phantom.cardiac_phase
    try:
        _drive_away(ctl)
        with (
            Console(
                ctl,
                port=0,
                anatomy_mesh=anatomy_meshes(),
                anatomy_labels=anatomy_labels(),
                cardiac_phase=phase,
                refresh_hz=10.0,
                # a loaded machine stalls the loop past 0.5 s: no stale banner in the pictures
                config=ConsoleConfig(stale_after_s=5.0),
            ) as console,
            sync_playwright() as p,
        ):
            browser = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=ARGS)
            for w, h in ((1920, 1080), (1400, 900)):
                page = browser.new_page(viewport={"width": w, "height": h})
                page.goto(console.url)
                expect(page.get_by_text("You have control")).to_be_visible(timeout=60_000)
                page.wait_for_timeout(4000)  # the scene's first frames on software WebGL
                for close in page.locator("button.mantine-Notification-closeButton").all():
                    close.click()
                page.screenshot(path=str(HERE / f"console_{w}.png"))
                if w == 1400:
                    page.evaluate(SCROLL_JS, 1)
                    page.wait_for_timeout(800)
                    page.screenshot(path=str(HERE / "console_views.png"))
                    page.evaluate(SCROLL_JS, 0)
                    page.get_by_role("button", name="Go to home", exact=True).click()
                    _wait(lambda: ctl.snapshot().mode is Mode.GOTO_VIEW, "go to view")
                    page.wait_for_timeout(600)
                    page.keyboard.press("Escape")
                    _wait(lambda: ctl.snapshot().mode is Mode.ESTOP, "e-stop")
                    expect(page.get_by_text("Cause:", exact=False)).to_be_visible()
                    page.wait_for_timeout(1500)
                    page.screenshot(path=str(HERE / "console_estop.png"))
                page.close()
            browser.close()
    finally:
        session.close()
    for name in ("console_1920", "console_1400", "console_views", "console_estop"):
        print(HERE / f"{name}.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
