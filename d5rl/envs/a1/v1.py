"""The A1 tasks as the D5RL release defines them (``a1-*-v1``).

Read from the release's ``legged_mujoco/__init__.py`` (action range), ``tasks/run.py``
(``SimpleRun``, ``RunToward``, ``Hiking``: reward, start, end, randomisation) and ``arenas/``
(floors: :mod:`d5rl.envs.a1.arenas`).  The env composes a physical model (:mod:`d5rl.envs.a1.model`)
with one task object, as dm_control's composer does: :class:`Run`, :class:`RunToward`, :class:`Hiking`.
"""

from __future__ import annotations

import gymnasium as gym
import mujoco
import numpy as np

from d5rl.envs.a1 import arenas, rewards
from d5rl.envs.a1.model import (
    ACTION_SCALE,
    CONTROL_DT,
    JOINTS,
    NOMINAL_POSE,
    PHYSICS_DT,
    A1State,
    Indices,
    build_spec,
    wrap_angle,
)
from d5rl.envs.base import MujocoEnv

ACTION_RANGE = 3.0  # joint targets span nominal ± ACTION_RANGE × ACTION_SCALE (the release's ACTION_OFFSET)
FALL_ANGLE = np.deg2rad(60.0)  # |roll| or |pitch| beyond this ends the episode
START_Z = 0.125  # m: the start search's first trunk height; it rises by START_DZ until nothing touches
START_DZ = 0.01
GOAL_RADIUS = 0.1  # m (2-D): a goal or waypoint this close counts as reached
GOAL_RANGE = 10.0  # m: RunToward's goals are uniform in [-GOAL_RANGE, GOAL_RANGE]^2
FRICTION_RANGE = (0.75, 1.25)  # RunToward: the floor's sliding friction per episode
TRUNK_MASS, TRUNK_MASS_SPREAD = 4.714, 0.25  # kg, RunToward: the trunk's mass per episode
MAX_LATERAL_OFFSET = 3.0  # m, hiking: |y| beyond this ends the episode
# The release's arenas are dm_control composer arenas, whose base model sets 5 no-slip solver iterations
# (tolerance 0) on top of the A1's elliptic cones and impratio 100: feet slip less.  It doubles the cost
# of a physics step (~2 -> ~4 ms of one core per control step), a small part of an agent's training step.
NOSLIP_ITERATIONS, NOSLIP_TOLERANCE = 5, 0.0


def euler_xyz(quat) -> tuple[float, float, float]:
    """(roll, pitch, yaw) of a wxyz quaternion in dm_control's ``quat_to_euler`` convention ('XYZ':
    R = Rx(roll) Ry(pitch) Rz(yaw)), which the release's reward and fall test use; it differs from the
    aerospace z-y-x angles away from level (pitch = asin(R[0, 2]), not asin(-R[2, 0]))."""
    r = np.empty(9)
    mujoco.mju_quat2Mat(r, np.asarray(quat, dtype=np.float64))
    r = r.reshape(3, 3)
    pitch = float(np.arcsin(np.clip(r[0, 2], -1.0, 1.0)))
    return float(-np.arctan2(r[1, 2], r[2, 2])), pitch, float(-np.arctan2(r[0, 1], r[0, 0]))


def action_box(model: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray]:
    """Joint-target bounds: nominal ± ACTION_RANGE × [0.2, 0.4, 0.4], clipped to the joints' ranges (the
    calf's lower bound -3.0 becomes -2.697 and its upper -0.6 becomes -0.916: its targets are not centred
    on the nominal -1.8)."""
    ranges = np.array([model.jnt_range[model.joint(j).id] for j in JOINTS])
    low = np.maximum(NOMINAL_POSE - ACTION_RANGE * ACTION_SCALE, ranges[:, 0])
    high = np.minimum(NOMINAL_POSE + ACTION_RANGE * ACTION_SCALE, ranges[:, 1])
    return low, high


