"""Tiny tasks whose datasets store simulator states, for the browse page's frame sources.

``test-browseenv-v0``: no derived cache; frames come from replaying states in the env
(``set_state`` + ``render``).  ``test-browsecam-v0``: a camera task whose ``DatasetSpec.derived``
builds a render cache with :func:`render_episode` (the family per-episode renderer convention).
A frame is filled with ``10 * state[0]`` (red), ``index`` (green), so tests can check which
state and episode a tile shows.
"""

import gymnasium as gym
import numpy as np

from d5rl.datasets.episode import Episode
from d5rl.registry import DatasetSpec, TaskSpec, register

CALLS: list[int] = []  # episode ids render_episode was asked for (same process)


def frame(state, size=8) -> np.ndarray:
    img = np.zeros((size, size, 3), np.uint8)
    img[..., 0] = int(10 * state[0]) % 256
    img[..., 1] = int(state[1]) % 256
    return img


class StateEnv(gym.Env):
    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}
    observation_space = gym.spaces.Box(-np.inf, np.inf, (2,), np.float32)
    action_space = gym.spaces.Box(-1, 1, (3,), np.float32)

    def __init__(self, render_mode=None):
        self.render_mode = render_mode
        self.state = np.zeros(2)

    def set_state(self, state):
        self.state = np.asarray(state, np.float64)

    def render(self):
        return frame(self.state, 12)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        return self.state.astype(np.float32), {}

    def step(self, action):
        return self.state.astype(np.float32), 0.0, False, False, {}


class Generator:
    version = "1"

    def __init__(self, task_id):
        pass

    def episode(self, index, rng):
        t = 6 + index % 3
        arrays = {
            "observations": rng.normal(size=(t + 1, 2)).astype(np.float32),
            "actions": rng.uniform(-1, 1, size=(t, 3)).astype(np.float32),
            "rewards": (np.arange(t) + index).astype(np.float32),
            "terminals": np.zeros(t, bool),
            "timeouts": np.eye(1, t, t - 1, dtype=bool)[0],
            "states": np.stack([np.arange(t + 1, dtype=np.float64), np.full(t + 1, float(index))], axis=1),
            "infos/completed": np.stack([np.arange(t) >= 2, np.arange(t) >= t - 1], axis=1),
            "infos/forward_speed": np.linspace(0, 1, t).astype(np.float32),
        }
        return Episode(arrays, {"id": index})


def render_episode(arrays, meta, size=8):
    CALLS.append(meta["id"])
    return {"observations/pixels/cam": np.stack([frame(s, size) for s in arrays["states"]])}


def renders(spec, root, manifest, *, episodes, workers=None, progress=True, size=8, render=True):
    if not render:
        return []
    from d5rl.datasets.render_cache import ensure_render_cache

    return [
        ensure_render_cache(
            root,
            manifest,
            "tests.browse.toy:render_episode",
            {"size": int(size)},
            name=f"cam-{size}",
            episodes=episodes,
            workers=workers,
            progress=progress,
        )
    ]


def _register(name, derived, observation):
    return register(
        TaskSpec(
            id=f"test-{name}-v0",
            entry_point="tests.browse.toy:StateEnv",
            max_episode_steps=10,
            description="browse test task",
            dataset=DatasetSpec(
                name=f"test-{name}",
                version=1,
                generator="tests.browse.toy:Generator",
                num_episodes=6,
                episodes_per_shard=3,
                derived=derived,
            ),
            observation=observation,
        )
    )


ENV_TASK = _register("browseenv", None, "state").id
CAM_TASK = _register("browsecam", "tests.browse.toy:renders", "pixels").id
