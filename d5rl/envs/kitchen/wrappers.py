"""Frame stacking for image observations (the paper stacks the last 3 frames per camera)."""

from __future__ import annotations

import collections

import gymnasium as gym
import numpy as np
from gymnasium import spaces


class FrameStack(gym.ObservationWrapper):
    """Stack the last ``num_stack`` frames of every image key along the channel axis.

    ``pixels/<cam>`` of shape (H, W, C) becomes (H, W, C * num_stack), oldest frame first;
    other keys (``proprio``) are passed through.  After reset the first frame is repeated.
    """

    def __init__(self, env: gym.Env, num_stack: int = 3, prefix: str = "pixels/"):
        super().__init__(env)
        if not isinstance(env.observation_space, spaces.Dict):
            raise TypeError("FrameStack needs dict observations (obs_mode='pixels')")
        self.num_stack = int(num_stack)
        self.keys = [k for k in env.observation_space.spaces if k.startswith(prefix)]
        new = dict(env.observation_space.spaces)
        for k in self.keys:
            s = env.observation_space[k]
            h, w, c = s.shape
            new[k] = spaces.Box(0, 255, shape=(h, w, c * self.num_stack), dtype=s.dtype)
        self.observation_space = spaces.Dict(new)
        self._frames = {k: collections.deque(maxlen=self.num_stack) for k in self.keys}

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        for k in self.keys:
            self._frames[k].clear()
            self._frames[k].extend([obs[k]] * self.num_stack)
        return self.observation(obs), info

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        for k in self.keys:
            self._frames[k].append(obs[k])
        return self.observation(obs), reward, terminated, truncated, info

    def observation(self, observation):
        out = dict(observation)
        for k in self.keys:
            out[k] = np.concatenate(list(self._frames[k]), axis=-1)
        return out