class Task:
    """What a v1 task defines: its floor, start, reward and end.  The env calls ``initialize_episode``
    at reset (before placing the robot), ``after_step`` after each control step, then ``reward``."""

    floor = "flat"
    directed = False  # the observation carries sin / cos of the heading error
    energy_coef = rewards.ENERGY_COEF
    default_speed = 1.0  # m/s, the release's default target

    def __init__(self, target_speed: float | None = None):
        self.target_speed = float(self.default_speed if target_speed is None else target_speed)

    def start_xy(self) -> tuple[float, float]:
        return 0.0, 0.0

    def initialize_episode(self, env: A1EnvV1, rng: np.random.Generator) -> None:
        arenas.regenerate(env.model, self.floor, rng)

    def after_step(self, env: A1EnvV1, rng: np.random.Generator) -> None:
        pass

    def heading_error(self, env: A1EnvV1) -> float:
        return 0.0

    def forward_speed(self, env: A1EnvV1) -> float:
        _, pitch, yaw = euler_xyz(env.body_quat())
        return float(env.local_velocity()[0] * np.cos(pitch) * np.cos(yaw))

    def reward(self, env: A1EnvV1) -> tuple[float, dict]:
        terms = {
            "forward_speed": self.forward_speed(env),
            "standing": float(rewards.standing_term_v1(env.upright(), env.joint_pos())),
            "energy": float(np.sum(env.joint_vel() * env.torques())),  # signed, as the release
            "heading_error": self.heading_error(env),
        }
        return float(
            rewards.speed_reward(
                terms["forward_speed"], terms["standing"], terms["energy"], self.target_speed, self.energy_coef
            )
        ), terms

    def failed(self, env: A1EnvV1) -> bool:
        return False

    def stats(self) -> dict:
        return {}


class Run(Task):
    """The release's ``SimpleRun``: track ``target_speed`` along the body's x axis on flat ground.
    The speed term reads v_x · cos(pitch) · cos(yaw): facing away from +x world lowers it."""


class RunToward(Task):
    """The release's ``RunToward``: run at 1 m/s toward a goal drawn uniformly within ±10 m (a new one
    once within 0.1 m).  Each episode draws the floor (``floors="mixed"``: smooth or bumpy with equal
    odds; ``"smooth"``: always the plane), the floor's sliding friction U(0.75, 1.25) and the trunk's
    mass 4.714 ± 0.25 kg.  The A1's feet have contact priority, so their own friction (0.8) applies
    to foot contacts whatever the floor's: the floor friction only changes other contacts (as in the
    release)."""

    floor = "bumpy"
    directed = True
    energy_coef = rewards.HIKING_ENERGY_COEF

    def __init__(self, target_speed: float | None = None, floors: str = "mixed"):
        super().__init__(target_speed)
        if floors not in ("mixed", "smooth"):
            raise ValueError(f"floors must be 'mixed' or 'smooth', got {floors!r}")
        self.floors = floors
        self.goal = np.zeros(2)
        self.bumpy = False

    def initialize_episode(self, env, rng):
        self.bumpy = self.floors == "mixed" and bool(rng.integers(2))
        geom = env.model.geom(arenas.FIELD)
        if self.bumpy:
            arenas.regenerate(env.model, self.floor, rng)
            geom.pos[2] = arenas.FIELD_Z
        else:
            geom.pos[2] = -10.0  # out of reach under the plane: a smooth episode
        friction = rng.uniform(*FRICTION_RANGE)
        for g in ("floor", arenas.FIELD):
            env.model.geom(g).friction[:] = [friction, 0.005, 0.0001]
        env.model.body("trunk").mass[0] = rng.uniform(TRUNK_MASS - TRUNK_MASS_SPREAD, TRUNK_MASS + TRUNK_MASS_SPREAD)
        self.goal = rng.uniform(-GOAL_RANGE, GOAL_RANGE, 2)

    def after_step(self, env, rng):
        while np.linalg.norm(self.goal - env.data.qpos[:2]) < GOAL_RADIUS:
            self.goal = rng.uniform(-GOAL_RANGE, GOAL_RANGE, 2)

    def target(self, env) -> np.ndarray:
        return self.goal

    def heading_error(self, env) -> float:
        """Bearing of the goal minus the body's heading (its x axis projected on the ground), wrapped to
        [-π, π); the release leaves the difference unwrapped, so its reward treats a goal just across
        the ±π line as almost straight behind."""
        d = self.target(env) - env.data.qpos[:2]
        x_axis = env.data.xmat[env.trunk_id].reshape(3, 3)[:2, 0]
        return wrap_angle(np.arctan2(d[1], d[0]) - np.arctan2(x_axis[1], x_axis[0]))

    def forward_speed(self, env) -> float:
        _, pitch, _ = euler_xyz(env.body_quat())
        return float(env.local_velocity()[0] * np.cos(pitch))

    def reward(self, env):
        _, terms = super().reward(env)
        return float(
            rewards.hiking_reward(
                terms["forward_speed"],
                terms["standing"],
                terms["energy"],
                terms["heading_error"],
                self.target_speed,
                self.energy_coef,
            )
        ), terms

    def stats(self) -> dict:
        return {"bumpy_floor": float(self.bumpy)}


