"""The Unitree A1 model (MuJoCo Menagerie, from the ``gymnasium-quadruped`` wheel) and its scenes.

Built with :class:`mujoco.MjSpec`: the Menagerie robot is loaded unchanged, then
its position actuators get the PD gains of the D5RL release (kp 60, kd 6,
torque clipped to ±33.5 N·m — MuJoCo's ``position`` actuator with ``kv`` *is*
that PD law, evaluated every 1 ms physics step), an IMU site with gyro and
velocimeter sensors is added, and the floor is either a plane or the hiking
course heightfield.
"""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np

from d5rl.assets import asset_path

PHYSICS_DT = 0.001  # s
CONTROL_DT = 0.05  # s (20 Hz)
KP, KD, TORQUE_LIMIT = 60.0, 6.0, 33.5
NOMINAL_POSE = np.array([0.0, 0.9, -1.8] * 4)
ACTION_SCALE = np.array([0.2, 0.4, 0.4] * 4)
LEGS = ("FR", "FL", "RR", "RL")
JOINTS = tuple(f"{leg}_{part}_joint" for leg in LEGS for part in ("hip", "thigh", "calf"))


def wrap_angle(a: float) -> float:
    """``a`` in radians, wrapped into [-pi, pi)."""
    return float((a + np.pi) % (2 * np.pi) - np.pi)


@dataclasses.dataclass(frozen=True)
class Course:
    """The hiking course: a heightfield with rolling bumps and two ramps, and waypoints on y = 0."""

    x_range: tuple[float, float] = (-26.0, 46.0)
    y_half_width: float = 5.0
    resolution: float = 0.1  # m per heightfield cell
    bump_height: float = 0.06  # m, std of the smoothed noise before clipping
    bump_smoothness: float = 0.75  # m, correlation length of the bumps
    ramps: tuple[tuple[float, float, float], ...] = ((-6.0, 4.0, 0.6), (12.0, 22.0, -0.6))  # (x0, x1, rise)
    start_x: float = -20.0
    flat_start: float = 3.0  # m of flat ground around the start
    waypoints: tuple[float, ...] = (-10.0, 0.0, 20.0, 40.0)
    seed: int = 0

    def heights(self) -> np.ndarray:
        """(nrow=y, ncol=x) terrain heights in metres, deterministic in ``seed``."""
        rng = np.random.default_rng(self.seed)
        x = np.arange(self.x_range[0], self.x_range[1] + 1e-9, self.resolution)
        y = np.arange(-self.y_half_width, self.y_half_width + 1e-9, self.resolution)
        noise = rng.normal(size=(len(y), len(x)))
        # separable Gaussian smoothing (pure numpy, no scipy)
        sigma = self.bump_smoothness / self.resolution
        k = np.arange(-int(3 * sigma), int(3 * sigma) + 1)
        kernel = np.exp(-0.5 * (k / sigma) ** 2)
        kernel /= kernel.sum()
        smooth = np.apply_along_axis(lambda r: np.convolve(r, kernel, mode="same"), 1, noise)
        smooth = np.apply_along_axis(lambda c: np.convolve(c, kernel, mode="same"), 0, smooth)
        smooth *= self.bump_height / smooth.std()
        h = np.clip(smooth, -2.5 * self.bump_height, 2.5 * self.bump_height)
        base = np.zeros_like(x)
        for x0, x1, rise in self.ramps:
            base += rise * np.clip((x - x0) / (x1 - x0), 0.0, 1.0)
        h = h + base[None, :]
        flat = np.abs(x - self.start_x) < self.flat_start  # the robot starts on level ground
        h[:, flat] = base[flat][None, :]
        return h

    def height_at(self, x: float) -> float:
        base = 0.0
        for x0, x1, rise in self.ramps:
            base += rise * float(np.clip((x - x0) / (x1 - x0), 0.0, 1.0))
        return base


