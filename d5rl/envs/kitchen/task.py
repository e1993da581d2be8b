"""The standard Franka Kitchen tasks with camera observations.

Description
    A 9-DoF Franka Panda in the relay-policy-learning kitchen (Gupta et al., 2019) must put
    four objects into their goal configurations.  ``mixed``: microwave, kettle, light switch,
    slide cabinet.  ``partial``: microwave, kettle, bottom burner, light switch (never all
    together in one dataset episode).  Any other set of the seven subtasks can be passed as
    ``tasks=``.

Action space
    ``Box(-1, 1, (9,), float32)``: joint velocities of the 7 arm joints and the 2 fingers,
    scaled so that 1 means 2 rad/s (2 m/s for the fingers), as in D4RL.  Each 0.08 s control
    step (40 physics steps of 2 ms) sets the position actuators' targets to
    ``qpos + 2 * action * 0.08`` clipped to the actuator ranges.  (D4RL integrated from a
    *noisy* joint reading; we use the true one so the environment stays Markov.)

Observation space
    ``obs_mode="pixels"`` (default): a dict with ``pixels/overview`` and ``pixels/wrist``,
    uint8 ``(S, S, 3)`` images (``image_size`` S = 64 by default, 128 selectable) and
    ``proprio``: the 9 robot joint positions (float32).
    ``obs_mode="state"``: float32 ``(30,)``, the 9 robot joint positions then the 21 object
    joint positions (4 knobs, 4 burners, switch, light, slide door, 2 hinge doors,
    microwave door, kettle position and quaternion).
    Wrap with :class:`d5rl.envs.wrappers.FrameStack` for the paper's 3 stacked frames.

Reward
    Each step: the number of target objects currently in their goal configuration (joint
    distance to the goal < 0.3), so 0..4 per step.  ``info["completed"]`` holds a bool per
    subtask (all seven, order :data:`SUBTASK_NAMES`), ``info["solved"]`` the target subtasks
    solved at any step so far and ``info["score"]`` the normalized score: the fraction of the
    four target subtasks solved so far (1.0 = all four).  ``info["episode_stats"]`` has
    ``subtask/<name>`` (spaces as ``_``) for all seven subtasks: 1.0 once that subtask's object
    has been in its goal configuration at any step of the episode, targets or not; evaluation
    averages them over episodes (which subtasks an agent does, not only how many count).

Start state
    The kitchen's rest pose (doors closed, knobs off, kettle on the bottom-left burner) with
    uniform noise of +-0.02 rad on the 7 arm joints (seeded through ``reset(seed=...)``).

Episode end
    No termination; truncated after 280 steps (22.4 s) by the registered TimeLimit.

Version history
    v0: first release.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import mujoco
import numpy as np
from gymnasium import spaces

from d5rl.envs.base import MujocoEnv
from d5rl.envs.kitchen import model as km
from d5rl.envs.kitchen.subtasks import MIXED, SUBTASK_NAMES, SUBTASKS, CompletionChecker
from d5rl.errors import D5RLError

FRAME_SKIP = 40  # 40 x 2 ms = 0.08 s control step
ACTION_SCALE = 2.0  # rad/s (m/s for fingers) at |action| = 1
CAMERAS = ("overview", "wrist")
OBS_MODES = ("pixels", "state")
JOINTS = km.NUM_ROBOT_QPOS + km.NUM_OBJECT_QPOS  # the state observation: 9 robot and 21 object joint positions
SUBTASK_STAT_KEYS = tuple(f"subtask/{n.replace(' ', '_')}" for n in SUBTASK_NAMES)  # info["episode_stats"] keys


def state_observations(qpos: np.ndarray) -> np.ndarray:
    """The ``obs_mode="state"`` observation of each row of ``qpos`` (T, >= 30): float32 (T, 30)."""
    return np.asarray(qpos)[:, :JOINTS].astype(np.float32)


class KitchenEnv(MujocoEnv):
    """Standard Franka Kitchen (see the module docstring)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 12}

    def __init__(
        self,
        tasks: Sequence[str] = MIXED,
        obs_mode: str = "pixels",
        image_size: int = 64,
        cameras: Sequence[str] = CAMERAS,
        init_noise: float = 0.02,
        render_mode: str | None = None,
        render_size: tuple[int, int] = (240, 320),
        scene_options: km.SceneOptions | None = None,
        model: mujoco.MjModel | None = None,
        width: int | None = None,
        height: int | None = None,
    ):
        unknown = [t for t in tasks if t not in SUBTASKS]
        if unknown:
            raise D5RLError(f"unknown kitchen subtasks {unknown}", f"choose from {list(SUBTASK_NAMES)}")
        if obs_mode not in OBS_MODES:
            raise D5RLError(f"obs_mode must be one of {OBS_MODES}, got {obs_mode!r}", "use 'pixels' or 'state'")
        if model is None:
            model = km.build_model(scene_options or km.SceneOptions())
        super().__init__(
            model,
            FRAME_SKIP,
            render_mode=render_mode,
            render_size=render_size,
            render_camera="overview",
            width=width,
            height=height,
        )
        self.tasks = tuple(tasks)
        self.obs_mode = obs_mode
        self.image_size = int(image_size)
        self.cameras = tuple(cameras)
        self.init_noise = float(init_noise)
        self.checker = CompletionChecker(model)
        self._task_cols = np.array([SUBTASK_NAMES.index(t) for t in self.tasks])
        self._ctrl_lo = model.actuator_ctrlrange[:, 0].copy()
        self._ctrl_hi = model.actuator_ctrlrange[:, 1].copy()
        self._solved = np.zeros(len(self.tasks), dtype=bool)
        self._reached = np.zeros(len(SUBTASK_NAMES), dtype=bool)

        self.action_space = spaces.Box(-1.0, 1.0, shape=(model.nu,), dtype=np.float32)
        proprio = spaces.Box(-np.inf, np.inf, shape=(km.NUM_ROBOT_QPOS,), dtype=np.float32)
        if obs_mode == "pixels":
            img = spaces.Box(0, 255, shape=(self.image_size, self.image_size, 3), dtype=np.uint8)
            self.observation_space = spaces.Dict({**{f"pixels/{c}": img for c in self.cameras}, "proprio": proprio})
        else:
            self.observation_space = spaces.Box(-np.inf, np.inf, shape=(JOINTS,), dtype=np.float32)

    # --- observations -------------------------------------------------------------------------
    def render_cameras(self, size: int | None = None, cameras: Sequence[str] | None = None) -> dict[str, np.ndarray]:
        """Images of the current state: ``{camera: uint8 (size, size, 3)}``."""
        size = self.image_size if size is None else int(size)
        return {c: self.render_camera_image(c, size, size) for c in (cameras or self.cameras)}

    def _get_obs(self):
        qpos = self.data.qpos
        if self.obs_mode == "state":
            return state_observations(qpos[None])[0]
        obs = {f"pixels/{c}": img for c, img in self.render_cameras().items()}
        obs["proprio"] = qpos[: km.NUM_ROBOT_QPOS].astype(np.float32)
        return obs

    def completed(self) -> np.ndarray:
        """Bool (7,): which subtasks' objects are in their goal configuration now."""
        return self.checker.completed(self.data.qpos)

    def _info(self, completed: np.ndarray) -> dict[str, Any]:
        return {
            "completed": completed,
            "solved": self._solved.copy(),
            "score": float(self._solved.mean()),
            "success": bool(self._solved.all()),
            "episode_stats": {k: float(r) for k, r in zip(SUBTASK_STAT_KEYS, self._reached)},
        }

    def _begin_episode(self, completed: np.ndarray) -> None:
        """What counts as done from the first state on (nothing, from the kitchen's rest pose)."""
        self._solved = completed[self._task_cols].copy()
        self._reached = completed.copy()

    # --- gymnasium API ------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        mujoco.mj_resetData(self.model, self.data)
        qpos = km.INIT_QPOS.copy()
        qpos[:7] += self.np_random.uniform(-self.init_noise, self.init_noise, size=7)
        self.data.qpos[:] = qpos
        self.data.ctrl[:] = np.clip(qpos[: self.model.nu], self._ctrl_lo, self._ctrl_hi)
        mujoco.mj_forward(self.model, self.data)
        completed = self.completed()
        self._begin_episode(completed)
        return self._get_obs(), self._info(completed)

    def action_to_ctrl(self, action: np.ndarray) -> np.ndarray:
        """Position targets for a normalized joint-velocity action."""
        a = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
        target = self.data.qpos[: self.model.nu] + ACTION_SCALE * a * self.dt
        return np.clip(target, self._ctrl_lo, self._ctrl_hi)

    def step(self, action):
        action = self.check_action(action)
        self.do_simulation(self.action_to_ctrl(action))
        completed = self.completed()
        in_goal = completed[self._task_cols]
        self._solved |= in_goal
        self._reached |= completed
        reward = float(in_goal.sum())
        return self._get_obs(), reward, False, False, self._info(completed)