class Hiking(RunToward):
    """The release's ``Hiking``: from x = -20, reach the waypoints (-10, 0), (0, 0), (20, 0), (40, 0) in
    order (each within 0.1 m in 2-D) at 1 m/s over a course redrawn every episode
    (:mod:`d5rl.envs.a1.arenas`); straying more than 3 m from y = 0 ends the episode.  After the last
    waypoint the robot is steered further along +x (the release has no goal there; 60 m at 1 m/s
    take 1200 steps, more than an episode)."""

    floor = "course"

    def __init__(self, target_speed: float | None = None):
        super().__init__(target_speed)
        self.reached = 0

    def start_xy(self):
        return arenas.HIKING_START

    def initialize_episode(self, env, rng):
        Task.initialize_episode(self, env, rng)
        self.reached = 0

    def after_step(self, env, rng):
        xy = env.data.qpos[:2]
        if self.reached < len(arenas.WAYPOINTS) and np.linalg.norm(self.target(env) - xy) < GOAL_RADIUS:
            self.reached += 1

    def target(self, env) -> np.ndarray:
        if self.reached < len(arenas.WAYPOINTS):
            return np.asarray(arenas.WAYPOINTS[self.reached])
        return np.array([env.data.qpos[0] + 10.0, 0.0])

    def failed(self, env) -> bool:
        return bool(abs(env.data.qpos[1]) > MAX_LATERAL_OFFSET)

    def stats(self) -> dict:
        return {"waypoints_reached": float(self.reached)}


TASKS = {"run": Run, "run_toward": RunToward, "hiking": Hiking}


