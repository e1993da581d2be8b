"""Evaluation: run episodes in parallel environments with batched policy inference."""

from __future__ import annotations

import functools
import json
import multiprocessing
import signal
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import jax
import numpy as np

from d5rl.errors import D5RLError, is_int
from d5rl.files import read_json, write_atomic
from d5rl.parallel import die_with_parent
from d5rl.rollout import Step, rollout
from d5rl.training.envs import env_factory, episode_scorer
from d5rl.video import check_video_path, write_gif, write_video

PROGRESS_FORMAT = 1


def _stack_obs(obs_list):
    if isinstance(obs_list[0], dict):
        return {k: np.stack([o[k] for o in obs_list]) for k in obs_list[0]}
    return np.stack(obs_list)


def evaluate(
    agent,
    task_id: str,
    num_episodes: int = 10,
    seed: int = 0,
    *,
    num_envs: int = 1,
    frame_stack: int = 1,
    processes: bool = False,
    video_path: str | Path | None = None,
    env_fn: Callable[[], gym.Env] | None = None,
    progress: EvalProgress | None = None,
) -> dict[str, Any]:
    """Mean return, normalized score (if the task has references), success and length over episodes, and
    each episode's (``returns``, ``lengths``, ``scores``); ``stats``: the mean over episodes of each value of
    the final ``info["episode_stats"]``, where the task reports some (the kitchen: which subtasks were done).

    ``num_envs`` environments step in lockstep and the agent acts on all of them in
    one batch; ``processes=True`` puts each in its own process (gymnasium
    ``AsyncVectorEnv``).  Episode ``i`` resets with seed ``seed + i`` and a stochastic
    policy acts in it with keys drawn from ``(seed, i, step)``, so its draws do not depend
    on ``num_envs``.  The policy's arithmetic does, in the last bit, at one row: for each of the ten
    agents a row's action has the same bits in batches of 2 to 10 rows, while a batch of one row (XLA's
    matrix-vector product) differs, for nine of them, by 1e-7 to 1e-5 (``num_envs=1``, or the last
    episode of a round still running alone); on a task whose episodes all start alike (A1 walk and
    run) that can change the rollout (docs/experiments/a1-updates).  ``video_path`` records the first
    episode.  ``progress`` keeps the finished episodes on disk, so that an
    evaluation killed midway resumes at its first unfinished episode with the same result (see
    :class:`EvalProgress`).
    """
    if int(num_episodes) < 1:
        raise D5RLError(f"cannot evaluate on {num_episodes} episodes", "evaluate on at least 1 episode")
    if not is_int(seed, lo=0):
        raise D5RLError(f"the evaluation seed must be a non-negative integer, got {seed!r}", "pass e.g. --seed 0")
    if video_path is not None:
        video_path = check_video_path(video_path)
    num_envs = batch_width(num_envs, num_episodes)
    evaluation = {
        "task_id": task_id,
        "seed": int(seed),
        "num_episodes": int(num_episodes),
        "frame_stack": int(frame_stack),
    }
    episodes = progress.load(evaluation) if progress is not None else []  # {"return", "length", "success", "info"}
    if episodes and video_path is not None and not _video_file(video_path):
        episodes = []  # the first episode's video was not written: evaluate it again
    if episodes:
        print(f"evaluation resumes at episode {len(episodes) + 1} of {num_episodes} ({progress.path.name})", flush=True)
    with _EvalEnvs(task_id, frame_stack, num_envs, processes, video_path is not None, env_fn) as envs:
        while len(episodes) < num_episodes:
            first = len(episodes)
            film = _Film(envs.render) if video_path is not None and first == 0 else None
            done = rollout(
                envs.envs,
                batched_policy(agent, seed, first),
                episode_seeds(seed, first, min(num_envs, num_episodes - first)),
                on_reset=film.on_reset if film else None,
                on_step=film.on_step if film else None,
            )
            episodes += [
                {"return": e.ret, "length": e.length, "success": e.success, "info": _final_info(e.info)} for e in done
            ]
            if film and film.frames:
                _write_video(Path(video_path), film.frames)
            if progress is not None and len(episodes) < num_episodes:
                progress.save(evaluation, episodes)
    out = _summary(task_id, episodes, scored=env_fn is None)
    if video_path is not None and _video_file(video_path):
        out["video"] = str(_video_file(video_path))
    if progress is not None:
        progress.clear()
    return out


