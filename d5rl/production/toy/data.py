"""The toy-reach datasets: episodes of a policy that acts like the expert with some probability per
step, else randomly; score references from the random and expert policies."""

from __future__ import annotations

import numpy as np

from d5rl.datasets.dataset import Dataset
from d5rl.datasets.episode import Episode
from d5rl.envs.toy.task import GOAL, HORIZON, ToyReachEnv
from d5rl.rollout import Step, rollout


def expert_action(pos: np.ndarray) -> np.ndarray:
    return np.clip((GOAL - pos) / 0.1, -1, 1).astype(np.float32)


def toy_episode(rng: np.random.Generator, expert_prob: float, noise: float, pixels: bool = False) -> Episode:
    """One episode from a policy that acts like the expert w.p. ``expert_prob`` per step, else randomly."""
    env = ToyReachEnv(pixels=pixels)
    obs_list, acts, rews = [], [], []

    def act(observations, live, steps) -> list:
        if rng.random() < expert_prob:
            a = np.clip(expert_action(env.pos) + noise * rng.standard_normal(2), -1, 1)
        else:
            a = rng.uniform(-1, 1, 2)
        return [a.astype(np.float32)]

    def on_step(step: Step) -> None:
        obs_list.append(step.next_obs)
        acts.append(step.action)
        rews.append(step.reward)

    rollout(
        [env],
        act,
        [int(rng.integers(2**31))],
        max_steps=HORIZON,
        on_reset=lambda i, obs, info: obs_list.append(obs),
        on_step=on_step,
    )
    arrays = {
        "actions": np.asarray(acts, np.float32),
        "rewards": np.asarray(rews, np.float32),
        "terminals": np.zeros(HORIZON, bool),
        "timeouts": np.eye(1, HORIZON, HORIZON - 1, dtype=bool)[0],
    }
    if pixels:
        for k in obs_list[0]:
            arrays[f"observations/{k}"] = np.stack([o[k] for o in obs_list])
    else:
        arrays["observations"] = np.stack(obs_list).astype(np.float32)
    return Episode(arrays, {"expert_prob": expert_prob})


def toy_dataset(
    num_episodes: int = 200, seed: int = 0, expert_prob: float = 0.3, noise: float = 0.3, pixels: bool = False
):
    """A :class:`~d5rl.datasets.dataset.Dataset` of ``num_episodes`` suboptimal episodes."""
    rng = np.random.default_rng(seed)
    eps = [toy_episode(rng, expert_prob, noise, pixels) for _ in range(num_episodes)]
    return Dataset.from_episodes(eps, metadata={"task_id": "toy-reach-pixels-v0" if pixels else "toy-reach-v0"})


class ToyGenerator:
    """Episode ``i``: :func:`toy_episode` with the dataset's expert probability and noise."""

    version = "1"
    name = "d5rl.envs.toy.data:ToyGenerator"  # in the manifests (the code's first home)

    def __init__(self, task_id: str, pixels: bool = False, expert_prob: float = 0.3, noise: float = 0.3):
        self.pixels, self.expert_prob, self.noise = pixels, expert_prob, noise

    def episode(self, index: int, rng: np.random.Generator) -> Episode:
        return toy_episode(rng, self.expert_prob, self.noise, self.pixels)


def reference_returns() -> tuple[float, float]:
    """(random, expert) mean returns over 20 seeded episodes each (the toy tasks' ScoreRef)."""
    out = []
    for prob in (0.0, 1.0):
        rng = np.random.default_rng(123)
        rets = [toy_episode(rng, prob, 0.0).arrays["rewards"].sum() for _ in range(20)]
        out.append(float(np.mean(rets)))
    return out[0], out[1]
