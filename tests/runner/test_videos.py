"""`d5rl report --videos`: one rollout GIF per task from the best cell's checkpoint."""

import json

import numpy as np
import pytest

pytest.importorskip("jax")

from d5rl.runner import expand_grid, run_bench, write_report
from d5rl.runner.grid import DEFAULT_JOB
from d5rl.runner.report import ReportError

PROTOCOL = {"eval_interval": 16, "eval_episodes": 2, "hidden_dims": "16,16", "batch_size": "16"}


def test_report_renders_the_median_episode_of_the_best_cells_final_evaluation(tmp_path):
    import imageio.v2 as imageio

    from d5rl.runner.videos import typical_rollout

    # a final evaluation of one round (5 episodes, 5 envs): the GIF's five episodes are all it averages
    protocol = {**PROTOCOL, "final_eval_episodes": 5}
    cells = expand_grid(["toy-reach-v0"], ["bc"], [0, 1], 16, 0, job=DEFAULT_JOB, overrides=protocol)
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
    # the replayed episodes are the final evaluation's own: their mean is the cell's published score
    _, _, shown, scores = typical_rollout(cells[best].directory(tmp_path), "toy-reach-v0")
    assert len(scores) == 5 and np.mean(scores) == pytest.approx(finals[best], rel=1e-9, abs=1e-12)
    assert len(set(scores)) > 1  # the toy's episodes differ, so the median below is a choice
    assert scores[shown] == sorted(scores)[2] and shown == scores.index(sorted(scores)[2])
    listed = ", ".join(f"{x:.2f}" for x in scores)
    assert f"final evaluation's episode {shown + 1}, the median of its first 5 ({listed})" in captions["toy-reach-v0"]
    # a GIF an earlier d5rl made of the same cell (its own episodes, one at a time) is made again
    label = captions["toy-reach-v0"].split(";")[0]
    old = {"toy-reach-v0": f"{label}; episode seed 3, the median of 5 (0.10, 0.20, 0.30, 0.40, 0.50)"}
    (tmp_path / "report" / "videos" / "captions.json").write_text(json.dumps(old))
    write_report(tmp_path, reps=20, plots=False, videos=True)
    assert json.loads((tmp_path / "report" / "videos" / "captions.json").read_text()) == captions

    # --video-tasks films the tasks named; one the grid does not have is refused before any work
    from d5rl.cli import main

    before = gif.read_bytes()
    assert main(["report", str(tmp_path), "--no-plots", "--reps", "20", "--video-tasks", "toy-reach-v0"]) == 0
    assert gif.read_bytes() == before
    with pytest.raises(ReportError, match="no cells of toy-other-v0 under .*name tasks of the grid: toy-reach-v0"):
        write_report(tmp_path, reps=20, plots=False, videos=["toy-other-v0"])
    # a task whose cells were taken out of the grid loses its GIF and caption; the others stay
    videos = tmp_path / "report" / "videos"
    (videos / "toy-gone-v0.gif").write_bytes(before)
    (videos / "captions.json").write_text(json.dumps({**captions, "toy-gone-v0": "BC seed 0"}))
    report = write_report(tmp_path, reps=20, plots=False).read_text()
    assert not (videos / "toy-gone-v0.gif").exists() and "toy-gone-v0" not in report
    assert json.loads((videos / "captions.json").read_text()) == captions and gif.read_bytes() == before
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

    # the report marks a caption the results have moved past: a better cell finished since, or the cell named
    # was trained again (its label carries its final score)
    rest = captions["toy-reach-v0"].split(";", 1)[1]
    other = 1 - best
    moved = {
        f"BC seed {other} (final score {finals[other]:.3f})": f"the task's best cell is now BC seed {best} (final",
        f"BC seed {best} (final score 9.999)": "made from an earlier training of this cell, not its current result",
    }
    for label, note in moved.items():
        (videos / "captions.json").write_text(json.dumps({"toy-reach-v0": f"{label};{rest}"}))
        report = write_report(tmp_path, reps=20, plots=False).read_text()
        assert f"**toy-reach-v0**: {label};{rest} (**{note}" in report
    (videos / "captions.json").write_text(json.dumps(captions))
    report = write_report(tmp_path, reps=20, plots=False).read_text()
    assert f"**toy-reach-v0**: {captions['toy-reach-v0']}\n" in report
