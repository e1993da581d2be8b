"""Environment and dataset access for training: registered tasks or the numpy toy task."""

from __future__ import annotations

import collections
import functools

import gymnasium as gym
import numpy as np

from d5rl.training import toy


class StackPixels(gym.Wrapper):
    """Stack the last ``k`` frames of every ``pixels*`` key on the channel axis (oldest first).

    After a reset the first frame is repeated, matching ``Dataset.sample(frame_stack=k)``,
    which clamps at the episode's first step.
    """

    def __init__(self, env: gym.Env, k: int):
        super().__init__(env)
        self.k = int(k)
        space = env.observation_space
        self.keys = [key for key in space.spaces if key.startswith("pixels")]
        spaces = dict(space.spaces)
        for key in self.keys:
            h, w, c = space[key].shape
            spaces[key] = gym.spaces.Box(0, 255, (h, w, c * self.k), np.uint8)
        self.observation_space = gym.spaces.Dict(spaces)
        self.frames = {key: collections.deque(maxlen=self.k) for key in self.keys}

    def _obs(self, obs):
        out = dict(obs)
        for key in self.keys:
            out[key] = np.concatenate(list(self.frames[key]), axis=-1)
        return out

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        for key in self.keys:
            self.frames[key].clear()
            self.frames[key].extend([obs[key]] * self.k)
        return self._obs(obs), info

    def step(self, action):
        obs, r, term, trunc, info = self.env.step(action)
        for key in self.keys:
            self.frames[key].append(obs[key])
        return self._obs(obs), r, term, trunc, info


def make_task_env(task_id: str, frame_stack: int = 1, render_mode: str | None = None, **kwargs) -> gym.Env:
    """The task's env (toy tasks included), with pixel frame stacking when ``frame_stack > 1``."""
    if task_id in toy.TOY_TASKS:
        env = gym.wrappers.TimeLimit(toy.ToyReachEnv(pixels="pixels" in task_id, render_mode=render_mode),
                                     toy.HORIZON)
    else:
        from d5rl.registry import make_env

        env = make_env(task_id, **({"render_mode": render_mode} if render_mode else {}), **kwargs)
    if frame_stack > 1 and isinstance(env.observation_space, gym.spaces.Dict):
        env = StackPixels(env, frame_stack)
    return env


def env_factory(task_id: str, frame_stack: int = 1, render_mode: str | None = None):
    """A picklable zero-argument constructor (for process-pool vector envs)."""
    return functools.partial(make_task_env, task_id, frame_stack, render_mode)


def load_task_dataset(task_id: str, **kwargs):
    if task_id in toy.TOY_TASKS:
        return toy.toy_dataset(pixels="pixels" in task_id, **kwargs)
    from d5rl import load_dataset

    return load_dataset(task_id, **kwargs)


def episode_scorer(task_id: str):
    """``(episode_return, final_info) -> normalized score``, or None when the task has no score.

    Tasks score either from the return (A1: random = 0, expert = 1) or from the last
    step's ``info["score"]`` (kitchen, WidowX); :func:`d5rl.episode_score` knows which.
    """
    if task_id in toy.TOY_TASKS:
        return lambda ret, info: float(toy.toy_normalize_score(ret))
    from d5rl.registry import episode_score, get_spec

    spec = get_spec(task_id)
    if spec.score_from == "return" and spec.score is None:
        return None
    return functools.partial(episode_score, task_id)
