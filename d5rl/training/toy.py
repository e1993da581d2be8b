"""A tiny continuous-control task in pure numpy, for tests and smoke runs.

``toy-reach-v0``: a point in the plane starts near (-0.5, -0.5) and must move to
the goal (0.5, 0.5).  Action: a velocity in [-1, 1]², position += 0.1·action
(clipped to [-1, 1]²).  Observation: (x, y, goal_x − x, goal_y − y).  Reward:
``1 − distance to goal / 2`` in [0, 1] minus 0.1 · ‖action‖²/2 (a small energy cost), so
a policy that walks straight to the goal and stops scores ≈ 0.9 per step.  Episodes
last 25 steps (time limit, no terminal).  ``toy-reach-pixels-v0`` adds a 2-camera
16×16 RGB rendering of the position under ``pixels/<camera>`` next to ``proprio``.

Datasets (:func:`toy_dataset`) mix an expert (straight to the goal, Gaussian
noise) with a random policy; normalized scores use the random and expert returns.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from d5rl.datasets.episode import Episode

TOY_TASKS = ("toy-reach-v0", "toy-reach-pixels-v0")
GOAL = np.array([0.5, 0.5], np.float32)
HORIZON = 25
IMG = 16
CAMERAS = ("front", "side")


class ToyReachEnv(gym.Env):
    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(self, pixels: bool = False, render_mode: str | None = None):
        self.pixels = pixels
        self.render_mode = render_mode
        self.action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
        state_space = gym.spaces.Box(-2.0, 2.0, (4,), np.float32)
        if pixels:
            self.observation_space = gym.spaces.Dict({
                **{f"pixels/{c}": gym.spaces.Box(0, 255, (IMG, IMG, 3), np.uint8) for c in CAMERAS},
                "proprio": gym.spaces.Box(-1.0, 1.0, (2,), np.float32),
            })
        else:
            self.observation_space = state_space
        self.pos = np.zeros(2, np.float32)
        self.t = 0

    def _image(self, flip: bool) -> np.ndarray:
        img = np.zeros((IMG, IMG, 3), np.uint8)
        def cell(p):
            return np.clip(((p + 1) / 2 * (IMG - 1)).round().astype(int), 0, IMG - 1)
        gx, gy = cell(GOAL)
        px, py = cell(self.pos)
        if flip:
            gx, gy, px, py = gy, gx, py, px
        img[gy, gx, 1] = 255
        img[py, px, 0] = 255
        img[..., 2] = 40
        return img

    def _obs(self):
        if self.pixels:
            return {"pixels/front": self._image(False), "pixels/side": self._image(True),
                    "proprio": self.pos.copy()}
        return np.concatenate([self.pos, GOAL - self.pos]).astype(np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.pos = (np.array([-0.5, -0.5]) + self.np_random.uniform(-0.1, 0.1, 2)).astype(np.float32)
        self.t = 0
        return self._obs(), {}

    def step(self, action):
        a = np.clip(np.asarray(action, np.float32), -1, 1)
        self.pos = np.clip(self.pos + 0.1 * a, -1, 1).astype(np.float32)
        self.t += 1
        dist = float(np.linalg.norm(GOAL - self.pos))
        reward = 1.0 - dist / 2 - 0.1 * float(np.sum(a**2)) / 2
        return self._obs(), reward, False, self.t >= HORIZON, {"success": dist < 0.1}

    def render(self):
        return np.kron(self._image(False), np.ones((8, 8, 1), np.uint8))


def expert_action(pos: np.ndarray) -> np.ndarray:
    return np.clip((GOAL - pos) / 0.1, -1, 1).astype(np.float32)


def toy_episode(rng: np.random.Generator, expert_prob: float, noise: float, pixels: bool = False) -> Episode:
    """One episode from a policy that acts like the expert w.p. ``expert_prob`` per step, else randomly."""
    env = ToyReachEnv(pixels=pixels)
    obs, _ = env.reset(seed=int(rng.integers(2**31)))
    obs_list, acts, rews = [obs], [], []
    for _ in range(HORIZON):
        if rng.random() < expert_prob:
            a = np.clip(expert_action(env.pos) + noise * rng.standard_normal(2), -1, 1)
        else:
            a = rng.uniform(-1, 1, 2)
        obs, r, term, trunc, _ = env.step(a.astype(np.float32))
        obs_list.append(obs)
        acts.append(a)
        rews.append(r)
    arrays = {
        "actions": np.asarray(acts, np.float32), "rewards": np.asarray(rews, np.float32),
        "terminals": np.zeros(HORIZON, bool), "timeouts": np.eye(1, HORIZON, HORIZON - 1, dtype=bool)[0],
    }
    if pixels:
        for k in obs_list[0]:
            arrays[f"observations/{k}"] = np.stack([o[k] for o in obs_list])
    else:
        arrays["observations"] = np.stack(obs_list).astype(np.float32)
    return Episode(arrays, {"expert_prob": expert_prob})


def toy_dataset(num_episodes: int = 200, seed: int = 0, expert_prob: float = 0.3, noise: float = 0.3,
                pixels: bool = False):
    """A :class:`~d5rl.datasets.loading.Dataset` of ``num_episodes`` suboptimal episodes."""
    from d5rl.datasets.loading import Dataset

    rng = np.random.default_rng(seed)
    eps = [toy_episode(rng, expert_prob, noise, pixels) for _ in range(num_episodes)]
    return Dataset.from_episodes(eps, metadata={"task_id": "toy-reach-pixels-v0" if pixels else "toy-reach-v0"})


def _reference_returns() -> tuple[float, float]:
    """(random, expert) mean returns over 20 seeded episodes each."""
    out = []
    for prob in (0.0, 1.0):
        rng = np.random.default_rng(123)
        rets = [toy_episode(rng, prob, 0.0).arrays["rewards"].sum() for _ in range(20)]
        out.append(float(np.mean(rets)))
    return out[0], out[1]


_REF: tuple[float, float] | None = None


def toy_normalize_score(raw_return):
    global _REF
    if _REF is None:
        _REF = _reference_returns()
    lo, hi = _REF
    return (np.asarray(raw_return, np.float64) - lo) / (hi - lo)
