"""WidowX 250 multi-stage bin sorting (``wx-sorting-v0``, ``wx-sorting-pickplacedata-v0``).

Description
    A WidowX 250 arm stands on a table in a room, with two identical bins: shoes go
    in the bin on the robot's left (+y), toys in the bin on its right (-y).  Each
    episode one shoe and one toy, drawn from a pool of five objects (three
    generated shoes, two ContactDB toys, each scaled so that it can be grasped
    whichever side it lies on), start at random positions and orientations in the
    central region between the bins.  Table, floor and wall textures and tints,
    object colours, the lights (position, colour, brightness, ambient) and a small
    camera pose jitter are drawn per episode from the env's seeded generator
    (:mod:`d5rl.envs.widowx.domain`).

Action space
    ``Box(-1, 1, (5,))``: end-effector position delta ``(dx, dy, dz)`` scaled by
    ``max_delta`` (3 cm per step), gripper yaw delta scaled by ``max_yaw_delta``
    (0.25 rad per step) and the gripper command (-1 open ... +1 closed, mapped
    linearly to the finger position targets).  The commanded pose is clipped to the
    workspace and converted to joint targets by analytic IK (gripper pointing
    down); joint position actuators track them (10 Hz control, 50 physics steps
    of 2 ms).

Observation space
    ``obs_mode="pixels"`` (default): ``Dict(pixels/side: uint8 (S, S, 3), proprio:
    float32 (8,))`` – one side camera (S = 128) and the joint positions (six arm
    joints, two fingers).  ``obs_mode="state"`` (debugging): ``float32 (25,)`` =
    joint positions (8), tip position (3), shoe position + quaternion (7), toy
    position + quaternion (7).

Reward
    The number of objects lying in their correct bin (0, 1 or 2) at each step.
    The normalized score of an episode is the fraction sorted at its end
    (final reward / 2), reported as ``info["score"]``.  ``info["episode_stats"]`` says, per
    object (``shoe/...``, ``toy/...``), whether it has ``lifted`` (its centre rose above
    :data:`LIFTED_Z` at some step of the episode) and whether it lies ``in_its_bin`` or
    ``in_other_bin`` now; evaluation averages the final values over episodes.

Start state
    The arm at a home pose above the table (±1.5 cm noise), gripper open; the
    objects dropped in uniformly random orientations (the paper's "random
    quaternion"; ``options={"upright": True}``: standing, random yaw), their lowest
    point 1 cm above the table, in x ∈ [0.22, 0.36], y ∈ [-0.07, 0.07] m, at least
    9 cm apart, then simulated until they are at rest (0.3–3 s): the first
    observation shows a settled scene.

Episode end
    No termination; the time limit is ``MAX_EPISODE_STEPS`` = 120 control steps
    (12 s).  The scripted policy needs 71 steps on average (91 at most in 500
    episodes) to attempt both objects, ~35 per pick-and-place.

Version history
    v0: initial release.  Revised in place with the datasets (dataset versions in
    CHANGELOG.md): dataset v1 dropped the objects in random orientations and let them
    settle; dataset v2 added the tabletop room, wall textures, light colours and
    ambient light to the per-episode variation, and rescaled the toys and the boot; dataset v3 made
    the room's floor, walls and table legs collide (before, an object thrown off the table fell forever).
"""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np

from d5rl.envs.base import MujocoEnv
from d5rl.envs.widowx import controller
from d5rl.envs.widowx import domain as wdom
from d5rl.envs.widowx import model as wm
from d5rl.envs.widowx import scene as wscene

FRAME_SKIP = 50  # 10 Hz control with 2 ms physics steps
HOME_POSE = np.array([0.22, 0.0, 0.18, math.pi / 2])
SETTLE_STEPS = 150  # at least 0.3 s of physics after dropping the objects
SETTLE_MAX_STEPS = 1500  # at most 3 s: objects are at rest well before (checked every SETTLE_STEPS)
REST_SPEED = 0.005  # m/s (and rad/s x 0.1 m): an object slower than this is at rest
DROP_HEIGHT = 0.01  # m between the table and the dropped object's lowest point
MIN_OBJECT_DISTANCE = 0.09
LIFTED_Z = 0.06  # m: an object whose centre rises this high has left the table (grasped, or thrown)


