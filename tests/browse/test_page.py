"""End to end: the page in a real headless Chromium (the system's, driven by Playwright) lists the
tasks, opens a dataset, clicks into an episode, shows its camera frames and plots, and the scrubber
moves frames and plot cursor together.  Everything it loads comes from the local server.

Skipped where Chromium is not installed, except in CI (``CI=true``), where `.ci/run` installs it.
Set ``D5RL_SCREENSHOTS=DIR`` to save screenshots of the views (the README's come from
``scripts/browse_screenshots.py``).
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import socket
import threading
import time
from pathlib import Path

import pytest

IN_CI = os.environ.get("CI", "").lower() == "true"
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]

if not IN_CI:
    pytest.importorskip("playwright.sync_api")
    pytest.importorskip("uvicorn")
    if CHROMIUM is None:
        pytest.skip(
            "Chromium is not installed (apt-get install chromium); CI installs it and runs this test",
            allow_module_level=True,
        )
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
        str(tmp_path / "chromium-profile"),
        executable_path=CHROMIUM,
        headless=True,
        args=CHROMIUM_ARGS,
        viewport={"width": 1200, "height": 900},
    )


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


RUNS_SECTION = 'section.task-runs[data-task="a1-walk-v0"]'  # what docs/img/browse-runs.png shows


@contextlib.contextmanager
def runs_page(tmp_path, run_dirs):
    """The Runs view over ``run_dirs`` in headless Chromium; fails the test if the page raised an error."""
    from playwright.sync_api import sync_playwright

    errors = []
    with Server(run_dirs) as server, sync_playwright() as p:
        ctx = browser(p, tmp_path)
        try:
            page = ctx.new_page()
            page.set_default_timeout(20_000)
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(server.url + "/#/runs")
            yield page
        finally:
            ctx.close()
    assert not errors, errors


def _grid(root: Path, cells) -> Path:
    """A grid of a1-walk-v0 cells: ``cells`` is ``[(algo, seed, [score of each evaluation])]``, evaluated
    every 50 of 100 steps from the end back."""
    from d5rl.runner.grid import Cell
    from d5rl.training.rundir import RunDir

    for algo, seed, scores in cells:
        cell = Cell("a1-walk-v0", algo, seed, 100, 0)
        d = cell.directory(root)
        RunDir(d).write_cell(cell.to_json())
        steps = range(100 - 50 * (len(scores) - 1), 101, 50)
        (d / "metrics.jsonl").write_text(
            "".join(json.dumps({"step": st, "eval/a1-walk-v0/score": sc}) + "\n" for st, sc in zip(steps, scores))
        )
        (d / "done").write_text("{}")
    return root


def test_runs_view_compares_agents_with_the_paper_as_the_reports_do(tmp_path):
    """Two grids whose folders are both ``cells``: one table per task with every agent of both, named apart,
    each entry as the grid's report.md writes it next to the paper's, sortable, the best mean highlighted;
    learning curves for the agent evaluated twice, final scores per seed for the others."""
    from d5rl.runner.report import write_report
    from d5rl.runner.results import seed_interval
    from tests.mdtables import report_entries

    grids = {
        "g1/cells": _grid(
            tmp_path / "g1/cells", [("bc", 0, [0.5]), ("bc", 1, [0.7]), ("iql", 0, [0.2, 0.8]), ("iql", 1, [0.4, 0.9])]
        ),
        "g2/cells": _grid(tmp_path / "g2/cells", [("bc", 0, [0.1]), ("bc", 1, [0.2]), ("bc", 2, [0.3])]),
    }
    reports = {k: report_entries(write_report(g, plots=False).read_text()) for k, g in grids.items()}
    with runs_page(tmp_path, list(grids.values())) as page:
        section = page.locator(RUNS_SECTION)
        section.locator(".dots .main-svg").first.wait_for()
        table = section.locator('table.compare[data-phase="offline"]')
        head = table.locator("th").all_inner_texts()
        assert [h.rstrip(" ▲▼") for h in head] == [
            "agent",
            "steps",
            "seeds",
            "mean ± std",
            "95% CI of the mean",
            "paper (a1-walk-v0)",
        ]
        rows = [r.locator("td").all_inner_texts() for r in table.locator("tr[data-algo]").all()]
        assert [r[0] for r in rows] == ["g1/cells: IQL", "g1/cells: BC", "g2/cells: BC"]  # best mean first
        for label, _, _, ours, _, paper in rows:
            grid, method = label.split(": ")
            assert f"{ours} / {paper}" == reports[grid][("a1-walk-v0", method)]  # as report.md writes it
            assert paper == {"IQL": "0.962 ± 0.007", "BC": "1.006 ± 0.015"}[method]
        assert rows[1][2:5] == ["2", "0.600 ± 0.100", "[0.500, 0.700]"]
        assert seed_interval([0.5, 0.7]) == (0.5, 0.7)  # every resample's mean is 0.5, 0.6 or 0.7
        assert table.locator("tr.best").all_inner_texts() == [table.locator("tr[data-algo]").first.inner_text()]
        assert "g1/cells: IQL" in table.locator("tr.best").inner_text()

        table.locator('th[data-col="mean ± std"]').click()  # ascending
        assert [r.split("\t")[0] for r in table.locator("tr[data-algo]").all_inner_texts()] == [
            "g2/cells: BC",
            "g1/cells: BC",
            "g1/cells: IQL",
        ]
        table.locator('th[data-col="agent"]').click()
        assert [r.split("\t")[0] for r in table.locator("tr[data-algo]").all_inner_texts()] == [
            "g1/cells: BC",
            "g1/cells: IQL",
            "g2/cells: BC",
        ]

        curves = section.locator(".plot.curve")
        assert curves.evaluate("d => d.data.filter(t => t.name).map(t => [t.name, t.x])") == [
            ["g1/cells: IQL (2 seeds)", [50, 100]]
        ]
        dots = section.locator(".plot.dots")
        assert dots.evaluate("d => d.data.map(t => [t.name, t.y, t.x])") == [
            ["g1/cells: BC", ["g1/cells: BC"] * 2, [0.5, 0.7]],
            ["g2/cells: BC", ["g2/cells: BC"] * 3, [0.1, 0.2, 0.3]],
            ["paper's mean", ["g1/cells: BC", "g2/cells: BC"], [1.006, 1.006]],
        ]
        # Plotly's tool bar shows at the top right on hover: it must not cover a plot's title
        for plot in (curves, dots):
            plot.hover()
            bar = plot.locator(".modebar").bounding_box()
            title = plot.locator("xpath=preceding-sibling::div[contains(@class, 'plot-title')]").bounding_box()
            assert bar and title and bar["y"] >= title["y"] + title["height"]
        shot(page, "runs")


def test_runs_view_shows_what_the_agents_do(tmp_path):
    from tests.browse.test_server import _run_dir

    with runs_page(tmp_path, [_run_dir(tmp_path / "run")]) as page:
        page.wait_for_selector("text=What the agents do")
        table = page.locator("table.scores").last.inner_text()
        assert "reached" in table and "0.500" in table  # the mean of the two seeds' 0.25 and 0.75
