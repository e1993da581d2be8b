"""A small MuJoCo base env shared by every family.

It owns the model/data pair, the control step (``frame_skip`` physics steps), the
full simulator state used to store and replay datasets, and rendering.  Families
add the task: observation, reward, termination, initial state.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import mujoco
import numpy as np

from d5rl.errors import D5RLError, is_int
from d5rl.rendering import make_renderer

# What a dataset stores per step to replay or re-render exactly: time, qpos, qvel,
# actuator activations, warm-start accelerations, controls, applied forces, mocap.
STATE_SPEC = mujoco.mjtState.mjSTATE_INTEGRATION


def qpos_of_states(states: np.ndarray, nq: int) -> np.ndarray:
    """The first ``nq`` joint positions of stored states (rows of :data:`STATE_SPEC`: time, then qpos, ...),
    read without a model."""
    return np.asarray(states)[:, 1 : 1 + nq]


class ResetNeededError(D5RLError, gym.error.ResetNeeded):
    """``step`` was called before the first ``reset``."""


class ActionError(D5RLError, ValueError):
    """An action of the wrong shape, or with NaN or infinite entries."""


def frame_size(render_size: tuple[int, int], width: int | None = None, height: int | None = None) -> tuple[int, int]:
    """``(height, width)`` of ``render()``'s frames: ``render_size``, with Gymnasium's ``width`` / ``height``
    keywords (as its MuJoCo envs take them) overriding either side."""
    size = (int(height) if height is not None else render_size[0], int(width) if width is not None else render_size[1])
    for name, v in (("height", height), ("width", width)):
        if v is not None and not is_int(v, lo=1, hi=8192):
            raise ValueError(f"{name} must be a number of pixels from 1 to 8192, got {v!r}")
    return size


class MujocoEnv(gym.Env):
    """Base class: physics, state save/restore, rendering.  Subclasses define the task.

    Every family's ``step`` starts with :meth:`check_action`: stepping before ``reset`` raises
    :class:`ResetNeededError`, an action of the wrong shape or with a NaN/inf entry raises
    :class:`ActionError` (nothing is simulated), and finite values outside ``[-1, 1]`` are clipped.
    """

    _was_reset = False

    metadata = {"render_modes": ["rgb_array"], "render_fps": 20}

    def __init__(
        self,
        model: mujoco.MjModel,
        frame_skip: int,
        render_mode: str | None = None,
        render_size: tuple[int, int] = (240, 320),
        render_camera: str | int = -1,
        width: int | None = None,
        height: int | None = None,
    ):
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']}, got {render_mode!r}")
        render_size = frame_size(render_size, width, height)
        self.model = model
        self.data = mujoco.MjData(model)
        self.frame_skip = int(frame_skip)
        self.render_mode = render_mode
        self.render_size = tuple(render_size)
        self.render_camera = render_camera
        self._renderers: dict[tuple[int, int], mujoco.Renderer] = {}
        self.metadata = {**self.metadata, "render_fps": int(round(1.0 / self.dt))}

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed, options=options)
        self._was_reset = True

    def check_action(self, action) -> np.ndarray:
        """``action`` as float64, clipped to ``[-1, 1]``, after checking that it can be applied."""
        if not self._was_reset:
            raise ResetNeededError(
                f"{type(self).__name__}.step() was called before reset()", "call env.reset(seed=...) first"
            )
        shape = self.action_space.shape
        if np.iscomplexobj(action):  # numpy would drop the imaginary parts with only a warning
            raise ActionError(
                f"action has complex values: {np.asarray(action).tolist()}", f"pass a real float array of shape {shape}"
            )
        try:
            a = np.asarray(action, dtype=np.float64)
        except (TypeError, ValueError):
            raise ActionError(f"action {action!r} is not numeric", f"pass a float array of shape {shape}") from None
        if a.shape != shape:
            raise ActionError(f"action must have shape {shape}, got {a.shape}", f"pass a float array of shape {shape}")
        if not np.isfinite(a).all():
            bad = np.flatnonzero(~np.isfinite(a)).tolist()
            raise ActionError(
                f"action has NaN or infinite entries at {bad}: {a.tolist()}",
                "check the policy's outputs (a diverged network gives NaN); actions must be finite",
            )
        return np.clip(a, self.action_space.low, self.action_space.high)

    # --- physics -----------------------------------------------------------------
    @property
    def dt(self) -> float:
        """Control step in seconds."""
        return self.model.opt.timestep * self.frame_skip

    def do_simulation(self, ctrl: np.ndarray | None = None, n_steps: int | None = None) -> None:
        if ctrl is not None:
            self.data.ctrl[:] = ctrl
        mujoco.mj_step(self.model, self.data, nstep=self.frame_skip if n_steps is None else n_steps)
        # mj_step leaves position-dependent quantities (xpos, site and camera poses) one substep
        # behind qpos; recompute them so rewards, observations and renders agree with the stored
        # state (replaying a state with set_state gives exactly these values).
        mujoco.mj_forward(self.model, self.data)

    @property
    def state_size(self) -> int:
        return mujoco.mj_stateSize(self.model, STATE_SPEC)

    def get_state(self) -> np.ndarray:
        """Full integration state (float64) – enough to replay or re-render this step."""
        out = np.empty(self.state_size, dtype=np.float64)
        mujoco.mj_getState(self.model, self.data, out, STATE_SPEC)
        return out

    def set_state(self, state: np.ndarray) -> None:
        """Restore a state from :meth:`get_state` and recompute derived quantities."""
        state = np.asarray(state, dtype=np.float64)
        if state.shape != (self.state_size,):
            raise ValueError(f"state must have shape ({self.state_size},), got {state.shape}")
        mujoco.mj_setState(self.model, self.data, state, STATE_SPEC)
        mujoco.mj_forward(self.model, self.data)

    # --- rendering ---------------------------------------------------------------
    def renderer(self, height: int, width: int) -> mujoco.Renderer:
        key = (int(height), int(width))
        if key not in self._renderers:
            self._renderers[key] = make_renderer(self.model, *key)
        return self._renderers[key]

    def render_camera_image(self, camera: str | int, height: int, width: int, scene_option: Any = None) -> np.ndarray:
        r = self.renderer(height, width)
        r.update_scene(self.data, camera=camera, scene_option=scene_option)
        return r.render()

    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() called without render_mode; pass render_mode='rgb_array'")
            return None
        return self.render_camera_image(self.render_camera, *self.render_size)

    def __getstate__(self) -> dict:
        """Pickling and ``copy.deepcopy`` leave the renderers out (a GL context cannot be copied); the copy
        makes its own on its first render."""
        return {**self.__dict__, "_renderers": {}}

    def close(self) -> None:
        for r in self._renderers.values():
            r.close()
        self._renderers.clear()
