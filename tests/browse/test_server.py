"""The browse server's endpoints on generated toy datasets: values equal what the dataset API gives,
frames come from the right source and are cached, and no request reads outside the allowed roots."""

from __future__ import annotations

import io
import json
import os
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("starlette")
pytest.importorskip("httpx")
from PIL import Image
from starlette.testclient import TestClient

from d5rl import paths
from d5rl.browse.server import create_app
from d5rl.datasets.generation import generate
from d5rl.datasets.loading import load_dataset
from d5rl.registry import get_spec, normalize_score
from d5rl.runner.grid import Cell
from d5rl.training.rundir import RunDir
from tests.browse import toy


def client(runs=()):
    return TestClient(create_app([Path(r) for r in runs]), base_url="http://localhost:8765")


def tiles(png: bytes, layout: dict) -> np.ndarray:
    """The frames of a strip, back as (n, h, w, 3)."""
    img = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))
    h, w, cols = layout["height"], layout["width"], layout["cols"]
    return np.stack(
        [
            img[(k // cols) * h : (k // cols + 1) * h, (k % cols) * w : (k % cols + 1) * w]
            for k in range(layout["frames"])
        ]
    )


@pytest.fixture
def toy_data():
    generate("toy-reach-pixels-v0", num_episodes=50, workers=1, progress=False)
    generate("toy-reach-v0", num_episodes=50, workers=1, progress=False)


def test_task_list_reports_what_is_on_disk(toy_data):
    body = client().get("/api/tasks").json()
    tasks = {t["id"]: t for t in body["tasks"]}
    assert not any(t.startswith("test-") for t in tasks)
    t = tasks["toy-reach-v0"]
    assert t["status"] == "partial (50 ep)" and t["on_disk"]["episodes"] == 50
    assert t["on_disk"]["transitions"] == 50 * 25
    assert t["on_disk"]["bytes"] > 0 and t["score"]["expert"] == get_spec("toy-reach-v0").score.expert
    assert tasks["a1-walk-v0"]["status"] == "not generated" and tasks["a1-walk-v0"]["on_disk"] is None
    assert tasks["a1-walk-v0"]["datacard"] == "a1.md" and tasks["wx-sorting-v0"]["datacard"] == "widowx.md"


def test_episode_series_equal_the_dataset(toy_data):
    ds = load_dataset("toy-reach-v0", generate=False, progress=False)
    ep = ds.episode(7)
    body = client().get("/api/tasks/toy-reach-v0/episodes/7").json()
    assert body["length"] == 25 and body["episodes"] == 50
    np.testing.assert_allclose(body["return"], ep.arrays["rewards"].sum(), rtol=1e-6)
    np.testing.assert_allclose(body["score"], normalize_score("toy-reach-v0", ep.arrays["rewards"].sum()), rtol=1e-6)
    reward = body["panels"][0]["series"]
    np.testing.assert_allclose(reward[0]["y"], ep.arrays["rewards"], rtol=1e-4)
    np.testing.assert_allclose(reward[1]["y"], np.cumsum(ep.arrays["rewards"]), rtol=1e-4)
    actions = body["panels"][-1]["series"]
    np.testing.assert_allclose(np.array([s["y"] for s in actions]).T, ep.arrays["actions"], rtol=1e-4, atol=1e-6)


def test_episode_table_and_overview(toy_data):
    ds = load_dataset("toy-reach-v0", generate=False, progress=False)
    returns = np.add.reduceat(ds.rewards.astype(np.float64), ds.episode_starts)
    c = client()
    table = c.get("/api/tasks/toy-reach-v0/episodes").json()
    np.testing.assert_allclose(table["returns"], returns, rtol=1e-4)
    np.testing.assert_allclose(table["scores"], normalize_score("toy-reach-v0", returns), rtol=1e-4)
    plots = {p["title"]: p for p in c.get("/api/tasks/toy-reach-v0/overview").json()["plots"]}
    hist = plots["Episode return"]
    assert sum(hist["y"]) == 50
    lo = np.array(hist["x"]) - np.array(hist["width"]) / 2  # bin k counts returns in [lo_k, lo_k + width_k)
    np.testing.assert_array_equal(hist["y"], np.histogram(returns, bins=np.append(lo, returns.max()))[0])


def test_infos_become_flags_and_speed_plots():
    generate(toy.ENV_TASK, workers=1, progress=False)
    c = client()
    ep = c.get(f"/api/tasks/{toy.ENV_TASK}/episodes/1").json()  # 7 transitions
    flags = next(p for p in ep["panels"] if p["title"] == "completed")
    assert flags["kind"] == "flags" and [s["y"] for s in flags["series"]] == [[0, 0, 1, 1, 1, 1, 1], [0] * 6 + [1]]
    plots = {p["title"]: p for p in c.get(f"/api/tasks/{toy.ENV_TASK}/overview").json()["plots"]}
    assert plots["completed: columns true at some step, per episode"]["y"] == [0, 0, 6]
    assert sum(plots["forward_speed (every step)"]["y"]) == 6 + 7 + 8 + 6 + 7 + 8


def test_frames_stored_in_the_dataset_are_served_losslessly(toy_data):
    ds = load_dataset("toy-reach-pixels-v0", generate=False, progress=False)
    c = client()
    body = c.get("/api/tasks/toy-reach-pixels-v0/episodes/3/frames").json()
    assert body["source"] == "dataset" and [cam["name"] for cam in body["cameras"]] == ["front", "side"]
    for cam in body["cameras"]:
        r = c.get(f"/api/tasks/toy-reach-pixels-v0/episodes/3/frames/{cam['name']}")
        assert r.status_code == 200 and r.headers["content-type"] == "image/png"
        np.testing.assert_array_equal(tiles(r.content, cam), ds.episode(3).arrays[f"observations/pixels/{cam['name']}"])
    assert c.get("/api/tasks/toy-reach-v0/episodes/3/frames").status_code == 404  # no pixels, no states


def test_frames_rendered_from_states_once_then_cached():
    generate(toy.CAM_TASK, workers=1, progress=False)  # states only: no render cache yet
    toy.CALLS.clear()
    c = client()
    body = c.get(f"/api/tasks/{toy.CAM_TASK}/episodes/4/frames").json()
    assert body["source"] == "rendered" and toy.CALLS == [4]
    cam = body["cameras"][0]
    png = c.get(f"/api/tasks/{toy.CAM_TASK}/episodes/4/frames/cam").content
    states = load_dataset(toy.CAM_TASK, generate=False, progress=False, render=False).episode(4).arrays["states"]
    np.testing.assert_array_equal(tiles(png, cam), np.stack([toy.frame(s) for s in states]))
    assert client().get(f"/api/tasks/{toy.CAM_TASK}/episodes/4/frames").json() == body  # a new server: from disk
    assert toy.CALLS == [4]
    cached = list((paths.home() / "browse-cache").rglob("cam.png"))
    assert len(cached) == 1 and not list((paths.home() / "browse-cache").rglob(".*tmp*"))


def test_frames_read_from_the_render_cache_when_it_covers_the_episode():
    generate(toy.CAM_TASK, workers=1, progress=False)
    load_dataset(toy.CAM_TASK, episodes=3, progress=False, workers=1)  # renders the first shard (episodes 0-2)
    toy.CALLS.clear()
    c = client()
    assert c.get(f"/api/tasks/{toy.CAM_TASK}/episodes/1/frames").json()["source"] == "render cache"
    assert c.get(f"/api/tasks/{toy.CAM_TASK}/episodes/4/frames").json()["source"] == "rendered"
    assert toy.CALLS == [4]  # episode 1 came from the cache


def test_frames_replayed_in_the_env_without_a_family_renderer():
    generate(toy.ENV_TASK, workers=1, progress=False)
    c = client()
    body = c.get(f"/api/tasks/{toy.ENV_TASK}/episodes/2/frames").json()
    assert body["source"] == "rendered" and body["cameras"][0]["height"] == 12
    png = c.get(f"/api/tasks/{toy.ENV_TASK}/episodes/2/frames/view").content
    states = load_dataset(toy.ENV_TASK, generate=False, progress=False).episode(2).arrays["states"]
    np.testing.assert_array_equal(tiles(png, body["cameras"][0]), np.stack([toy.frame(s, 12) for s in states]))


def test_the_papers_repeated_entries_are_marked(tmp_path):
    """The paper prints TD3+BC's A1 run entry for RLPD too; the runs table says so beside it."""
    from d5rl.browse.runs import comparison_rows
    from d5rl.runner.results import collect

    for algo in ("td3bc", "bc"):
        cell = Cell("a1-run-v1", algo, 0, 100, 0)
        d = cell.directory(tmp_path)
        RunDir(d).write_cell(cell.to_json())
        (d / "metrics.jsonl").write_text(json.dumps({"step": 100, "eval/a1-run-v1/score": 0.5}) + "\n")
        (d / "done").write_text("{}")
    rows = {r["algo"]: r["paper_text"] for r in comparison_rows(collect(tmp_path), "offline")}
    assert rows == {"td3bc": "0.002 ± 0.021 († also RLPD's on this row)", "bc": "0.684 ± 0.026"}


def _run_dir(root: Path) -> Path:
    for seed, scores in ((0, [0.1, 0.5]), (1, [0.3, 0.7])):
        cell = Cell("toy-reach-v0", "bc", seed, 100, 0)
        d = cell.directory(root)
        RunDir(d).write_cell(cell.to_json())
        with open(d / "metrics.jsonl", "w") as f:
            for step, s in zip((50, 100), scores):
                f.write(json.dumps({"step": step, "eval/toy-reach-v0/score": s}) + "\n")
        (d / "done").write_text("{}")
        (d / "summary.json").write_text(json.dumps({"stats": {"reached": 0.25 + 0.5 * seed}}))
        (d / "videos").mkdir()
        (d / "videos" / "final.mp4").write_bytes(b"\x00\x00\x00\x18ftypmp42")
    return root


def test_runs_curves_tables_and_videos(tmp_path):
    run = _run_dir(tmp_path / "run")
    c = client([run])
    assert c.get("/api/tasks").json()["runs"] == [
        {"index": 0, "name": "run", "label": "run", "path": str(run.resolve())}
    ]
    body = c.get("/api/runs/0").json()
    (curve,) = body["curves"]
    assert curve["steps"] == [50, 100] and curve["seeds"] == 2
    np.testing.assert_allclose(curve["mean"], [0.2, 0.6]) and np.testing.assert_allclose(curve["std"], [0.1, 0.1])
    (row,) = body["tables"]["offline"]
    assert row["n"] == 2 and row["mean"] == pytest.approx(0.6) and row["std"] == pytest.approx(0.1)
    assert row["text"] == "0.600 ± 0.100" and row["scores"] == [0.5, 0.7] and row["seeds"] == [0, 1]
    assert row["ci"] == [0.5, 0.7] and row["ci_text"] == "[0.500, 0.700]"  # resampled means: 0.5, 0.6 or 0.7
    assert row["paper"] is None and row["paper_text"] == "-" and row["steps"] == "100"
    (what,) = body["behaviour"]  # the task's episode stats, mean over the two seeds
    assert what["task"] == "toy-reach-v0" and what["rows"][0]["cells"] == 2
    assert what["rows"][0]["stats"]["reached"] == pytest.approx(0.5)
    video = body["cells"][0]["videos"][0]
    assert video == "toy-reach-v0/bc/seed0/videos/final.mp4"
    r = c.get(f"/api/runs/0/files/{video}")
    assert r.status_code == 200 and r.headers["content-type"] == "video/mp4"
    assert c.get("/api/runs/1").status_code == 404


def test_requests_cannot_leave_the_allowed_directories(tmp_path, toy_data):
    run = _run_dir(tmp_path / "run")
    secret = tmp_path / "secret.mp4"
    secret.write_bytes(b"TOP-SECRET-BYTES")
    (run / "link.mp4").symlink_to(secret)
    (run / "toy-reach-v0" / "linkdir").symlink_to(tmp_path, target_is_directory=True)
    c = client([run])
    for path in [
        "../secret.mp4",
        "%2e%2e/secret.mp4",
        "..%2fsecret.mp4",
        "%2E%2E%2Fsecret.mp4",
        "toy-reach-v0/..%2F..%2Fsecret.mp4",
        "link.mp4",
        "toy-reach-v0/linkdir/secret.mp4",
        str(secret),
        "%2F" + str(secret).lstrip("/"),
        "/" + str(secret),
        "toy-reach-v0/bc/seed0/cell.json",
        "toy-reach-v0/bc/seed0/videos/final.mp4%00.json",
    ]:
        r = c.get(f"/api/runs/0/files/{path}")
        assert r.status_code in (403, 404) and b"TOP-SECRET" not in r.content, (path, r.status_code)
    for url in [
        "/api/tasks/..%2F..%2Fetc/episodes/0",
        "/api/tasks/%2e%2e/overview",
        "/api/tasks/toy-reach-pixels-v0/episodes/0/frames/..%2F..%2Fmanifest.json",
        "/api/tasks/toy-reach-pixels-v0/episodes/0/frames/%2e%2e%2f%2e%2e%2fframes.json",
        "/api/tasks/toy-reach-pixels-v0/episodes/-1",
        "/api/tasks/toy-reach-pixels-v0/episodes/99999999999",
        "/api/tasks/toy-reach-pixels-v0/episodes/50",
        "/api/datacards/..%2F..%2FREADME.md",
        "/api/datacards/%2e%2e%2fREADME.md",
        "/static/..%2F..%2Fcli.py",
        "/static/%2e%2e/server.py",
        "/api/runs/..%2F..%2F/files/x.mp4",
    ]:
        r = c.get(url)
        assert r.status_code in (400, 403, 404), (url, r.status_code)
        assert b"import " not in r.content and b"d5rl:" not in r.content
    c.get("/api/tasks/toy-reach-pixels-v0/episodes/0/frames")  # a real strip exists now
    r = c.get("/api/tasks/toy-reach-pixels-v0/episodes/0/frames/front")
    assert r.status_code == 200


def test_safe_paths_resolve_before_checking(tmp_path):
    from d5rl.browse.safe import NotAllowed, file_under, inside

    root = tmp_path / "root"
    (root / "a").mkdir(parents=True)
    (root / "a" / "v.mp4").write_bytes(b"x")
    (tmp_path / "out.mp4").write_bytes(b"x")
    assert file_under(root, "a/v.mp4", (".mp4",)) == (root / "a" / "v.mp4").resolve()
    assert inside(root / "a" / ".." / "a", [root]) == (root / "a").resolve()
    for bad in ["../out.mp4", "a/../../out.mp4", str(tmp_path / "out.mp4"), "a/v.mp4/..", "a", ""]:
        with pytest.raises(NotAllowed):
            file_under(root, bad, (".mp4",))
    os.symlink(tmp_path / "out.mp4", root / "a" / "l.mp4")
    with pytest.raises(NotAllowed):
        file_under(root, "a/l.mp4", (".mp4",))


@pytest.mark.parametrize(
    "host, port, needle",
    [
        ("127.0.0.1", 70000, "--port must be from 1 to 65535, got 70000"),
        ("127.0.0.1", 0, "--port must be from 1 to 65535, got 0"),
        ("256.1.1.1", 8765, "pass an address of this machine with --host"),
    ],
)
def test_serve_refuses_a_bad_port_or_host_in_one_line(host, port, needle):
    from d5rl.browse.server import serve
    from d5rl.errors import D5RLError

    with pytest.raises(D5RLError, match=needle.replace("-", r"\-")):
        serve(host, port, [])


def test_run_labels_tell_grids_apart(tmp_path):
    from d5rl.browse.runs import run_labels

    a, b = tmp_path / "results/table1-state/cells", tmp_path / "results/a1-o2o/cells"
    assert run_labels([a, b]) == ["table1-state/cells", "a1-o2o/cells"]  # both folders are named cells
    assert run_labels([a]) == ["table1-state/cells"]  # a bare "cells" keeps the folder above it
    assert run_labels([tmp_path / "runs/mine"]) == ["mine"]
    assert run_labels([a, tmp_path / "runs/x/cells"]) == ["results/table1-state/cells", "runs/x/cells"]
    assert run_labels([a, a]) == ["table1-state/cells", "table1-state/cells #2"]


@pytest.mark.parametrize(
    "host, ok",
    [
        ("localhost:8765", True),
        ("127.0.0.1:8765", True),
        ("[::1]:8765", True),
        ("192.168.1.7", True),
        ("browse-host.example", True),
        ("evil.example", False),
        ("evil.example:8765", False),
        ("localhost.evil.example", False),
        ("", False),
    ],
)
def test_only_requests_naming_this_server_are_answered(host, ok):
    """DNS rebinding: a page on evil.example points its name at 127.0.0.1 and reads the server from the
    user's browser, with ``Host: evil.example``."""
    c = TestClient(create_app([], host="browse-host.example"), base_url="http://localhost:8765")
    r = c.get("/api/tasks", headers={"Host": host})
    assert (r.status_code == 200) == ok, (host, r.status_code, r.text[:200])
    if not ok:
        assert r.status_code == 400 and "is not a name of this d5rl browse server" in r.text
        assert c.get("/", headers={"Host": host}).status_code == 400
