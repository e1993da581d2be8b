"""A WidowX dataset episode seen through the simulator: camera frames and state observations of its stored
states (in its own domain, from ``meta``).  Datasets store no camera images; the WidowX datasets' derived
caches (:func:`d5rl.production.widowx.data.renders`) are made of these functions, whose "module:function"
names are in every cache's records.
"""

from __future__ import annotations

import functools

import mujoco
import numpy as np

from d5rl.envs.base import STATE_SPEC
from d5rl.envs.widowx import domain as wdom
from d5rl.envs.widowx import model as wm
from d5rl.envs.widowx.task import WidowXSortingEnv
from d5rl.rendering import make_renderer


@functools.lru_cache(maxsize=2)
def _render_context(size: int):
    model = wm.load_model()
    data = mujoco.MjData(model)
    return model, data, make_renderer(model, size, size)


def render_states(states: np.ndarray, meta: dict, size: int = 128, camera: str = "side") -> np.ndarray:
    """Camera frames ``uint8 (N, size, size, 3)`` for stored ``states`` of one episode (its ``meta``)."""
    model, data, renderer = _render_context(int(size))
    wdom.apply_domain(model, wdom.Domain.from_json(meta["domain"]))
    out = np.empty((len(states), size, size, 3), np.uint8)
    for i, s in enumerate(np.asarray(states, np.float64)):
        mujoco.mj_setState(model, data, s, STATE_SPEC)
        mujoco.mj_forward(model, data)
        renderer.update_scene(data, camera=camera)
        out[i] = renderer.render()
    return out


def render_episode(arrays: dict[str, np.ndarray], meta: dict, size: int = 128) -> dict[str, np.ndarray]:
    """The derived arrays of one stored episode: its side-camera frames."""
    return {"observations/pixels/side": render_states(arrays["states"], meta, size=int(size))}


_STATE_ENV = {}


def state_episode(arrays: dict[str, np.ndarray], meta: dict) -> dict[str, np.ndarray]:
    """``observations``: the ``obs_mode="state"`` vector (25) of every stored state, in its domain."""
    if "env" not in _STATE_ENV:
        _STATE_ENV["env"] = WidowXSortingEnv(obs_mode="state")
    env = _STATE_ENV["env"]
    env.set_domain(wdom.Domain.from_json(meta["domain"]))
    out = []
    for s in np.asarray(arrays["states"], np.float64):
        env.set_state(s)
        out.append(env.state_vector())
    return {"observations": np.asarray(out, np.float32)}
