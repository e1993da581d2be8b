"""`d5rl report --videos`: one rollout GIF per task from the best cell's checkpoint."""

import json

import numpy as np
import pytest

pytest.importorskip("jax")

from d5rl.runner import expand_grid, run_bench, write_report
from d5rl.runner.grid import DEFAULT_JOB

PROTOCOL = {"eval_interval": 16, "eval_episodes": 2, "hidden_dims": "16,16", "batch_size": "16"}


def test_report_renders_the_median_episode_of_the_best_cell(tmp_path):
    import imageio.v2 as imageio

    from d5rl.training.evaluation import evaluate
    from d5rl.training.loop import load_run

    cells = expand_grid(["toy-reach-v0"], ["bc"], [0, 1], 16, 0, job=DEFAULT_JOB, overrides=PROTOCOL)
    assert not run_bench(cells, tmp_path, workers=0, progress=False).failed
    report = write_report(tmp_path, reps=20, plots=False, videos=True).read_text()
    gif = tmp_path / "report" / "videos" / "toy-reach-v0.gif"
    captions = json.loads((tmp_path / "report" / "videos" / "captions.json").read_text())
    assert gif.exists() and "## Rollouts" in report and "videos/toy-reach-v0.gif" in report

    finals = {}
    for c in cells:
        rows = [json.loads(x) for x in (c.directory(tmp_path) / "metrics.jsonl").read_text().splitlines()]
        finals[c.seed] = [r["eval/toy-reach-v0/score"] for r in rows if "eval/toy-reach-v0/score" in r][-1]
    best = max(finals, key=lambda s: (finals[s], -s))
    assert captions["toy-reach-v0"].startswith(f"BC seed {best} ")
    # the episode shown is the median of the five evaluation episodes (seeds 0-4) of that agent
    agent, _ = load_run(cells[best].directory(tmp_path))
    scores = [evaluate(agent, "toy-reach-v0", 1, seed=s)["score"] for s in range(5)]
    median = sorted(scores)[2]
    shown = scores.index(median)
    assert f"episode seed {shown}, the median of 5" in captions["toy-reach-v0"]
    frames = imageio.mimread(str(gif))
    assert len(frames) >= 2 and np.asarray(frames[0]).shape[-1] == 3  # (the GIF writer merges repeated frames)

    import shutil

    # a machine holding only a weaker cell's checkpoint keeps the GIF of the better one
    before = gif.read_bytes()
    shutil.rmtree(cells[best].directory(tmp_path) / "checkpoint")
    write_report(tmp_path, reps=20, plots=False, videos=True)
    assert gif.read_bytes() == before
    assert json.loads((tmp_path / "report" / "videos" / "captions.json").read_text()) == captions
    # ... and a machine without any checkpoint keeps the GIFs already written
    for c in cells:
        shutil.rmtree(c.directory(tmp_path) / "checkpoint", ignore_errors=True)
    write_report(tmp_path, reps=20, plots=False, videos=True)
    assert gif.read_bytes() == before
