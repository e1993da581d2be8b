"""Unitree A1 locomotion tasks."""

from __future__ import annotations

import gymnasium as gym
import mujoco
import numpy as np

from d5rl.envs.a1 import rewards
from d5rl.envs.a1.model import (
    ACTION_SCALE,
    CONTROL_DT,
    NOMINAL_POSE,
    PHYSICS_DT,
    A1State,
    Course,
    Indices,
    build_model,
    wrap_angle,
)
from d5rl.envs.base import MujocoEnv

MAX_TILT = np.deg2rad(60.0)
MAX_LATERAL_OFFSET = 3.0  # m, hiking
WAYPOINT_TOLERANCE = 0.1  # m, hiking: a waypoint counts once the robot is this close to its x


def _euler_from_quat(q):
    w, x, y, z = q
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


class Command:
    """What a v0 task asks the robot to follow (dm_control style: the env composes one per task).  The
    base runs along +x and is paid by :func:`rewards.speed_reward`; the env calls ``reset`` after placing
    the robot and ``after_step`` after each control step."""

    directed = False  # the observation carries sin / cos of the heading error
    energy_coef = rewards.ENERGY_COEF

    def reset(self, env: A1Env, rng: np.random.Generator) -> None:
        pass

    def after_step(self, env: A1Env, rng: np.random.Generator) -> None:
        pass

    def desired_heading(self, env: A1Env) -> float:
        return 0.0

    def reward(self, env: A1Env, forward: float, standing: float, energy: float, heading_error: float) -> float:
        return rewards.speed_reward(forward, standing, energy, env.target_speed, self.energy_coef)

    def waypoints_reached(self) -> int:
        return 0

    def stats(self) -> dict:
        return {}


class Forward(Command):
    """Track the target speed along +x on flat ground (a1-walk-v0, a1-run-v0)."""


class Directed(Command):
    """A task with a direction to follow: the observation carries the heading error, and the reward
    :func:`rewards.hiking_reward` weighs the speed by it."""

    directed = True
    energy_coef = rewards.HIKING_ENERGY_COEF

    def reward(self, env, forward, standing, energy, heading_error):
        return rewards.hiking_reward(forward, standing, energy, heading_error, env.target_speed, self.energy_coef)


class Heading(Directed):
    """Follow a heading drawn at reset that turns by U(±π/2) every ``change_steps`` steps (the hiking
    data agent's task)."""

    def __init__(self, change_steps: int = 100):
        self.change_steps = int(change_steps)
        self.heading = 0.0

    def reset(self, env, rng):
        self.heading = rng.uniform(-np.pi, np.pi)

    def after_step(self, env, rng):
        if env.steps % self.change_steps == 0:
            self.heading = wrap_angle(self.heading + rng.uniform(-np.pi / 2, np.pi / 2))

    def desired_heading(self, env):
        return self.heading


class Waypoints(Directed):
    """Walk the course through its waypoints (a1-hiking-v0): head for the next one's x on the line y = 0."""

    def __init__(self, course: Course):
        self.course = course
        self.reached = 0

    def reset(self, env, rng):
        self.reached = 0

    def after_step(self, env, rng):
        waypoints = self.course.waypoints
        while self.reached < len(waypoints) and env.data.qpos[0] >= waypoints[self.reached] - WAYPOINT_TOLERANCE:
            self.reached += 1

    def desired_heading(self, env):
        wx = self.course.waypoints[min(self.reached, len(self.course.waypoints) - 1)]
        x, y = env.data.qpos[0], env.data.qpos[1]
        return float(np.arctan2(-y, wx - x))

    def waypoints_reached(self) -> int:
        return self.reached

    def stats(self):
        return {"waypoints_reached": float(self.reached)}