def build_spec(course: Course | None = None) -> mujoco.MjSpec:
    scene = asset_path("gymnasium-quadruped", "assets", "unitree_a1", "scene.xml")
    spec = mujoco.MjSpec.from_file(str(scene))
    spec.option.timestep = PHYSICS_DT
    for act in spec.actuators:
        lo, hi = act.ctrlrange
        act.set_to_position(kp=KP, kv=KD)
        act.ctrlrange = [lo, hi]
        act.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
        act.forcerange = [-TORQUE_LIMIT, TORQUE_LIMIT]
        act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
    trunk = spec.body("trunk")
    trunk.add_site(name="imu", pos=[0, 0, 0], size=[0.01, 0, 0])
    spec.add_sensor(name="gyro", type=mujoco.mjtSensor.mjSENS_GYRO, objtype=mujoco.mjtObj.mjOBJ_SITE, objname="imu")
    spec.add_sensor(
        name="velocimeter", type=mujoco.mjtSensor.mjSENS_VELOCIMETER, objtype=mujoco.mjtObj.mjOBJ_SITE, objname="imu"
    )
    trunk.add_camera(
        name="track", mode=mujoco.mjtCamLight.mjCAMLIGHT_TRACKCOM, pos=[0.0, -2.0, 0.6], xyaxes=[1, 0, 0, 0, 0.3, 1]
    )
    spec.visual.global_.offwidth = 640
    spec.visual.global_.offheight = 480
    if course is not None:
        _add_course(spec, course)
    return spec


def _add_course(spec: mujoco.MjSpec, course: Course) -> None:
    floor = spec.geom("floor")
    floor.pos = [0, 0, -5.0]  # the plane stays as a safety net far below the course
    h = course.heights()
    lo, hi = float(h.min()), float(h.max())
    span = max(hi - lo, 1e-3)
    nrow, ncol = h.shape
    half_x = (course.x_range[1] - course.x_range[0]) / 2
    spec.add_hfield(
        name="course",
        size=[half_x, course.y_half_width, span, 0.5],
        nrow=nrow,
        ncol=ncol,
        userdata=((h - lo) / span).ravel().tolist(),
    )
    spec.worldbody.add_geom(
        name="terrain",
        type=mujoco.mjtGeom.mjGEOM_HFIELD,
        hfieldname="course",
        material="groundplane",
        pos=[(course.x_range[0] + course.x_range[1]) / 2, 0.0, lo],
    )
    for i, wx in enumerate(course.waypoints):
        spec.worldbody.add_site(
            name=f"waypoint{i}", pos=[wx, 0.0, course.height_at(wx) + 0.3], size=[0.08, 0, 0], rgba=[1.0, 0.4, 0.1, 0.8]
        )


def build_model(course: Course | None = None) -> mujoco.MjModel:
    return build_spec(course).compile()


@dataclasses.dataclass(frozen=True)
class Indices:
    """Addresses into qpos/qvel/sensordata, looked up once per model."""

    qpos_joints: np.ndarray
    qvel_joints: np.ndarray
    gyro: slice
    velocimeter: slice

    @classmethod
    def of(cls, model: mujoco.MjModel) -> Indices:
        qpos = np.array([model.jnt_qposadr[model.joint(j).id] for j in JOINTS])
        qvel = np.array([model.jnt_dofadr[model.joint(j).id] for j in JOINTS])

        def sens(name):
            s = model.sensor(name)
            return slice(int(s.adr[0]), int(s.adr[0] + s.dim[0]))

        return cls(qpos, qvel, sens("gyro"), sens("velocimeter"))


class A1State:
    """Named state accessors of an A1 env (v0 and v1): the env sets ``data``, ``idx`` (:class:`Indices`)
    and ``trunk_id``."""

    def joint_pos(self):
        return self.data.qpos[self.idx.qpos_joints]

    def joint_vel(self):
        return self.data.qvel[self.idx.qvel_joints]

    def torques(self):
        return self.data.actuator_force.copy()

    def observation(self, heading_error: float | None = None) -> np.ndarray:
        """The policy's observation: joint positions, velocities and torques, the gyro, the trunk's local
        velocity and orientation, the previous action, and (directed tasks) the heading error as sin, cos.
        The env also sets ``_prev_action``."""
        parts = [
            self.joint_pos(),
            self.joint_vel(),
            self.torques(),
            self.data.sensordata[self.idx.gyro],
            self.local_velocity(),
            self.body_quat(),
            self._prev_action,
        ]
        if heading_error is not None:
            parts.append([np.sin(heading_error), np.cos(heading_error)])
        return np.concatenate(parts).astype(np.float32)

    def body_quat(self):
        return self.data.qpos[3:7]

    def local_velocity(self):
        return self.data.sensordata[self.idx.velocimeter]

    def upright(self) -> float:
        """z component of the body's up axis in the world frame (1 = level)."""
        return float(self.data.xmat[self.trunk_id][8])
