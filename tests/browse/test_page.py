"""End to end: the page in a real headless Chromium (the system's, driven by Playwright) lists the
tasks, opens a dataset, clicks into an episode, shows its camera frames and plots, and the scrubber
moves frames and plot cursor together.  Everything it loads comes from the local server.

Skipped where Chromium is not installed, except in CI (``CI=true``), where `.ci/run` installs it.
Set ``D5RL_SCREENSHOTS=DIR`` to save screenshots of the views (the README's come from
``scripts/browse_screenshots.py``).
"""

from __future__ import annotations

import os
import shutil
import socket
import threading
import time
from pathlib import Path

import pytest

IN_CI = os.environ.get("CI", "").lower() == "true"
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]

if not IN_CI:
    pytest.importorskip("playwright.sync_api")
    pytest.importorskip("uvicorn")
    if CHROMIUM is None:
        pytest.skip("Chromium is not installed (apt-get install chromium); CI installs it and runs this test",
                    allow_module_level=True)
elif CHROMIUM is None:
    raise RuntimeError("CI=true but no chromium on PATH: .ci/run must `apt-get install chromium`")


class Server:
    """``d5rl browse``'s app under uvicorn on a free loopback port, in a thread."""

    def __init__(self, run_dirs=()):
        import uvicorn

        from d5rl.browse.server import create_app

        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.url = f"http://127.0.0.1:{self.sock.getsockname()[1]}"
        self.server = uvicorn.Server(uvicorn.Config(create_app([Path(r) for r in run_dirs]), log_level="warning"))
        self.thread = threading.Thread(target=self.server.run, kwargs={"sockets": [self.sock]}, daemon=True)

    def __enter__(self):
        self.thread.start()
        deadline = time.monotonic() + 30
        while not self.server.started:
            assert time.monotonic() < deadline and self.thread.is_alive(), "server did not start"
            time.sleep(0.05)
        return self

    def __exit__(self, *exc):
        self.server.should_exit = True
        self.thread.join(10)
        self.sock.close()


def browser(playwright, tmp_path):
    return playwright.chromium.launch_persistent_context(
        str(tmp_path / "chromium-profile"), executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS,
        viewport={"width": 1200, "height": 900})


def shot(page, name):
    out = os.environ.get("D5RL_SCREENSHOTS")
    if out:
        Path(out).mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(Path(out) / f"{name}.png"))


def test_click_into_an_episode_and_scrub(tmp_path):
    from playwright.sync_api import sync_playwright

    from d5rl.datasets.generation import generate

    generate("toy-reach-pixels-v0", num_episodes=20, workers=1, progress=False)
    requests, errors = [], []
    with Server() as server, sync_playwright() as p:
        ctx = browser(p, tmp_path)
        try:
            page = ctx.new_page()
            page.set_default_timeout(20_000)
            page.on("request", lambda r: requests.append(r.url))
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(server.url + "/#/")
            page.click('tr[data-task="toy-reach-pixels-v0"]')
            page.wait_for_function("document.querySelectorAll('#overview .main-svg').length >= 3")
            assert page.locator("#episodes tr[data-episode]").count() == 20
            shot(page, "dataset")
            page.click('tr[data-episode="3"]')
            page.wait_for_selector('.frame[data-loaded="1"][data-camera="front"]')
            page.wait_for_selector('.frame[data-loaded="1"][data-camera="side"]')
            page.wait_for_function("document.querySelectorAll('.plot-panel .main-svg').length >= 2")
            assert "episode 3 of 20" in page.inner_text("h1")
            front = page.locator('.frame[data-camera="front"]')
            assert "url(" in front.evaluate("e => e.style.backgroundImage")
            # frames are 16x16, shown 15x larger, 26 in one row of the strip: frame k is at -k*240 px
            assert front.evaluate("e => e.style.backgroundPosition") == "0px 0px"
            page.fill("#scrubber", "5")
            page.dispatch_event("#scrubber", "input")
            page.wait_for_function("document.body.dataset.frame === '5'")
            assert front.evaluate("e => e.style.backgroundPosition") == "-1200px 0px"
            assert page.inner_text("#frame-label").startswith("frame 5 / 25")
            cursor = page.evaluate("[...document.querySelectorAll('.plot-panel')].map(d => d.layout.shapes[0].x0)")
            assert cursor and all(x == 5 for x in cursor)
            rewards = page.evaluate("document.querySelector('.plot-panel').data[0].y.length")
            assert rewards == 25
            shot(page, "episode")
        finally:
            ctx.close()
    assert not errors, errors
    assert requests and all(u.startswith(server.url) or u.startswith("data:") for u in requests), requests


def test_runs_view_shows_what_the_agents_do(tmp_path):
    from playwright.sync_api import sync_playwright

    from tests.browse.test_server import _run_dir

    errors = []
    with Server([_run_dir(tmp_path / "run")]) as server, sync_playwright() as p:
        ctx = browser(p, tmp_path)
        try:
            page = ctx.new_page()
            page.set_default_timeout(20_000)
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(server.url + "/#/runs")
            page.wait_for_selector("text=What the agents do")
            table = page.locator("table.scores").last.inner_text()
            assert "reached" in table and "0.500" in table  # the mean of the two seeds' 0.25 and 0.75
            shot(page, "runs")
        finally:
            ctx.close()
    assert not errors, errors
