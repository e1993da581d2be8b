"""A kitchen dataset episode seen through the simulator: camera frames and state observations of its stored
states (the standard and the randomized kitchen's state observations alike).  Datasets store no camera
images; the kitchen datasets' derived caches (:func:`d5rl.production.kitchen.data.renders`) are made of
these functions, whose "module:function" names are in every cache's records.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from d5rl.envs.base import qpos_of_states
from d5rl.envs.kitchen.task import CAMERAS, JOINTS, KitchenEnv, state_observations

# --- rendering stored states ----------------------------------------------------------------------
_RENDER_ENV = {}


def _render_env(size: int):
    if size not in _RENDER_ENV:
        _RENDER_ENV[size] = KitchenEnv(obs_mode="pixels", image_size=size)
    return _RENDER_ENV[size]


def render_states(env, states: np.ndarray, cameras: Sequence[str] = CAMERAS, size: int = 64):
    """``{camera: uint8 (N, size, size, 3)}`` for stored simulator states (one row per state)."""
    states = np.asarray(states, dtype=np.float64)
    out = {c: np.empty((len(states), size, size, 3), np.uint8) for c in cameras}
    for i, s in enumerate(states):
        env.set_state(s)
        for c in cameras:
            out[c][i] = env.render_camera_image(c, size, size)
    return out


def state_episode(arrays: dict, meta: dict) -> dict:
    """``observations``: the ``obs_mode="state"`` observation (30 joint positions) of every stored state,
    read from the states without simulating (the standard and the randomized kitchen alike)."""
    return {"observations": state_observations(qpos_of_states(arrays["states"], JOINTS))}


def render_episode(arrays: dict, meta: dict, cameras: Sequence[str] = CAMERAS, size: int = 64) -> dict:
    """Derived arrays of one stored episode: ``observations/pixels/<camera>``."""
    frames = render_states(_render_env(int(size)), arrays["states"], cameras, int(size))
    return {f"observations/pixels/{c}": v for c, v in frames.items()}
