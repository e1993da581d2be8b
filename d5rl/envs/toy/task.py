"""``toy-reach``: a tiny continuous-control task in pure numpy, for tests and smoke runs.

A point in the plane starts near (-0.5, -0.5) and must move to the goal (0.5, 0.5).  Action: a
velocity in [-1, 1]², position += 0.1·action (clipped to [-1, 1]²).  Observation: (x, y,
goal_x − x, goal_y − y); the pixel variant has a 2-camera 16×16 RGB rendering of the position under
``pixels/<camera>`` next to ``proprio``.  Reward: ``1 − distance to goal / 2`` in [0, 1] minus
0.1 · ‖action‖²/2 (a small energy cost), so a policy that walks straight to the goal and stops
scores ≈ 0.9 per step.  Episodes last 25 steps (time limit, no terminal).  Success: within 0.1 of
the goal.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

GOAL = np.array([0.5, 0.5], np.float32)
HORIZON = 25
IMG = 16
CAMERAS = ("front", "side")


class ToyReachEnv(gym.Env):
    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(
        self,
        pixels: bool = False,
        render_mode: str | None = None,
        render_size: tuple[int, int] = (8 * IMG, 8 * IMG),
        width: int | None = None,
        height: int | None = None,
    ):
        from d5rl.envs.base import frame_size  # start-up time: the numpy toy does not load MuJoCo (base does)

        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']}, got {render_mode!r}")
        self.pixels = pixels
        self.render_mode = render_mode
        self.render_size = frame_size(render_size, width, height)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
        state_space = gym.spaces.Box(-2.0, 2.0, (4,), np.float32)
        if pixels:
            self.observation_space = gym.spaces.Dict(
                {
                    **{f"pixels/{c}": gym.spaces.Box(0, 255, (IMG, IMG, 3), np.uint8) for c in CAMERAS},
                    "proprio": gym.spaces.Box(-1.0, 1.0, (2,), np.float32),
                }
            )
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
            return {"pixels/front": self._image(False), "pixels/side": self._image(True), "proprio": self.pos.copy()}
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
        if self.render_mode is None:  # as every family and Gymnasium's own envs
            gym.logger.warn("render() called without render_mode; pass render_mode='rgb_array'")
            return None
        h, w = self.render_size  # the front camera's cells, scaled by nearest neighbour
        return self._image(False)[np.arange(h) * IMG // h][:, np.arange(w) * IMG // w]
