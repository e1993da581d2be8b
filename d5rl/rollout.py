"""One rollout loop: a policy steps through one or more Gymnasium environments in lockstep, one episode each.

Evaluation, report videos and data generation all run episodes through :func:`rollout`; what differs
between them (how actions are drawn, what is recorded, which frames are filmed) is the ``act`` callable and
the ``on_reset`` / ``on_step`` observers.  This module sits below everything that acts in an env: it imports
only numpy and Gymnasium.

``envs`` is a list of environments stepped in this process, or one Gymnasium vector env (e.g.
``AsyncVectorEnv``: one process each) with at least as many sub-envs as episodes.  Episode ``i`` resets
with ``seeds[i]``; the ``act`` callable sees the observations of the episodes still running, so a batched
policy acts on all of them in one call.  A policy that acts from the simulator state (a scripted
demonstrator) ignores the observations, builds itself in ``on_reset`` and ends its episode when its
script is done by answering :data:`STOP` instead of an action.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np

# act(observations, live, steps) -> actions: ``observations`` of the episodes still running (indices ``live``
# into the batch), ``steps[i]`` the number of steps episode ``live[i]`` has taken; one action per live episode,
# or STOP for an episode that ends here
Act = Callable[[list, np.ndarray, np.ndarray], Any]


class _Stop:
    def __repr__(self) -> str:
        return "STOP"


STOP = _Stop()  # act's answer for an episode that ends before this step, without stepping


@dataclass
class Step:
    """One transition of episode ``episode`` (its index in the batch), as an ``on_step`` observer sees it."""

    episode: int
    t: int  # the step's index in its episode: 0 for the first action
    obs: Any
    action: np.ndarray
    reward: float
    terminated: bool
    truncated: bool
    info: dict
    next_obs: Any

    @property
    def done(self) -> bool:
        return bool(self.terminated or self.truncated)


@dataclass
class Episode:
    """The outcome of one episode: the return (a float64 sum of the rewards), the number of steps, whether any
    step's ``info["success"]`` was true, how it ended, and the last step's info."""

    seed: int | None
    ret: float = 0.0
    length: int = 0
    success: bool = False
    terminated: bool = False
    truncated: bool = False
    info: dict = field(default_factory=dict)


def rollout(
    envs: Sequence[gym.Env] | gym.vector.VectorEnv,
    act: Act,
    seeds: Sequence[int | None],
    *,
    max_steps: int | None = None,
    on_reset: Callable[[int, Any, dict], None] | None = None,
    on_step: Callable[[Step], None] | None = None,
) -> list[Episode]:
    """Run one episode in each of the first ``len(seeds)`` envs until each terminates or truncates (or has
    taken ``max_steps`` steps: then it counts as truncated).  ``on_reset(i, obs, info)`` is called after
    episode ``i`` resets, ``on_step(step)`` after each of its steps; both in episode order within a step.

    ``act`` may answer :data:`STOP` in place of an episode's action: that episode ends there, before the
    step and without taking it (nothing reaches ``on_step``); it counts as truncated (it was cut short, not
    terminal), its length is the steps it took and its ``info`` its last step's (``{}`` if it took none)."""
    n = len(seeds)
    batch = _Vector(envs, n) if isinstance(envs, gym.vector.VectorEnv) else _Envs(envs, n)
    obs, infos = batch.reset(list(seeds))
    episodes = [Episode(seed=s) for s in seeds]
    if on_reset is not None:
        for i in range(n):
            on_reset(i, obs[i], infos[i])
    done = np.zeros(n, bool)
    steps = np.zeros(n, np.int64)
    while not done.all():
        live = np.flatnonzero(~done)
        actions = act([obs[i] for i in live], live, steps[live])
        stop = np.array([a is STOP for a in actions], bool)
        if stop.any():
            for i in live[stop]:
                episodes[i].truncated = done[i] = True
            live, actions = live[~stop], [a for a, s in zip(actions, stop) if not s]
            if not len(live):
                continue
        for i, (next_obs, reward, term, trunc, info), action in zip(live, batch.step(live, actions), actions):
            ep = episodes[i]
            ep.ret += float(reward)
            ep.length += 1
            ep.success |= bool(info.get("success", False))
            trunc = bool(trunc) or (max_steps is not None and ep.length >= max_steps and not term)
            ep.terminated, ep.truncated, done[i] = bool(term), trunc, bool(term) or trunc
            ep.info = info
            if on_step is not None:
                on_step(Step(int(i), int(steps[i]), obs[i], action, reward, bool(term), trunc, info, next_obs))
            obs[i] = next_obs
            steps[i] += 1
    return episodes


class _Envs:
    """Envs stepped one after another in this process."""

    def __init__(self, envs: Sequence[gym.Env], n: int):
        if len(envs) < n:
            raise ValueError(f"{n} episodes need {n} envs, got {len(envs)}")
        self.envs = envs

    def reset(self, seeds):
        out = [self.envs[i].reset(seed=s) for i, s in enumerate(seeds)]
        return [o for o, _ in out], [info for _, info in out]

    def step(self, live, actions):
        return [self.envs[i].step(a) for i, a in zip(live, actions)]


class _Vector:
    """A Gymnasium vector env: every sub-env steps at once; those without a live episode get zero actions and
    their results are dropped (their episodes are reset, with seeds of their own, before the next rollout)."""

    PAD_SEED = 10**6  # the sub-envs beyond the episodes reset with max(seeds) + PAD_SEED + i

    def __init__(self, vec: gym.vector.VectorEnv, n: int):
        if vec.num_envs < n:
            raise ValueError(f"{n} episodes need {n} envs, got a vector env of {vec.num_envs}")
        self.vec, self.n = vec, n

    def reset(self, seeds):
        known = [s for s in seeds if s is not None]
        pad = [(max(known) if known else 0) + self.PAD_SEED + i for i in range(self.vec.num_envs - len(seeds))]
        obs, info = self.vec.reset(seed=list(seeds) + pad)
        return [_item(obs, i) for i in range(self.n)], [_info_item(info, i) for i in range(self.n)]

    def step(self, live, actions):
        actions = np.asarray(actions)
        full = np.zeros((self.vec.num_envs,) + actions.shape[1:], np.float32)
        full[live] = actions
        obs, reward, term, trunc, info = self.vec.step(full)
        return [(_item(obs, j), reward[j], term[j], trunc[j], _info_item(info, j)) for j in live]


def _item(batched, j: int):
    """Sub-env ``j``'s part of a batched observation (an array or a dict of arrays)."""
    if isinstance(batched, dict):
        return {k: _item(v, j) for k, v in batched.items()}
    return batched[j]


def _info_item(info: dict, j: int) -> dict:
    """Sub-env ``j``'s part of a vector env's info: the keys its ``_key`` mask marks as set for ``j``."""
    out = {}
    for k, v in info.items():
        if k.startswith("_"):
            continue
        mask = info.get(f"_{k}")
        if mask is not None and not mask[j]:
            continue
        out[k] = _info_item(v, j) if isinstance(v, dict) else v[j]
    return out
