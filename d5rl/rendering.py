"""Headless rendering: pick a GL backend and make renderers with clear errors.

``MUJOCO_GL`` must be set before mujoco is imported; :mod:`d5rl.envs` defaults it
to ``egl`` on Linux (Mesa's llvmpipe works without a GPU).  ``osmesa`` is the fallback.
"""

from __future__ import annotations

import os

import d5rl.envs  # noqa: F401  (the MUJOCO_GL default, before mujoco is imported)
import mujoco  # noqa: E402

from d5rl.errors import RenderBackendError

_HINT = (
    "install a headless GL library (Debian/Ubuntu: `apt-get install libegl1 libgl1 libosmesa6`) "
    "and set MUJOCO_GL=egl or MUJOCO_GL=osmesa before importing d5rl"
)


def make_renderer(model: mujoco.MjModel, height: int, width: int) -> mujoco.Renderer:
    """A ``mujoco.Renderer`` whose offscreen buffer is grown to fit ``height x width``."""
    model.vis.global_.offheight = max(int(model.vis.global_.offheight), int(height))
    model.vis.global_.offwidth = max(int(model.vis.global_.offwidth), int(width))
    try:
        return mujoco.Renderer(model, height=int(height), width=int(width))
    except Exception as e:  # mujoco raises plain Exceptions / RuntimeErrors / AttributeErrors for GL
        backend = os.environ.get("MUJOCO_GL", "(unset)")
        raise RenderBackendError(f"cannot create an offscreen renderer with MUJOCO_GL={backend}: {e}", _HINT) from e
