"""Headless rendering: pick a GL backend and make renderers with clear errors.

``MUJOCO_GL`` must be set before mujoco is imported; :mod:`d5rl.gl` defaults it
to ``egl`` on Linux (Mesa's llvmpipe works without a GPU).  ``osmesa`` is the fallback.
"""

from __future__ import annotations

import os

import mujoco
import numpy as np

from d5rl import gl
from d5rl.errors import RenderBackendError

_HINT = (
    "install a headless GL library (Debian/Ubuntu: `apt-get install libegl1 libgl1 libosmesa6`) "
    "and set MUJOCO_GL=egl or MUJOCO_GL=osmesa before importing d5rl"
)


def make_renderer(model: mujoco.MjModel, height: int, width: int) -> mujoco.Renderer:
    """A ``mujoco.Renderer`` whose offscreen buffer is grown to fit ``height x width``."""
    if gl.GL_PROBLEM is not None:
        raise RenderBackendError(f"cannot render: {gl.GL_PROBLEM}", _HINT)
    model.vis.global_.offheight = max(int(model.vis.global_.offheight), int(height))
    model.vis.global_.offwidth = max(int(model.vis.global_.offwidth), int(width))
    try:
        return mujoco.Renderer(model, height=int(height), width=int(width))
    except Exception as e:  # mujoco raises plain Exceptions / RuntimeErrors / AttributeErrors for GL
        backend = os.environ.get("MUJOCO_GL", "(unset)")
        raise RenderBackendError(f"cannot create an offscreen renderer with MUJOCO_GL={backend}: {e}", _HINT) from e


def sync_materials(renderer: mujoco.Renderer, model: mujoco.MjModel) -> None:
    """Copy ``model``'s material-to-texture assignment into ``renderer``'s GL context.

    ``mjr_makeContext`` copies ``mat_texid`` / ``mat_texrepeat`` / ``mat_texuniform`` into the context
    when the renderer is made and renders from that copy afterwards (MuJoCo has no upload call for
    them, unlike ``mjr_uploadTexture`` for texture pixels), so a model whose materials change textures
    after its renderer exists must be synced, or a reused renderer draws the old assignment.
    """
    ctx = renderer._mjr_context
    if ctx is None:  # closed
        return
    for name in ("mat_texid", "mat_texrepeat", "mat_texuniform"):
        src = np.asarray(getattr(model, name)).ravel()
        getattr(ctx, name)[: src.size] = src