def batch_width(num_envs: int, num_episodes: int) -> int:
    """How many episodes an evaluation steps together: ``num_envs``, at most one per episode."""
    return max(1, min(int(num_envs), int(num_episodes)))


def episode_seeds(seed: int, first: int, count: int) -> list[int]:
    """The reset seeds of an evaluation's episodes ``first`` to ``first + count - 1``: episode ``i`` of an
    evaluation with seed ``seed`` resets with ``seed + i``."""
    return [seed + first + i for i in range(count)]


def batched_policy(agent, seed: int, first: int = 0):
    """The :func:`d5rl.rollout.rollout` policy of an evaluation with seed ``seed`` for a batch of its episodes
    numbered from ``first``: the agent's evaluation actions, each drawn with the key of its (episode, step)
    (see :func:`_step_keys`).  Stepped beside the same episodes (:func:`episode_seeds`) it replays them exactly,
    as the report's rollout GIFs do."""
    key = jax.random.PRNGKey(seed)

    def act(observations, live, steps):
        return np.asarray(agent.eval_actions(_stack_obs(observations), seed=_step_keys(key, first + live, steps)))

    return act


def _summary(task_id: str, episodes: list[dict], *, scored: bool) -> dict[str, Any]:
    """The means :func:`evaluate` returns over its episodes (``score`` only for a registered task's env)."""
    returns = [e["return"] for e in episodes]
    out = {
        "return": float(np.mean(returns)),
        "return_std": float(np.std(returns)),
        "length": float(np.mean([e["length"] for e in episodes])),
        "success": float(np.mean([e["success"] for e in episodes])),
        "episodes": len(episodes),
        "returns": returns,
        "lengths": [int(e["length"]) for e in episodes],
    }
    stats = [e["info"].get("episode_stats") or {} for e in episodes]
    if any(stats):
        out["stats"] = {k: float(np.mean([st[k] for st in stats if k in st])) for k in sorted(set().union(*stats))}
    scorer = episode_scorer(task_id) if scored else None
    if scorer is not None:
        scores = np.asarray([scorer(e["return"], e["info"]) for e in episodes], np.float64)
        out["score"] = float(scores.mean())
        out["score_std"] = float(scores.std())
        out["scores"] = scores.tolist()
    return out


class _Film:
    """The frames of a rollout's first episode: after its reset and after each of its steps but the last."""

    def __init__(self, render: Callable[[], np.ndarray]):
        self.render, self.frames = render, []

    def on_reset(self, i: int, obs, info) -> None:
        if i == 0:
            self.frames.append(self.render())

    def on_step(self, step: Step) -> None:
        if step.episode == 0 and not step.done:
            self.frames.append(self.render())


class _EvalEnvs:
    """The ``num_envs`` envs an evaluation steps: in this process, or each in its own process (a Gymnasium
    ``AsyncVectorEnv``); the first renders when the evaluation is filmed.  On an error or Ctrl-C the worker
    processes are stopped at once, mid-step or not."""

    def __init__(self, task_id, frame_stack, num_envs, processes, render, env_fn):
        fns = [
            env_fn or env_factory(task_id, frame_stack, "rgb_array" if (render and i == 0) else None)
            for i in range(num_envs)
        ]
        self.processes = processes
        if processes:
            parts = [functools.partial(_in_worker, fn) for fn in fns]
            self.envs = gym.vector.AsyncVectorEnv(parts, copy=True, context="spawn")
        else:
            self.envs = [fn() for fn in fns]

    def render(self) -> np.ndarray:
        if self.processes:
            return np.asarray(self.envs.call("render")[0])
        return np.asarray(self.envs[0].render())

    def __enter__(self):
        return self

    def __exit__(self, kind, *_):
        if self.processes:
            self.envs.close(terminate=kind is not None)
        else:
            for e in self.envs:
                e.close()


