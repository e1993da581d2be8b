"""One rollout GIF per task for a report: the final policy of the task's best cell, one episode.

``d5rl report RUN_DIR --videos`` calls :func:`write_rollout_gifs`.  For each task it takes the finished,
current cell with the highest final score (ties: the paper's method order, then the lower seed), restores
its agent from the cell's checkpoint, runs five evaluation episodes (seeds 0-4, the agent's evaluation
actions), replays the median-scoring one with the env's render camera (fast render settings, every
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
from d5rl.training.envs import episode_scorer, make_task_env
from d5rl.training.rundir import RunDir
from d5rl.video import FrameRenderer, write_gif

GIFS = "videos"  # the report's folder of rollout GIFs and their captions.json
GIF_SIZE = (120, 160)  # (height, width) of the frames
EVERY = 2  # keep every 2nd step: ~10 frames per second of simulated time at 20 Hz control


def ranked_cells(results, task: str) -> list:
    """The finished, current cells of ``task`` with a final score, best first (the GIF's choice)."""
    order = list(METHODS)
    cells = [r for r in results if r.task == task and r.counts and r.final]
    score = lambda r: r.final.get("online", r.final.get("offline", -np.inf))  # noqa: E731
    rank = lambda r: (-score(r), order.index(r.algo) if r.algo in order else len(order), r.seed)  # noqa: E731
    return sorted(cells, key=rank)


def _episode(agent, env, task: str, seed: int, camera=None, every: int = EVERY):
    """``(normalized score or return, frames)`` of one evaluation episode (frames only with a camera: after the
    reset, every ``every``-th step and after the last)."""
    import jax  # the train extra: a report without videos does not need it

    key = jax.random.PRNGKey(seed)

    def act(observations, live, steps):
        nonlocal key
        key, k = jax.random.split(key)
        batch = jax.tree_util.tree_map(lambda x: np.asarray(x)[None], observations[0])
        return np.asarray(agent.eval_actions(batch, seed=k))

    frames = []

    def film(step: Step) -> None:
        if (step.t + 1) % every == 0 or step.done:
            frames.append(camera())

    (episode,) = rollout(
        [env],
        act,
        [seed],
        on_reset=(lambda *_: frames.append(camera())) if camera else None,
        on_step=film if camera else None,
    )
    scorer = episode_scorer(task)
    return (scorer(episode.ret, episode.info) if scorer is not None else episode.ret), frames


def typical_rollout(cell_dir: Path, task: str, *, episodes: int = 5, size=GIF_SIZE, every: int = EVERY):
    """The median-scoring of ``episodes`` evaluation episodes (seeds 0, 1, ...; the lower seed on ties) of
    the agent saved in ``cell_dir``: ``(frames, frames per second, its seed, every episode's score)``."""
    from d5rl.training.loop import load_run  # JAX (the train extra): loaded by the commands that need it

    agent, resolved = load_run(cell_dir)
    env = make_task_env(task, resolved["train"]["frame_stack"], render_mode="rgb_array")  # envs without a
    # MuJoCo camera (toy) are filmed through render(), which needs a render mode as in Gymnasium
    try:
        scores = [_episode(agent, env, task, s)[0] for s in range(episodes)]
        median = sorted(scores)[(episodes - 1) // 2]
        seed = scores.index(median)
        camera = FrameRenderer(env, size, "fast")
        try:
            again, frames = _episode(agent, env, task, seed, camera, every)
        finally:
            camera.close()
    finally:
        env.close()
    assert again == scores[seed], "evaluation episodes must replay exactly"
    return frames, float(env.unwrapped.metadata.get("render_fps", 20)) / every, seed, scores


def write_rollout_gifs(results, out_dir: Path, log=print) -> dict[str, str]:
    """``{task: caption}`` for every GIF under ``out_dir/videos`` after writing the ones it can (see the
    module docstring).  A caption names the cell and the episode's score."""
    videos = Path(out_dir) / GIFS
    captions = read_captions(videos)
    for task in sorted({r.task for r in results}):
        shown = captions.get(task) if (videos / f"{task}.gif").exists() else None
        for cell in ranked_cells(results, task):
            if shown is not None and shown.startswith(_cell_label(cell) + ";"):
                break  # the GIF already shows this cell, better than any whose checkpoint is here: keep it
            if not RunDir(cell.directory).checkpoint.exists():
                continue
            frames, fps, seed, scores = typical_rollout(cell.directory, task)
            write_gif(videos / f"{task}.gif", frames, fps)
            captions[task] = (
                f"{_cell_label(cell)}; episode seed {seed}, the median of {len(scores)} "
                f"({', '.join(f'{x:.2f}' for x in scores)})"
            )
            log(f"rollout {task}: {captions[task]}")
            break
    _write_captions(videos, captions)
    return captions


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


def _write_captions(videos: Path, captions: dict[str, str]) -> None:
    if captions:
        videos.mkdir(parents=True, exist_ok=True)
        (videos / "captions.json").write_text(json.dumps(captions, indent=2, sort_keys=True) + "\n")