class A1Env(A1State, MujocoEnv):
    """Unitree A1 quadruped tracking a forward speed, on flat ground or on a hiking course.

    **Description.** The MuJoCo Menagerie A1 under 20 Hz PD position control (kp 60, kd 6,
    torques clipped to ±33.5 N·m, 1 ms physics). ``a1-walk-v0`` tracks 0.75 m/s and
    ``a1-run-v0`` 1.25 m/s on flat ground; ``a1-hiking-v0`` walks at 0.75 m/s along a
    generated course of rolling bumps and ramps through waypoints at x = -10, 0, 20, 40.

    **Action space.** ``Box(-1, 1, (12,))``: joint targets = nominal pose [0, 0.9, -1.8] per
    leg (FR, FL, RR, RL; hip, thigh, calf) + action × [0.2, 0.4, 0.4].

    **Observation space.** ``Box(-inf, inf, (58,))`` float32: joint positions (12), joint
    velocities (12), joint torques (12), body gyro (3), body-frame linear velocity (3), body
    quaternion wxyz (4), previous action (12).  With ``command="heading"`` or
    ``"waypoints"`` two more entries: sin and cos of the heading error (60 in all).

    **Reward.** ``10 · tolerance(v_fwd·cos(roll)·cos(pitch), target ± 0.1, margin target) ·
    standing − c · Σ|q̇ · τ|`` with ``standing`` = upright tolerance × mean joint tolerance
    around the nominal pose and c = 0.01 (hiking: the speed term is multiplied by
    ``tolerance(heading error, ±π/12, margin π)`` and c = 0.001).  Per-step terms are in
    ``info`` (``forward_speed``, ``standing``, ``energy``, ``heading_error``);
    ``info["episode_stats"]`` has the episode's mean ``forward_speed`` so far (m/s), whether it
    ``ended_early`` (a fall, or straying off the course), and on the course the
    ``waypoints_reached``; evaluation averages the final values over episodes.

    **Start state.** The ``home`` keyframe with joint noise U(±0.05 rad) and yaw noise
    U(±0.1 rad) (hiking: at x = -20 facing the course).

    **Episode end.** Terminates when |roll| or |pitch| > 60° (hiking also when the lateral
    offset exceeds 3 m); truncated after 400 steps (hiking 1000) by the TimeLimit wrapper.

    **Version history.** v0: initial release.  Superseded by v1 (:class:`d5rl.envs.a1.v1.A1EnvV1`), which
    takes the D5RL release's action range (3× this one's), reward, start state and hiking course.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 20}

    def __init__(
        self,
        target_speed: float = 0.75,
        terrain: str = "flat",
        command: str = "forward",
        course_seed: int = 0,
        heading_change_steps: int = 100,
        render_mode: str | None = None,
        render_size: tuple[int, int] = (240, 320),
        width: int | None = None,
        height: int | None = None,
    ):
        if terrain not in ("flat", "course"):
            raise ValueError(f"terrain must be 'flat' or 'course', got {terrain!r}")
        if command not in ("forward", "heading", "waypoints"):
            raise ValueError(f"command must be 'forward', 'heading' or 'waypoints', got {command!r}")
        if command == "waypoints" and terrain != "course":
            raise ValueError("command='waypoints' needs terrain='course'")
        self.course = Course(seed=course_seed) if terrain == "course" else None
        super().__init__(
            build_model(self.course),
            frame_skip=round(CONTROL_DT / PHYSICS_DT),
            render_mode=render_mode,
            render_size=render_size,
            render_camera="track",
            width=width,
            height=height,
        )
        self.target_speed = float(target_speed)
        self.task = {
            "forward": Forward,
            "heading": lambda: Heading(heading_change_steps),
            "waypoints": lambda: Waypoints(self.course),
        }[command]()
        self.idx = Indices.of(self.model)
        self.trunk_id = self.model.body("trunk").id
        self._home = self.model.key("home").id  # an id, not a keyframe view: the env pickles and deep-copies
        obs_dim = 58 + (2 if self.task.directed else 0)
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (obs_dim,), np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (12,), np.float32)
        self._prev_action = np.zeros(12)
        self.steps = 0  # control steps since reset

    # --- task -------------------------------------------------------------------------------------
    def _heading_error(self) -> float:
        _, _, yaw = _euler_from_quat(self.body_quat())
        return wrap_angle(self.task.desired_heading(self) - yaw)

    def _obs(self) -> np.ndarray:
        return self.observation(self._heading_error() if self.task.directed else None)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        rng = self.np_random
        mujoco.mj_resetDataKeyframe(self.model, self.data, self._home)
        self.data.qpos[self.idx.qpos_joints] += rng.uniform(-0.05, 0.05, 12)
        yaw = rng.uniform(-0.1, 0.1)
        if self.course is not None:
            self.data.qpos[0] = self.course.start_x
            self.data.qpos[2] += self.course.height_at(self.course.start_x)
        self.data.qpos[3:7] = [np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)]
        self.data.ctrl[:] = NOMINAL_POSE
        self._prev_action = np.zeros(12)
        self.task.reset(self, rng)
        self.steps = 0
        self._speed_sum = 0.0
        mujoco.mj_forward(self.model, self.data)
        return self._obs(), {}

    def reward_terms(self) -> tuple[float, dict]:
        """The reward of the current state and its terms (also stored in datasets for relabelling)."""
        roll, pitch, _ = _euler_from_quat(self.body_quat())
        forward = float(self.local_velocity()[0] * np.cos(roll) * np.cos(pitch))
        standing = float(rewards.standing_term(self.upright(), self.joint_pos()))
        energy = float(np.abs(self.joint_vel() * self.torques()).sum())
        heading_error = self._heading_error()
        reward = self.task.reward(self, forward, standing, energy, heading_error)
        return float(reward), {
            "forward_speed": forward,
            "standing": standing,
            "energy": energy,
            "heading_error": heading_error,
        }

    def step(self, action):
        action = self.check_action(action)
        self.do_simulation(NOMINAL_POSE + ACTION_SCALE * action)
        self._prev_action = action
        self.steps += 1
        self.task.after_step(self, self.np_random)

        reward, terms = self.reward_terms()
        roll, pitch, _ = _euler_from_quat(self.body_quat())
        terminated = bool(abs(roll) > MAX_TILT or abs(pitch) > MAX_TILT)
        if self.course is not None and abs(self.data.qpos[1]) > MAX_LATERAL_OFFSET:
            terminated = True
        self._speed_sum += terms["forward_speed"]
        stats = {"forward_speed": self._speed_sum / self.steps, "ended_early": float(terminated), **self.task.stats()}
        info = {
            **terms,
            "x": float(self.data.qpos[0]),
            "waypoints_reached": self.task.waypoints_reached(),
            "episode_stats": stats,
        }
        return self._obs(), float(reward), terminated, False, info
