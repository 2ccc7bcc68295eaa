"""The monitor page in a real browser (Debian's headless Chromium via Playwright) during a live sim run
(the product's default: the actor's plans): retreat events arrive, plans show planned against executed,
E-STOP holds the arm without a token, the token typed once survives a reload and never shows in the URL,
release lets learning resume. Saves a screenshot."""

import json
import os
import re
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest
from polling import wait_until
from stack_helpers import write_stack_config

CHROMIUM = "/usr/bin/chromium"
ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]

pytestmark = pytest.mark.skipif(
    not Path(CHROMIUM).exists(),
    reason="needs Debian's chromium at /usr/bin/chromium (apt-get install chromium)",
)


def _state(url: str) -> dict:
    with urllib.request.urlopen(url + "api/state", timeout=5) as r:
        return json.loads(r.read())


def test_monitor_in_chromium(tmp_path):
    from playwright.sync_api import sync_playwright

    path, cfg = write_stack_config(tmp_path, "mon", vision_rate_hz=5.0, steps=100000)
    up = subprocess.Popen(
        [sys.executable, "-m", "deploy.cli", "up", str(path)], stdout=subprocess.PIPE, text=True
    )
    try:
        url, token = None, None
        for line in up.stdout:
            if line.startswith("operator token: "):
                token = line.strip().removeprefix("operator token: ")
                continue
            assert "token" not in line and (token is None or token not in line), line  # only its own line
            m = re.match(r"monitor: (http://\S+/)$", line.strip())
            if m:
                url = m.group(1)
                break
        assert url and token, "the stack printed no monitor URL"
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, args=ARGS)
            page = browser.new_page(viewport={"width": 1400, "height": 900})
            page.goto(url)
            wait_until(
                lambda: int(page.inner_text("#retreats")) > 0, 90, "retreat events on the page", every=0.2
            )
            wait_until(lambda: "executed" in page.inner_text("#plans"), 30, "plans on the page", every=0.2)
            plans = _state(url)["plans"]
            assert plans and all(len(p["planned"]) == p["n"] + 1 for p in plans)  # the path travels along
            assert page.input_value("#token") == ""
            page.click("#estop")  # no token typed yet: an e-stop needs none
            wait_until(
                lambda: page.inner_text("#mode").lower() == "estop", 10, "the page showing estop", every=0.2
            )
            ee0 = _state(url)["robot"]["ee"]
            step0 = _state(url)["robot"]["chunk_seq"]
            time.sleep(2.0)
            s = _state(url)
            assert s["robot"]["mode"] == "estop"
            assert max(abs(a - b) for a, b in zip(s["robot"]["ee"], ee0, strict=True)) < 0.005  # held
            assert s["robot"]["chunk_seq"] == step0  # no chunk accepted while e-stopped
            assert s["robot"]["joint_speed"] < 0.02, s["robot"]  # rad/s: the arm is still
            assert "rad/s" in page.inner_text("#jspeed")
            page.fill("#token", token)  # once: the tab keeps it (sessionStorage), never the URL
            assert "token" not in page.url and token not in page.url
            page.reload()
            assert page.input_value("#token") == token and token not in page.url
            assert page.evaluate("sessionStorage.getItem('adaptiveh-token')") == token
            assert page.evaluate("JSON.stringify(localStorage)") == "{}"  # not kept beyond the tab
            page.click("#release")
            wait_until(lambda: page.inner_text("#mode").lower() == "running", 10, "release", every=0.2)
            seg = int(page.inner_text("#segments"))
            wait_until(lambda: int(page.inner_text("#segments")) > seg, 30, "learning to resume", every=0.2)
            wait_until(
                lambda: "ep " in page.inner_text("#learner"), 30, "learner telemetry on the page", every=0.2
            )
            assert page.inner_text("#policy-from") == "an empty policy (no handoff)"  # what it began with
            # The success rate over the last 20 finished episodes, and how many episodes there were.
            wait_until(lambda: "episodes)" in page.inner_text("#success"), 30, "a success rate", every=0.2)
            shown = page.inner_text("#success")
            sr = _state(url)["success"]
            assert re.fullmatch(r"\d+ % of \d+ \(\d+ episodes\)", shown) and 1 <= sr["of"] <= 20, shown
            # Tests write only to temporary folders; the README's picture is refreshed on request, with
            # ADAPTIVEH_MONITOR_SCREENSHOT=results/monitor_screenshot.png (this file's test alone).
            shot = Path(os.environ.get("ADAPTIVEH_MONITOR_SCREENSHOT", str(tmp_path / "monitor_full.png")))
            page.screenshot(path=str(shot), full_page=True)
            page.screenshot(path=str(tmp_path / "monitor.png"))
            # A control with a wrong token is refused; the E-STOP still stops.
            page.fill("#token", "wrong")
            page.click("#pause")
            wait_until(lambda: "refused" in page.inner_text("#reply"), 5, "a refusal", every=0.2)
            page.click("#estop")
            wait_until(
                lambda: page.inner_text("#mode").lower() == "estop", 10, "estop with a wrong token", every=0.2
            )
            # An old bookmark's ?token= is moved into the tab's sessionStorage and off the address bar.
            old = browser.new_page()
            old.goto(f"{url}?token={token}&view=1")
            wait_until(lambda: "token" not in old.url, 5, "the token stripped from the URL", every=0.2)
            assert old.url.endswith("?view=1") and old.input_value("#token") == token
            assert old.evaluate("sessionStorage.getItem('adaptiveh-token')") == token
            browser.close()
    finally:
        up.terminate()
        up.wait(timeout=60)
    for log in (tmp_path / "logs").iterdir():  # the page sent the token: no part wrote it down
        assert log.stat().st_mode & 0o777 == 0o600 and token not in log.read_text(errors="replace"), log
