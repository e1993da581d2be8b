"""Environment and dataset access for training: registered tasks, with frame stacking for cameras."""

from __future__ import annotations

import functools

import gymnasium as gym

from d5rl.datasets.loading import load_dataset
from d5rl.envs.wrappers import FrameStack
from d5rl.registry import episode_score, get_spec, make_env


def make_task_env(task_id: str, frame_stack: int = 1, render_mode: str | None = None, **kwargs) -> gym.Env:
    """The task's env, with pixel frame stacking when ``frame_stack > 1``."""
    env = make_env(task_id, **({"render_mode": render_mode} if render_mode else {}), **kwargs)
    if frame_stack > 1 and isinstance(env.observation_space, gym.spaces.Dict):
        env = FrameStack(env, frame_stack)
    return env


def env_factory(task_id: str, frame_stack: int = 1, render_mode: str | None = None):
    """A picklable zero-argument constructor (for process-pool vector envs)."""
    return functools.partial(make_task_env, task_id, frame_stack, render_mode)


def load_task_dataset(task_id: str, **kwargs):
    return load_dataset(task_id, **kwargs)


def episode_scorer(task_id: str):
    """``(episode_return, final_info) -> normalized score``, or None when the task has no score.

    Tasks score either from the return (A1: random = 0, expert = 1) or from the last
    step's ``info["score"]`` (kitchen, WidowX); :func:`d5rl.episode_score` knows which.
    """
    spec = get_spec(task_id)
    if spec.score_from == "return" and spec.score is None:
        return None
    return functools.partial(episode_score, task_id)
