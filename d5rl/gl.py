"""The GL backend MuJoCo renders with, chosen before MuJoCo is imported.

d5rl's environments render offscreen: on Linux, ``MUJOCO_GL`` defaults to ``egl`` here, before
any family imports MuJoCo (which reads it once, at import; :mod:`d5rl.envs` imports this module first).
A value you set yourself is kept; ``osmesa`` also works.

MuJoCo's import fails outright for a ``MUJOCO_GL`` it does not know, and may for a backend whose
library is missing.  Most of d5rl never renders (``d5rl list``, state tasks, training on states), so
such a setting turns rendering off here instead (``MUJOCO_GL=disable``), and :data:`GL_PROBLEM` says
why; :func:`d5rl.rendering.make_renderer` reports it as the one-line error when something renders.
"""

import ctypes
import ctypes.util
import os
import sys

# MuJoCo's accepted values (mujoco/rendering/classic/gl_context.py) and the library each backend loads.
_OFF = ("disable", "disabled", "off", "false", "0")
_VALID = ("enable", "enabled", "on", "true", "1", "glfw", "") + (
    ("glx", "egl", "osmesa") if sys.platform.startswith("linux") else ("wgl", "cgl")
)
_LIBRARY = {
    "egl": ("EGL", ("libEGL.so.1", "libEGL.so")),
    "osmesa": ("OSMesa", ("libOSMesa.so.8", "libOSMesa.so.6", "libOSMesa.so")),
}


def _loadable(name: str, files: tuple[str, ...]) -> bool:
    for f in files:  # what the backend will load anyway; faster than asking ldconfig
        try:
            ctypes.CDLL(f)
            return True
        except OSError:
            pass
    return ctypes.util.find_library(name) is not None


def gl_problem(value: str, loadable=_loadable) -> str | None:
    """Why MuJoCo cannot render with ``MUJOCO_GL=value`` (None when it may)."""
    v = value.lower().strip()
    if v in _OFF:
        return None
    if v not in _VALID:
        return f"MUJOCO_GL={value!r} is not one of MuJoCo's backends {[b for b in _VALID if b]}"
    lib = _LIBRARY.get(v)
    if lib is not None and sys.platform.startswith("linux") and not loadable(*lib):
        return f"MUJOCO_GL={value} needs lib{lib[0]}, which is not installed"
    return None


GL_PROBLEM: str | None = None
if sys.platform.startswith("linux"):
    os.environ.setdefault("MUJOCO_GL", "egl")
if "mujoco" not in sys.modules and os.environ.get("MUJOCO_GL") is not None:
    GL_PROBLEM = gl_problem(os.environ["MUJOCO_GL"])
    if GL_PROBLEM is not None:
        os.environ["MUJOCO_GL"] = "disable"
        os.environ["D5RL_GL_PROBLEM"] = GL_PROBLEM  # worker processes inherit the reason with the setting
    elif os.environ["MUJOCO_GL"] == "disable":
        GL_PROBLEM = os.environ.get("D5RL_GL_PROBLEM")
