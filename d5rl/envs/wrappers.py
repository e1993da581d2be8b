"""Frame stacking for camera observations (the paper stacks the last 3 frames per camera)."""

from __future__ import annotations

import collections

import gymnasium as gym
import numpy as np


class FrameStack(gym.Wrapper):
    """Stack the last ``k`` frames of every ``pixels*`` key on the channel axis (oldest first);
    other keys (``proprio``) pass through.

    ``pixels/<cam>`` of shape (H, W, C) becomes (H, W, C·k).  After a reset the first frame is
    repeated, matching ``Dataset.sample(frame_stack=k)``, which clamps at the episode's first step.
    """

    def __init__(self, env: gym.Env, k: int = 3):
        super().__init__(env)
        if not isinstance(env.observation_space, gym.spaces.Dict):
            raise TypeError("FrameStack needs dict observations (a camera task, not its -state twin)")
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