def sorted_count(model: mujoco.MjModel, data: mujoco.MjData, domain: wdom.Domain) -> tuple[int, dict[str, str | None]]:
    """How many of the episode's objects lie in their category's bin, and where each lies."""
    where: dict[str, str | None] = {}
    count = 0
    for name in domain.objects:
        pos = data.xipos[model.body(name).id]
        where[name] = next((b for b in wm.BIN_CENTERS if wscene.in_bin(pos, b)), None)
        count += int(where[name] == wm.CATEGORY[name])
    return count, where


class WidowXSortingEnv(MujocoEnv):
    __doc__ = __doc__

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(
        self,
        obs_mode: str = "pixels",
        image_size: int = 128,
        randomize: bool = True,
        max_delta: float = 0.03,
        max_yaw_delta: float = 0.25,
        render_mode: str | None = None,
        render_size: tuple[int, int] | None = None,
        width: int | None = None,
        height: int | None = None,
    ):
        if obs_mode not in ("pixels", "state"):
            raise ValueError(f"obs_mode must be 'pixels' or 'state', got {obs_mode!r}")
        model = wm.load_model()
        super().__init__(
            model,
            FRAME_SKIP,
            render_mode=render_mode,
            render_size=render_size or (image_size, image_size),
            render_camera="side",
            width=width,
            height=height,
        )
        self.obs_mode = obs_mode
        self.image_size = int(image_size)
        self.randomize = bool(randomize)
        self.max_delta = float(max_delta)
        self.max_yaw_delta = float(max_yaw_delta)
        self.index = wscene.SceneIndex(model)
        self.domain: wdom.Domain = wdom.sample_domain(np.random.default_rng(0), randomize=False)
        wdom.apply_domain(self.model, self.domain)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (5,), np.float32)
        proprio = gym.spaces.Box(-np.inf, np.inf, (8,), np.float32)
        if obs_mode == "pixels":
            self.observation_space = gym.spaces.Dict(
                {"pixels/side": gym.spaces.Box(0, 255, (image_size, image_size, 3), np.uint8), "proprio": proprio}
            )
        else:
            self.observation_space = gym.spaces.Box(-np.inf, np.inf, (25,), np.float32)

    # --- control -----------------------------------------------------------------
    def commanded_pose(self) -> np.ndarray:
        """``(x, y, z, yaw)`` the arm is being driven to (from the joint targets in ``ctrl``)."""
        return controller.fk(self.data.ctrl[self.index.arm_act])

    def measured_pose(self) -> np.ndarray:
        """``(x, y, z, yaw)`` of the arm's actual joint angles (assuming the gripper points down)."""
        return controller.fk(self.data.qpos[self.index.arm_qpos])

    def tip_position(self) -> np.ndarray:
        return self.data.site_xpos[self.index.tip_site].copy()

    def _set_targets(self, pose: np.ndarray, grip: float) -> None:
        pose = np.asarray(pose, dtype=np.float64).copy()
        pose[:3] = controller.clip_to_workspace(pose[:3])
        q = controller.ik(pose)
        lo, hi = self.model.actuator_ctrlrange[self.index.arm_act].T
        self.data.ctrl[self.index.arm_act] = np.clip(q, lo, hi)
        f = wm.FINGER_OPEN + (wm.FINGER_CLOSED - wm.FINGER_OPEN) * (float(np.clip(grip, -1, 1)) + 1.0) / 2.0
        self.data.ctrl[self.index.finger_act] = [f, -f]

    def step(self, action):
        a = self.check_action(action)
        pose = self.commanded_pose()
        pose[:3] += a[:3] * self.max_delta
        pose[3] += a[3] * self.max_yaw_delta
        self._set_targets(pose, a[4])
        self.do_simulation()
        return self._step_result()

    def _step_result(self):
        for name in self.domain.objects:
            self._lifted[name] |= bool(wscene.object_center(self.model, self.data, name)[2] > LIFTED_Z)
        count, where = sorted_count(self.model, self.data, self.domain)
        info = self._info(count, where)
        return self._obs(), float(count), False, False, info

    def _info(self, count: int, where: dict) -> dict[str, Any]:
        return {
            "num_sorted": count,
            "score": count / 2.0,
            "success": count == 2,
            "is_success": count == 2,
            "shoe_bin": where[self.domain.shoe],
            "toy_bin": where[self.domain.toy],
            "episode_stats": {
                f"{wm.CATEGORY[n]}/{k}": float(v)
                for n in self.domain.objects
                for k, v in (
                    ("lifted", self._lifted[n]),
                    ("in_its_bin", where[n] == wm.CATEGORY[n]),
                    ("in_other_bin", where[n] not in (None, wm.CATEGORY[n])),
                )
            },
        }

    # --- reset -------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        options = options or {}
        rng = self.np_random
        domain = options.get("domain")
        if domain is None:
            domain = wdom.sample_domain(rng, randomize=self.randomize)
        elif isinstance(domain, dict):
            domain = wdom.Domain.from_json(domain)
        self.set_domain(domain)
        mujoco.mj_resetData(self.model, self.data)
        for i, name in enumerate(wm.POOL):
            self.index.set_object_pose(self.data, name, [-1.0 - 0.3 * i, 0.0, wm.PARK_Z], [1, 0, 0, 0])
        (xlo, xhi), (ylo, yhi) = wm.OBJECT_REGION
        placed: list[np.ndarray] = []
        for name in domain.objects:
            for _ in range(100):
                xy = rng.uniform([xlo, ylo], [xhi, yhi])
                if all(np.linalg.norm(xy - p) >= MIN_OBJECT_DISTANCE for p in placed):
                    break
            placed.append(xy)
            if options.get("upright"):  # standing on the sole / base with a random yaw
                quat = wscene.yaw_quat(rng.uniform(-math.pi, math.pi))
            else:  # any orientation (the paper: "random quaternion")
                quat = wscene.random_quat(rng)
            z = DROP_HEIGHT - wscene.lowest_point(self.index, name, quat)
            self.index.set_object_pose(self.data, name, [xy[0], xy[1], z], quat)
        home = HOME_POSE.copy()
        home[:3] += rng.uniform(-0.015, 0.015, 3)
        q = controller.ik(home)
        self.data.qpos[self.index.arm_qpos] = q
        self.data.qpos[self.index.finger_qpos] = [wm.FINGER_OPEN, -wm.FINGER_OPEN]
        self._set_targets(home, -1.0)
        self._settle()
        self._lifted = dict.fromkeys(domain.objects, False)
        count, where = sorted_count(self.model, self.data, self.domain)
        return self._obs(), self._info(count, where)

    def _settle(self) -> None:
        """Let the dropped objects fall and come to rest (the robot holds its home pose), so an
        episode's first observation shows a scene at rest."""
        for _ in range(SETTLE_MAX_STEPS // SETTLE_STEPS):
            self.do_simulation(n_steps=SETTLE_STEPS)
            if max(self.index.object_speed(self.data, n) for n in self.domain.objects) < REST_SPEED:
                return

    def set_domain(self, domain: wdom.Domain) -> None:
        """Apply an episode's objects and looks (textures, lights, camera) to the model."""
        self.domain = domain
        wdom.apply_domain(self.model, domain)

    # --- observations ------------------------------------------------------------
    def proprio(self) -> np.ndarray:
        return self.data.qpos[self.index.robot_qpos].astype(np.float32)

    def state_vector(self) -> np.ndarray:
        parts = [self.data.qpos[self.index.robot_qpos], self.tip_position()]
        for name in self.domain.objects:
            parts.extend(self.index.object_pose(self.data, name))
        return np.concatenate(parts).astype(np.float32)

    def _obs(self):
        if self.obs_mode == "state":
            return self.state_vector()
        return {"pixels/side": self.render_side(), "proprio": self.proprio()}

    def render_side(self, size: int | None = None) -> np.ndarray:
        s = self.image_size if size is None else int(size)
        return self.render_camera_image("side", s, s)