class A1EnvV1(A1State, MujocoEnv):
    """Unitree A1 tasks as the D5RL release defines them: track a speed, run toward goals, or hike.

    **Description.** The MuJoCo Menagerie A1 (the release's model) under 20 Hz PD position control
    (kp 60, kd 6, 1 ms physics): every physics step applies the torque kp·(target − q) − kd·q̇
    clipped to ±33.5 N·m, as the release's ``A1.apply_action`` does (MuJoCo's position actuator
    with ``kv`` and ``forcerange``); contacts as in the release's dm_control arenas (elliptic cones,
    impratio 100, 5 no-slip iterations).  ``task="run"`` tracks ``target_speed`` on flat ground
    (``a1-walk-v1`` 0.75 m/s, ``a1-run-v1`` 1.25 m/s); ``"hiking"`` walks at 1 m/s through four
    waypoints over a course redrawn every episode (a bumpy ring-shaped rim, two 1.2 m ridges:
    :mod:`d5rl.envs.a1.arenas`; ``a1-hiking-v1``); ``"run_toward"`` runs at 1 m/s toward random goals
    on smooth or bumpy floors (the hiking data agent's task; ``floors="smooth"`` keeps the plane).

    **Action space.** ``Box(-1, 1, (12,))`` mapped linearly onto joint targets in [nominal −
    3 × [0.2, 0.4, 0.4], nominal + 3 × [0.2, 0.4, 0.4]] per leg (FR, FL, RR, RL; hip, thigh, calf;
    nominal [0, 0.9, -1.8]) clipped to the joints' ranges (the release's ``ClipActionToRange``
    rescaled to [-1, 1]: :func:`action_box`).

    **Observation space.** ``Box(-inf, inf, (58,))`` float32: joint positions (12), joint velocities
    (12), joint torques (12), body gyro (3), body-frame linear velocity (3), body quaternion wxyz (4),
    previous action (12, in [-1, 1]).  Hiking and run_toward add sin and cos of the heading error (60).

    **Reward.** The release's: ``10 · tolerance(v, target ± 0.1, margin target, linear) · standing −
    c · Σ q̇·τ`` with the energy term signed; run: v = v_x·cos(pitch)·cos(yaw), c = 0.01; hiking and
    run_toward: v = v_x·cos(pitch), the speed term times ``tolerance(heading error, ±π/12, margin π,
    linear)``, c = 0.001.  ``standing`` = ``tolerance(z-axis up, [0.9, ∞), margin 0.9, quadratic)``
    × Π over joints ``tolerance(q_j, nominal_j ± offset_j, margin offset_j, gaussian, 0.5 at the
    margin)`` with offsets [0.2, 0.4, 0.4].  Angles are dm_control's 'XYZ' Euler angles
    (:func:`euler_xyz`).  ``info`` has the terms (``forward_speed`` = v, ``standing``, ``energy``,
    ``heading_error``) and ``episode_stats`` (mean ``forward_speed``, ``ended_early``; hiking:
    ``waypoints_reached``).

    **Start state.** Joints at the nominal pose, level and facing +x, at rest, at (0, 0) (hiking:
    (-20, 0)), lowered onto the floor: the trunk starts at the first height 0.125 + k·0.01 m at which
    nothing touches.  Flat-ground starts are the same for every seed, as in the release.

    **Episode end.** Terminates when |roll| or |pitch| > 60° (hiking also when |y| > 3 m); truncated
    after 400 steps (hiking 1000) by the TimeLimit wrapper.

    **Version history.** v1: the release's action range (3× v0's), reward (product of gaussian joint
    terms, signed energy, 'XYZ' angles), no-slip contact iterations, start state and hiking task (1 m/s, course redrawn per
    episode, waypoints reached within 0.1 m).  v0 (:class:`d5rl.envs.a1.task.A1Env`): ±1× range,
    mean of quadratic joint terms, |energy|, one fixed course at 0.75 m/s.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 20}

    def __init__(
        self,
        task: str = "run",
        target_speed: float | None = None,
        render_mode: str | None = None,
        render_size: tuple[int, int] = (240, 320),
        width: int | None = None,
        height: int | None = None,
        **task_kwargs,
    ):
        if task not in TASKS:
            raise ValueError(f"task must be one of {sorted(TASKS)}, got {task!r}")
        self.task = TASKS[task](target_speed, **task_kwargs)
        spec = build_spec()
        spec.option.noslip_iterations = NOSLIP_ITERATIONS
        spec.option.noslip_tolerance = NOSLIP_TOLERANCE
        arenas.add_floor(spec, self.task.floor)
        super().__init__(
            spec.compile(),
            frame_skip=round(CONTROL_DT / PHYSICS_DT),
            render_mode=render_mode,
            render_size=render_size,
            render_camera="track",
            width=width,
            height=height,
        )
        self.target_speed = self.task.target_speed
        self.idx = Indices.of(self.model)
        self.trunk_id = self.model.body("trunk").id
        self.action_low, self.action_high = action_box(self.model)
        obs_dim = 58 + (2 if self.task.directed else 0)
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (obs_dim,), np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (12,), np.float32)
        self._prev_action = np.zeros(12)
        self._t = 0
        self._speed_sum = 0.0

    def joint_targets(self, action) -> np.ndarray:
        """Joint targets of an action in [-1, 1] (linear onto :func:`action_box`)."""
        a = np.asarray(action, dtype=np.float64)
        return self.action_low + (a + 1.0) / 2.0 * (self.action_high - self.action_low)

    # --- episode -------------------------------------------------------------------------------
    def _obs(self) -> np.ndarray:
        return self.observation(self.task.heading_error(self) if self.task.directed else None)

    def _place_robot(self, x: float, y: float, joints=NOMINAL_POSE) -> None:
        """The joints at ``joints`` (the nominal pose), level, at rest, at the lowest height on the release's 1 cm
        grid where nothing touches."""
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[self.idx.qpos_joints] = joints
        self.data.qpos[:7] = [x, y, START_Z, 1.0, 0.0, 0.0, 0.0]
        self.data.ctrl[:] = joints  # zero torque at rest
        for _ in range(1000):
            mujoco.mj_forward(self.model, self.data)
            if self.data.ncon == 0:
                return
            self.data.qpos[2] += START_DZ
        raise RuntimeError(f"no contact-free start height found at ({x}, {y})")

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.task.initialize_episode(self, self.np_random)
        if self.task.floor != "flat":
            MujocoEnv.close(self)  # renderers hold the old heightfield: the next render makes fresh ones
        self._place_robot(*self.task.start_xy())
        self._prev_action = np.zeros(12)
        self._t = 0
        self._speed_sum = 0.0
        return self._obs(), {}

    def reward_terms(self) -> tuple[float, dict]:
        """The reward of the current state and its terms (also stored in datasets for relabelling)."""
        return self.task.reward(self)

    def replay_step(self, state: np.ndarray, action) -> np.ndarray:
        """Observation at a stored ``state`` that ``action`` led to: the state is set and the task advances
        as in :meth:`step` (a reached goal or waypoint makes way for the next, drawn from the env's
        generator), so replaying an episode's states in order after a reset with its seed recomputes its
        observations."""
        self.set_state(state)
        self._prev_action = self.check_action(action)
        self.task.after_step(self, self.np_random)
        return self._obs()

    def step(self, action):
        action = self.check_action(action)
        self.do_simulation(self.joint_targets(action))
        self._prev_action = action
        self._t += 1
        self.task.after_step(self, self.np_random)
        reward, terms = self.task.reward(self)
        roll, pitch, _ = euler_xyz(self.body_quat())
        terminated = bool(abs(roll) > FALL_ANGLE or abs(pitch) > FALL_ANGLE or self.task.failed(self))
        self._speed_sum += terms["forward_speed"]
        stats = {"forward_speed": self._speed_sum / self._t, "ended_early": float(terminated), **self.task.stats()}
        info = {**terms, "x": float(self.data.qpos[0]), "episode_stats": stats}
        return self._obs(), float(reward), terminated, False, info
