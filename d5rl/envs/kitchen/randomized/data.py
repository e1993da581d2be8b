"""A randomized-kitchen dataset episode seen through the simulator: camera frames of its stored states in
its stored domain.  The randomized kitchen datasets' derived caches
(:func:`d5rl.production.kitchen.randomized.data.renders`) are made of this function, whose "module:function"
name is in every cache's records.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from d5rl.envs.kitchen.randomized.domain import Domain
from d5rl.envs.kitchen.randomized.task import CAMERAS, RandomizedKitchenEnv

# --- rendering stored states with their domains -------------------------------------------------
_RENDER_ENV = {}


def render_episode(arrays: dict, meta: dict, cameras: Sequence[str] = CAMERAS, size: int = 128) -> dict:
    """``observations/pixels/<camera>`` of a stored episode, in its stored domain."""
    size = int(size)
    if size not in _RENDER_ENV:
        _RENDER_ENV[size] = RandomizedKitchenEnv(image_size=size)
    env = _RENDER_ENV[size]
    env.set_domain(Domain.from_json(meta["domain"]))
    states = np.asarray(arrays["states"], dtype=np.float64)
    out = {c: np.empty((len(states), size, size, 3), np.uint8) for c in cameras}
    for i, s in enumerate(states):
        env.set_state(s)
        for c in cameras:
            out[c][i] = env.render_camera_image(c, size, size)
    return {f"observations/pixels/{c}": v for c, v in out.items()}
