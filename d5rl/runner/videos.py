"""One rollout GIF per task for a report: the final policy of the task's best cell, one episode.

``d5rl report RUN_DIR --videos`` calls :func:`write_rollout_gifs`.  For each task it takes the finished,
current cell with the highest final score (ties: the paper's method order, then the lower seed), restores
its agent from the cell's checkpoint, replays the first round of its final evaluation (the first
``eval_envs`` episodes, five in the published grids, stepped together as they ran, so they score what they
scored there), films the median-scoring one with the env's render camera (fast render settings, every
``EVERY``-th step) and writes it to ``videos/<task>.gif``.  Cells whose checkpoint is not on this
machine (grids carried between machines keep results, not checkpoints) are passed over for the next
best, but a GIF written earlier is kept when its caption names a cell ranked above every cell whose
checkpoint is here (or when no cell of its task has one).  Needs the
``train`` extra (JAX) and a GL backend.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from d5rl.rollout import Step, rollout
from d5rl.runner.results import METHODS, method_name
from d5rl.training.config import final_eval_episodes
from d5rl.training.envs import episode_scorer, make_task_env
from d5rl.training.rundir import RunDir
from d5rl.video import FrameRenderer, write_gif

GIFS = "videos"  # the report's folder of rollout GIFs and their captions.json
GIF_SIZE = (120, 160)  # (height, width) of the frames
EVERY = 2  # keep every 2nd step: ~10 frames per second of simulated time at 20 Hz control
EPISODE = "; final evaluation's episode "  # a caption after its cell's label: which episode the GIF shows


def ranked_cells(results, task: str) -> list:
    """The finished, current cells of ``task`` with a final score, best first (the GIF's choice)."""
    order = list(METHODS)
    cells = [r for r in results if r.task == task and r.counts and r.final]
    score = lambda r: r.final.get("online", r.final.get("offline", -np.inf))  # noqa: E731
    rank = lambda r: (-score(r), order.index(r.algo) if r.algo in order else len(order), r.seed)  # noqa: E731
    return sorted(cells, key=rank)


def _round(agent, envs, task: str, seed: int, film: int | None = None, camera=None, every: int = EVERY):
    """``(each episode's normalized score or return, frames)`` of the first round of an evaluation with seed
    ``seed``: its first ``len(envs)`` episodes, stepped together as :func:`d5rl.training.evaluation.evaluate`
    steps them, so each replays exactly, to the last bit of the actions.  Frames (with a camera) of episode
    ``film``: after the reset, every ``every``-th step and after the last."""
    from d5rl.training.evaluation import batched_policy, episode_seeds  # JAX (the train extra)

    frames = []

    def on_reset(i, *_):
        if i == film:
            frames.append(camera())

    def on_step(step: Step) -> None:
        if step.episode == film and ((step.t + 1) % every == 0 or step.done):
            frames.append(camera())

    episodes = rollout(
        envs,
        batched_policy(agent, seed),
        episode_seeds(seed, 0, len(envs)),
        on_reset=on_reset if camera else None,
        on_step=on_step if camera else None,
    )
    scorer = episode_scorer(task)
    return [scorer(e.ret, e.info) if scorer is not None else e.ret for e in episodes], frames


def typical_rollout(cell_dir: Path, task: str, *, size=GIF_SIZE, every: int = EVERY):
    """The median-scoring episode (the earlier on ties) of the first round of the final evaluation of the agent
    saved in ``cell_dir``: the first ``eval_envs`` of its episodes, replayed beside each other as they ran, so
    the episode shown is one the cell's published score averages.  ``(frames, frames per second, the episode's
    index in the evaluation, every episode's score)``."""
    from d5rl.training.evaluation import batch_width  # JAX (the train extra)
    from d5rl.training.loop import load_run  # JAX (the train extra): loaded by the commands that need it
    from d5rl.training.parts import evaluation_seed

    agent, resolved = load_run(cell_dir)
    train = resolved["train"]
    width = batch_width(train["eval_envs"], final_eval_episodes(train))  # the final evaluation's first round
    seed = evaluation_seed(resolved["seed"])
    # envs without a MuJoCo camera (toy) are filmed through render(), which needs a render mode as in Gymnasium
    envs = [make_task_env(task, train["frame_stack"], render_mode="rgb_array") for _ in range(width)]
    try:
        scores, _ = _round(agent, envs, task, seed)
        shown = scores.index(sorted(scores)[(width - 1) // 2])
        camera = FrameRenderer(envs[shown], size, "fast")
        try:
            again, frames = _round(agent, envs, task, seed, shown, camera, every)
        finally:
            camera.close()
    finally:
        for env in envs:
            env.close()
    assert again == scores, "evaluation episodes must replay exactly"
    return frames, float(envs[0].unwrapped.metadata.get("render_fps", 20)) / every, shown, scores


def write_rollout_gifs(results, out_dir: Path, log=print) -> dict[str, str]:
    """``{task: caption}`` for every GIF under ``out_dir/videos`` after writing the ones it can (see the
    module docstring).  A caption names the cell and the episode's score."""
    videos = Path(out_dir) / GIFS
    captions = read_captions(videos)
    for task in sorted({r.task for r in results}):
        shown = captions.get(task) if (videos / f"{task}.gif").exists() else None
        for cell in ranked_cells(results, task):
            here = RunDir(cell.directory).checkpoint.exists()
            if shown is not None and _names(shown, cell):
                if shown.startswith(_cell_label(cell) + EPISODE) or not here:
                    break  # the GIF already shows this cell, better than any whose checkpoint is here: keep it
                # else made by an earlier d5rl's GIF code (episodes of its own, one at a time): made again
            if not here:
                continue
            frames, fps, shown, scores = typical_rollout(cell.directory, task)
            write_gif(videos / f"{task}.gif", frames, fps)
            captions[task] = (
                f"{_cell_label(cell)}{EPISODE}{shown + 1}, the median of its first "
                f"{len(scores)} ({', '.join(f'{x:.2f}' for x in scores)})"
            )
            log(f"rollout {task}: {captions[task]}")
            break
    _write_captions(videos, captions)
    return captions


def caption_note(results, task: str, caption: str) -> str:
    """What a GIF's caption no longer says truly, given the grid's results now (empty when it holds): the cell
    it names was trained again or went stale since (its label, with its final score, matches no current
    cell), or a better cell has finished since, on a machine other than the one that made the GIF."""
    ranked = ranked_cells(results, task)
    if ranked and _names(caption, ranked[0]):
        return ""
    if any(_names(caption, cell) for cell in ranked):
        return (
            f"the task's best cell is now {_cell_label(ranked[0])}; to film it, run `d5rl report --videos` "
            "where its checkpoint is"
        )
    return (
        "made from an earlier training of this cell, not its current result; to film the task's best cell, "
        "run `d5rl report --videos` where its checkpoint is"
    )


def _names(caption: str, cell) -> bool:
    """Whether a GIF's caption names ``cell`` as it is now (its label, final score included, then ``;``)."""
    return caption.startswith(_cell_label(cell) + ";")


def _cell_label(cell) -> str:
    """How a caption names its cell: method, seed and final score (a cell trained again scores anew)."""
    final = cell.final.get("online", cell.final.get("offline"))
    return f"{method_name(cell.algo)} seed {cell.seed} (final score {final:.3f})"


def read_captions(videos: Path) -> dict[str, str]:
    path = videos / "captions.json"
    try:
        return dict(json.loads(path.read_text()))
    except (OSError, ValueError):
        return {}


def drop_rollouts(videos: Path, tasks) -> list[str]:
    """Delete the GIFs (and captions) of tasks no longer in the grid (their cells were removed), so the report
    shows only tasks it has results for; returns the tasks dropped."""
    captions = read_captions(videos)
    gone = sorted({*captions, *(p.stem for p in videos.glob("*.gif"))} - set(tasks))
    for task in gone:
        (videos / f"{task}.gif").unlink(missing_ok=True)
        captions.pop(task, None)
    if gone and captions:
        _write_captions(videos, captions)
    elif gone:
        (videos / "captions.json").unlink(missing_ok=True)
    return gone


def _write_captions(videos: Path, captions: dict[str, str]) -> None:
    if captions:
        videos.mkdir(parents=True, exist_ok=True)
        (videos / "captions.json").write_text(json.dumps(captions, indent=2, sort_keys=True) + "\n")