class EvalProgress:
    """The finished episodes of one evaluation, in a JSON file rewritten atomically after each batch of
    ``num_envs`` episodes.  An evaluation resumes from it only when it is the same evaluation: the same
    ``evaluation`` (task, seed, episode count and frame stack) and the same ``identity`` (the training loop:
    the step and a hash of the agent's arrays); otherwise, or when the file is damaged, it starts at episode 1.  Each
    episode's result does not depend on which episodes ran beside it or before it, so a resumed evaluation
    returns the same numbers as an unbroken one.  The file is removed when the evaluation finishes.  It also
    keeps the wall seconds its episodes took over every process that worked on it (``wall_s``); after
    :meth:`load`, ``earlier_s`` is the part spent by earlier processes, which a resumed run adds to its wall
    time (a long evaluation stopped near its end holds most of a cell's time)."""

    def __init__(self, path: str | Path, identity: dict[str, Any]):
        self.path, self.identity = Path(path), dict(identity)
        self.earlier_s = 0.0  # wall seconds the loaded episodes took in earlier processes
        self._since = time.monotonic()  # when this process's part of the evaluation began

    def _header(self, evaluation: dict[str, Any]) -> dict[str, Any]:
        return {"format": PROGRESS_FORMAT, **evaluation, **self.identity}

    def load(self, evaluation: dict[str, Any]) -> list[dict]:
        """The finished episodes, each ``{"return", "length", "success", "info"}``; [] unless the file holds
        this evaluation's."""
        self.earlier_s, self._since = 0.0, time.monotonic()
        if not self.path.exists():
            return []
        try:
            data = read_json(self.path, "evaluation progress")  # bounded: a FIFO here is refused, not waited on
            episodes = data["episodes"]
            ok = data["evaluation"] == self._header(evaluation)
            ok = ok and all(set(e) == {"return", "length", "success", "info"} for e in episodes)
            wall = float(data.get("wall_s", 0.0))  # files written before evaluations kept their time: unknown, 0
        except (OSError, ValueError, KeyError, TypeError, D5RLError) as e:
            print(
                f"warning: {self.path} is damaged ({type(e).__name__}); the evaluation starts at episode 1",
                file=sys.stderr,
                flush=True,
            )
            return []
        if not ok:
            return []
        self.earlier_s = wall if np.isfinite(wall) and wall > 0 else 0.0
        return episodes[: evaluation["num_episodes"]]

    def save(self, evaluation: dict[str, Any], episodes: list[dict]) -> None:
        wall = self.earlier_s + time.monotonic() - self._since
        data = {"evaluation": self._header(evaluation), "episodes": episodes, "wall_s": round(wall, 3)}
        write_atomic(self.path, json.dumps(data) + "\n")

    def clear(self) -> None:
        self.path.unlink(missing_ok=True)


@jax.jit
def _step_keys(key, episodes, steps):
    """One key per (episode, step): a stochastic policy's action in episode ``i`` at step ``t`` is the same
    whichever episodes step beside it, so the result does not depend on ``num_envs``."""
    return jax.vmap(lambda e, t: jax.random.fold_in(jax.random.fold_in(key, e), t))(episodes, steps)


def _final_info(info: dict) -> dict:
    """What evaluation reads from an episode's last info (``score`` and ``episode_stats``), as plain floats."""
    out: dict[str, Any] = {}
    if "score" in info:
        out["score"] = float(info["score"])
    if "episode_stats" in info:
        out["episode_stats"] = {k: float(v) for k, v in info["episode_stats"].items() if not k.startswith("_")}
    return out


def _in_worker(make_env: Callable[[], gym.Env]) -> gym.Env:
    """Build an env inside an AsyncVectorEnv worker that dies with the evaluating process and leaves
    Ctrl-C to it (which then terminates the workers), so no worker outlives its evaluation."""
    if multiprocessing.parent_process() is not None:  # AsyncVectorEnv also calls this once in the parent
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        die_with_parent()
    return make_env()


def _video_file(path: str | Path | None) -> Path | None:
    """The video :func:`_write_video` wrote for ``path`` (an MP4, or a GIF without ffmpeg), if it exists."""
    if path is None:
        return None
    return next((p for p in (Path(path), Path(path).with_suffix(".gif")) if p.exists()), None)


def _write_video(path: Path, frames) -> None:
    """An MP4, or a GIF without ffmpeg; either is renamed into place whole, so that a kill never leaves a
    truncated video for a resumed evaluation to trust."""
    try:
        write_video(path, frames, fps=20)
    except (ImportError, RuntimeError, ValueError):  # no ffmpeg (the path was checked): fall back to GIF
        write_gif(path.with_suffix(".gif"), frames, fps=20)
