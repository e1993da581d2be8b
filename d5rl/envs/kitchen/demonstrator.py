"""A scripted, human-like demonstrator for the seven kitchen subtasks.

Each subtask is a short script of *phases* in task space: a target position and
orientation of the gripper's ``end_effector`` site (possibly recomputed every step from
the object's current state, e.g. along a door's arc), a gripper command and a
condition that ends the phase.  A resolved-rate controller (damped least squares on
the site Jacobian, with a null-space pull to a comfortable posture) turns the task-space
error into joint velocities, which are written as the env's normalized actions.

Human-like variation is drawn per episode and per phase from the caller's generator:
overall speed, grasp/approach offsets, a random via point before each approach, brief
pauses, and smoothed action noise.  Everything is a pure function of the generator.
"""

from __future__ import annotations

import dataclasses
from typing import Callable, Iterator

import mujoco
import numpy as np

from d5rl.envs.kitchen import model as km
from d5rl.envs.kitchen.task import ACTION_SCALE

OPEN, CLOSE = 1.0, -1.0


def rot_x(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rot_y(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rot_z(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


# Gripper orientations (columns: site x, y, z axes in the world).  The site's z axis is the
# pointing direction of the gripper, its y axis the direction the fingers open along.
R_FORWARD = np.array([[0.0, 1, 0], [0, 0, 1], [1, 0, 0]])  # point +y, fingers open along x
R_FORWARD_FLAT = R_FORWARD @ rot_z(-np.pi / 2)  # point +y, fingers open along z (joint 7 stays in range)
R_DOWN = np.array([[-1.0, 0, 0], [0, 1, 0], [0, 0, -1]])  # point down, fingers open along y
R_DOWN_X = np.array([[0.0, 1, 0], [1, 0, 0], [0, 0, -1]])  # point down, fingers (and palm) along x
# The finger pads span -0.044..+0.050 m along the site's z axis: the site sits at the pads' middle and
# the fingertips reach 5 cm beyond it.
FINGERTIP = 0.05


@dataclasses.dataclass
class Phase:
    """One motion: go to ``target(ctx) -> (pos, rot)`` with the gripper at ``grip``."""

    name: str
    target: Callable[["Context"], tuple[np.ndarray, np.ndarray]]
    grip: float = OPEN
    tol: float = 0.015  # position tolerance (m) when no ``done`` is given
    rot_tol: float = 0.12  # orientation tolerance (rad)
    done: Callable[["Context"], bool] | None = None
    max_steps: int = 40
    speed: float = 1.0  # multiplies the controller's speed limits
    freeze: bool = False  # evaluate ``target`` once when the phase starts (relative moves)
    min_steps: int = 0  # never end before this many steps (e.g. while a glide is under way)
    any_roll: bool = True  # the hand may be turned half a turn about its axis (symmetric grasps)
    roll_room: float = 0.0  # the last joint must keep this much room (rad, positive) for a later turn
    integral: bool = True  # integral action (off where the hand presses against something and would wind up)
    joints: np.ndarray | None = None  # a joint-space move instead: joint targets (rad) of the 7 arm joints
    # when a joint's velocity saturates, scale all joints down together instead of clipping that one,
    # so the hand keeps its direction (final approaches: clipping bent the path into a 4-6 cm sideways
    # drift that put a finger against the hinged door after the microwave, kettle or bottom burner)
    straight: bool = False


class Context:
    """What a script reads: the model/data, object accessors and this episode's variation."""

    def __init__(self, env, rng: np.random.Generator):
        self.env = env
        self.model, self.data = env.model, env.data
        self.rng = rng
        self.phase_step = 0  # steps taken in the current phase (set by the policy)
        self._site = env.model.site(km.END_EFFECTOR_SITE).id

    def site(self, name: str) -> np.ndarray:
        return self.data.site_xpos[self.model.site(name).id].copy()

    def body_pos(self, name: str) -> np.ndarray:
        return self.data.xpos[self.model.body(name).id].copy()

    def body_mat(self, name: str) -> np.ndarray:
        return self.data.xmat[self.model.body(name).id].reshape(3, 3).copy()

    def joint(self, name: str) -> float:
        return float(self.data.qpos[self.model.joint(name).qposadr[0]])

    @property
    def ee_pos(self) -> np.ndarray:
        return self.data.site_xpos[self._site].copy()

    @property
    def ee_rot(self) -> np.ndarray:
        return self.data.site_xmat[self._site].reshape(3, 3).copy()

    def jitter(self, scale: float) -> np.ndarray:
        return self.rng.normal(0.0, scale, size=3)


# --- the controller ------------------------------------------------------------------------------
def orientation_error(r_target: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Rotation vector taking ``r`` to ``r_target`` (world frame)."""
    qt, qc, qe = np.zeros(4), np.zeros(4), np.zeros(4)
    mujoco.mju_mat2Quat(qt, np.ascontiguousarray(r_target).ravel())
    mujoco.mju_mat2Quat(qc, np.ascontiguousarray(r).ravel())
    mujoco.mju_negQuat(qe, qc)
    q = np.zeros(4)
    mujoco.mju_mulQuat(q, qt, qe)
    if q[0] < 0:
        q = -q
    angle = 2 * np.arccos(np.clip(q[0], -1, 1))
    s = np.linalg.norm(q[1:])
    return np.zeros(3) if s < 1e-9 else q[1:] / s * angle


class Controller:
    """Resolved-rate control of the end-effector site, output as normalized joint velocities."""

    # The position servos reach about half the commanded joint velocity within a 0.08 s step
    # (measured: action 0.5 -> 0.50 rad/s on the shoulder, 0.63 rad/s on the wrist).
    TRACKING = 0.5
    # null-space pull towards the rest posture (the last two wrist joints turn freely)
    POSTURE_GAIN = np.array([0.5, 0.5, 0.5, 0.5, 0.15, 0.0, 0.0])
    ROT_WEIGHT = 0.4
    # The servos sag under gravity when the commanded velocity is small, leaving a steady 1-2 cm
    # error near a target; an integral of the position error (within INTEGRAL_ZONE, reset every
    # phase) removes it.
    INTEGRAL_GAIN = 0.5  # (m/s) per (m of error summed over steps)
    INTEGRAL_ZONE = 0.05
    INTEGRAL_MAX = 0.1
    JOINT_SPEED = 0.9  # rad/s cap of joint-space moves (the fastest joint; action 0.9)
    IK_POSTURE_GAIN = 0.2  # per iteration: inverse kinematics settles near the rest posture

    def __init__(self, env, max_lin: float = 0.8, max_ang: float = 2.0, gain: float = 4.0, damping: float = 0.05):
        self.env = env
        self.model, self.data = env.model, env.data
        self.site = env.model.site(km.END_EFFECTOR_SITE).id
        self.max_lin, self.max_ang, self.gain, self.damping = max_lin, max_ang, gain, damping
        # a comfortable posture for the null space: the rest pose, shoulder lifted off its limit
        self.posture = km.INIT_QPOS[:7] + np.array([0.0, 0.25, 0.0, 0.0, 0.0, 0.0, 0.0])
        self.lo = env.model.jnt_range[:7, 0].copy()
        self.hi = env.model.jnt_range[:7, 1].copy()
        self.margin = 0.03
        self._jacp = np.zeros((3, env.model.nv))
        self._jacr = np.zeros((3, env.model.nv))
        self.integral = np.zeros(3)
        self._scratch: mujoco.MjData | None = None  # for inverse kinematics (made on first use)

    def reset(self) -> None:
        """Forget the integral (a new target)."""
        self.integral[:] = 0.0

    def action(self, pos: np.ndarray, rot: np.ndarray, grip: float, speed: float = 1.0,
               integral: bool = True, straight: bool = False) -> np.ndarray:
        d = self.data
        jac = self._jacobian(d)
        ep = pos - d.site_xpos[self.site]
        er = orientation_error(rot, d.site_xmat[self.site].reshape(3, 3))
        if integral and np.linalg.norm(ep) < self.INTEGRAL_ZONE:
            self.integral = np.clip(self.integral + ep, -self.INTEGRAL_MAX, self.INTEGRAL_MAX)
        v = self.gain * ep + self.INTEGRAL_GAIN * self.integral
        w = self.gain * er
        lin_lim, ang_lim = self.max_lin * speed, self.max_ang * speed
        if np.linalg.norm(v) > lin_lim:
            v *= lin_lim / np.linalg.norm(v)
        if np.linalg.norm(w) > ang_lim:
            w *= ang_lim / np.linalg.norm(w)
        twist = np.concatenate([v, self.ROT_WEIGHT * w])
        q = d.qpos[:7]
        rest = (self.posture - q) * self.POSTURE_GAIN
        free = np.ones(7, dtype=bool)
        weight = self._limit_weights(q)
        for _ in range(3):  # drop joints that would be pushed further into their limits, re-solve
            qdot = self._solve(jac, twist, weight * free, rest)
            blocked = ((q <= self.lo + self.margin) & (qdot < 0)) | ((q >= self.hi - self.margin) & (qdot > 0))
            if not (blocked & free).any():
                break
            free &= ~blocked
        qdot[~free] = 0.0
        return self._to_action(qdot, grip, straight)

    def _jacobian(self, data: mujoco.MjData) -> np.ndarray:
        """(6, 7) site Jacobian of the arm joints; orientation rows count less than position rows
        (rad vs m): reach the point first."""
        mujoco.mj_jacSite(self.model, data, self._jacp, self._jacr, self.site)
        return np.vstack([self._jacp[:, :7], self.ROT_WEIGHT * self._jacr[:, :7]])

    def _limit_weights(self, q: np.ndarray) -> np.ndarray:
        """Soft joint-limit avoidance: joints close to a limit take a smaller share of the motion."""
        return np.clip(np.minimum(q - self.lo, self.hi - q) / 0.3, 0.1, 1.0)

    def _solve(self, jac: np.ndarray, twist: np.ndarray, w: np.ndarray, rest: np.ndarray) -> np.ndarray:
        """Weighted damped least squares for ``twist``, plus ``rest`` projected into the null space."""
        jw = jac * w
        jjt = jw @ jac.T + self.damping**2 * np.eye(6)
        qdot = w * (jac.T @ np.linalg.solve(jjt, twist))
        null = np.diag(w) - jw.T @ np.linalg.solve(jjt, jac * w)
        return qdot + null @ rest

    def _to_action(self, qdot: np.ndarray, grip: float, straight: bool = False) -> np.ndarray:
        """Joint velocities (rad/s) as the env's normalized action; ``straight``: when a joint
        saturates, slow all of them together so the motion keeps its direction."""
        act = np.empty(9)
        act[:7] = qdot / (ACTION_SCALE * self.TRACKING)
        if straight:
            peak = np.abs(act[:7]).max()
            if peak > 1.0:
                act[:7] /= peak
        act[7:] = grip
        return np.clip(act, -1.0, 1.0)

    def joint_action(self, q_target: np.ndarray, grip: float, speed: float = 1.0) -> np.ndarray:
        """Straight-line joint-space motion towards ``q_target`` (rad), proportional with a speed cap."""
        dq = np.asarray(q_target) - self.data.qpos[:7]
        qdot = self.gain * dq
        peak = np.abs(qdot).max()
        cap = self.JOINT_SPEED * speed
        if peak > cap:
            qdot *= cap / peak  # scale all joints together: a straight line in joint space
        return self._to_action(qdot, grip)

    def solve_ik(self, pos: np.ndarray, rot: np.ndarray, q_seed: np.ndarray, iters: int = 150):
        """Arm joints putting the site at ``pos``/``rot``: damped least squares from ``q_seed`` on a
        scratch copy of the state (the simulation is not touched), with the joint-limit weighting of
        :meth:`action` and a null-space pull towards the rest posture.  Returns ``(q, position error m,
        rotation error rad)``."""
        if self._scratch is None:
            self._scratch = mujoco.MjData(self.model)
        s = self._scratch
        s.qpos[:] = self.data.qpos
        q = np.array(q_seed, dtype=float)
        for _ in range(iters):
            s.qpos[:7] = q
            mujoco.mj_kinematics(self.model, s)
            mujoco.mj_comPos(self.model, s)
            jac = self._jacobian(s)
            er = orientation_error(rot, s.site_xmat[self.site].reshape(3, 3))
            twist = np.concatenate([pos - s.site_xpos[self.site], self.ROT_WEIGHT * er])
            rest = self.IK_POSTURE_GAIN * (self.posture - q)
            q = np.clip(q + self._solve(jac, twist, self._limit_weights(q), rest), self.lo + 0.05, self.hi - 0.05)
        s.qpos[:7] = q
        mujoco.mj_kinematics(self.model, s)
        err = float(np.linalg.norm(pos - s.site_xpos[self.site]))
        rot_err = float(np.linalg.norm(orientation_error(rot, s.site_xmat[self.site].reshape(3, 3))))
        return q, err, rot_err

    def best_roll(self, rot: np.ndarray, room: float = 0.0) -> bool:
        """Whether to use ``rot`` turned half a turn about the gripper axis instead (the parallel
        gripper is symmetric): pick the roll that keeps the last joint away from its limits and
        turns the hand least."""
        z = self.data.site_xmat[self.site].reshape(3, 3)[:, 2]
        q7, lo, hi = self.data.qpos[6], self.lo[6] + 0.25, self.hi[6] - 0.25
        best, best_cost = False, np.inf
        for flip in (False, True):
            r = rot @ rot_z(np.pi) if flip else rot
            turn = float(orientation_error(r, self.data.site_xmat[self.site].reshape(3, 3)) @ z)
            q_after = q7 + turn
            cost = abs(turn) + (10.0 if not (lo <= q_after and q_after + room <= hi) else 0.0)
            if cost < best_cost:
                best, best_cost = flip, cost
        return best

    def reached(self, pos: np.ndarray, rot: np.ndarray, tol: float, rot_tol: float) -> bool:
        d = self.data
        ep = np.linalg.norm(pos - d.site_xpos[self.site])
        er = np.linalg.norm(orientation_error(rot, d.site_xmat[self.site].reshape(3, 3)))
        return ep < tol and er < rot_tol


# --- subtask scripts ----------------------------------------------------------------------------
def _approach_dir(rot: np.ndarray) -> np.ndarray:
    return rot[:, 2]


def _never(ctx: Context) -> bool:
    return False


def _hold(name: str, grip: float, steps: int) -> Phase:
    """Stay where the gripper is for ``steps`` steps (e.g. while the fingers close)."""
    return Phase(name, lambda c: (c.ee_pos, c.ee_rot), grip=grip, done=_never, max_steps=steps, freeze=True)


def _fixed(pos: np.ndarray, rot: np.ndarray):
    pos, rot = np.array(pos, dtype=float), np.array(rot, dtype=float)
    return lambda ctx: (pos, rot)


def _grasp_and_swing(ctx: Context, hinge_body: str, handle_site: str, joint: str, goal: float, rot: np.ndarray,
                     lead: float, depth: float, wrist_follow: float = 0.5, dz: tuple[float, float] = (-0.04, 0.04),
                     enough: float | None = None) -> Iterator[Phase]:
    """Grasp a handle on a hinged door and swing it along its arc to ``goal`` (joint value)."""
    handle = ctx.site(handle_site) + np.array([0, 0, ctx.rng.uniform(*dz)])
    n = _approach_dir(rot)
    yield Phase("pre-grasp", _fixed(handle - (0.12 + ctx.rng.uniform(0, 0.04)) * n, rot), tol=0.03, rot_tol=0.25)
    yield Phase("reach", _fixed(handle + depth * n, rot), tol=0.012, max_steps=30, speed=0.8, straight=True)
    yield Phase("grasp", _fixed(handle + depth * n, rot), grip=CLOSE, done=_never, max_steps=4)
    hinge = ctx.body_pos(hinge_body)
    q0 = ctx.joint(joint)
    grip_offset = (handle + depth * n) - hinge
    sign = np.sign(goal - q0)

    def swing(c: Context):
        q = c.joint(joint)
        qt = q + sign * lead
        qt = min(qt, goal) if sign > 0 else max(qt, goal)
        # the handle is a vertical bar: the fingers can slide around it, so the hand only turns
        # with part of the door's rotation (less arm reconfiguration, as people do)
        return hinge + rot_z(qt - q0) @ grip_offset, rot_z(wrist_follow * (qt - q0)) @ rot

    enough = goal if enough is None else enough
    history: list[float] = []

    def swung(c: Context) -> bool:
        q = c.joint(joint)
        history.append(q)
        if sign * (q - enough) >= 0:
            return True
        # stalled (the arm is at the end of its reach) once far enough for the subtask to count
        stalled = len(history) > 8 and abs(history[-1] - history[-6]) < 0.01
        return stalled and sign * (q - (enough - sign * 0.12)) >= 0

    yield Phase("swing", swing, grip=CLOSE, done=swung, max_steps=50)
    yield _hold("release", OPEN, 3)
    yield Phase("retreat", lambda c: (c.ee_pos - 0.12 * c.ee_rot[:, 2], c.ee_rot), tol=0.04, rot_tol=9, max_steps=15, freeze=True)


def microwave(ctx: Context) -> Iterator[Phase]:
    yaw = np.arctan2(-ctx.body_mat("microdoorroot")[0, 1], ctx.body_mat("microdoorroot")[1, 1])
    rot = rot_z(yaw) @ R_FORWARD
    yield from _grasp_and_swing(ctx, "microdoorroot", "microhandle_site", "microwave", -0.72, rot, 0.4, 0.015,
                                enough=-0.62)


def hinge_cabinet(ctx: Context) -> Iterator[Phase]:
    yield from _grasp_and_swing(ctx, "hingerightdoor", "hinge_site2", "right_hinge_cabinet", 1.6, R_FORWARD, 0.35,
                                0.015, dz=(-0.10, -0.03), enough=1.45)


def slide_cabinet(ctx: Context) -> Iterator[Phase]:
    handle = ctx.site("slide_site") + np.array([0, 0, ctx.rng.uniform(-0.05, 0.05)])
    rot = R_FORWARD
    n = _approach_dir(rot)
    yield Phase("pre-grasp", _fixed(handle - (0.12 + ctx.rng.uniform(0, 0.04)) * n, rot), tol=0.03, rot_tol=0.25)
    yield Phase("reach", _fixed(handle + 0.015 * n, rot), tol=0.012, max_steps=30, speed=0.8, straight=True)
    yield Phase("grasp", _fixed(handle + 0.015 * n, rot), grip=CLOSE, done=_never, max_steps=4)
    target = ctx.rng.uniform(0.36, 0.42)

    def pull(c: Context):
        q = c.joint("slide_cabinet")
        return handle + 0.015 * n + np.array([min(q + 0.12, target), 0, 0]), rot

    yield Phase("slide", pull, grip=CLOSE, done=lambda c: c.joint("slide_cabinet") >= target - 0.03, max_steps=50,
                speed=0.7)
    yield _hold("release", OPEN, 3)
    yield Phase("retreat", lambda c: (c.ee_pos - 0.12 * n, rot), tol=0.04, rot_tol=9, max_steps=15, freeze=True)


def _knob(ctx: Context, knob_body: str, joint: str, goal: float) -> Iterator[Phase]:
    # the knob's ridge sticks out 3.6 cm from its plate; the fingertips stop just short of the plate
    plate = ctx.body_pos(knob_body) + np.array([0, -0.021, 0])
    center = plate - np.array([0, FINGERTIP + 0.008, 0])
    rot = R_FORWARD  # fingers across the ridge
    n = _approach_dir(rot)
    # the wrist turns the knob by ~1.2 rad: approach with the hand roll that leaves the last joint room
    yield Phase("pre-grasp", _fixed(center - (0.10 + ctx.rng.uniform(0, 0.04)) * n, rot), tol=0.03, rot_tol=0.25,
                roll_room=1.3)
    yield Phase("reach", _fixed(center, rot), tol=0.02, max_steps=20, speed=0.8, roll_room=1.3)
    yield Phase("grasp", _fixed(center, rot), grip=CLOSE, done=_never, max_steps=4)

    def turn(c: Context):
        angle = -c.joint(joint)  # the knob turns about -y; the gripper turns about +y
        return center, rot_y(min(angle + 0.8, -goal + 0.5)) @ rot  # the grip slips ~0.3 rad

    history: list[float] = []

    def turned(c: Context) -> bool:
        q = c.joint(joint)
        history.append(q)
        stalled = len(history) > 6 and abs(history[-1] - history[-5]) < 0.01
        return q <= goal + 0.15 or (stalled and q <= goal + 0.3)

    flipped = {}

    def turn_same_roll(c: Context):  # keep the roll the hand grasped with
        pos, r = turn(c)
        if "flip" not in flipped:
            flipped["flip"] = np.linalg.norm(orientation_error(r, c.ee_rot)) > np.pi / 2
        return pos, (r @ rot_z(np.pi) if flipped["flip"] else r)

    yield Phase("turn", turn_same_roll, grip=CLOSE, done=turned, max_steps=30, speed=0.8, any_roll=False)
    yield _hold("release", OPEN, 3)
    yield Phase("retreat", lambda c: (c.ee_pos - 0.10 * n, c.ee_rot), tol=0.04, rot_tol=9, max_steps=15, freeze=True)


def bottom_burner(ctx: Context) -> Iterator[Phase]:
    yield from _knob(ctx, "knob 2", "knob_Joint_2", -1.0)


def top_burner(ctx: Context) -> Iterator[Phase]:
    yield from _knob(ctx, "knob 4", "knob_Joint_4", -1.0)


def light_switch(ctx: Context) -> Iterator[Phase]:
    tip = ctx.site("light_site")
    rot = R_FORWARD  # (the half-turned hand would need the 5th joint past its limit to push)
    # push a little below the lever's axis so the fingers do not ride over it
    side = np.array([0.05 + ctx.rng.uniform(0, 0.01), 0.0, ctx.rng.uniform(-0.012, -0.004)])
    yield Phase("pre-push", _fixed(tip + side + np.array([0, -0.10, 0]), rot), grip=CLOSE, tol=0.03, rot_tol=0.25,
                any_roll=False)
    yield Phase("reach", _fixed(tip + side + np.array([0, -0.01, 0]), rot), grip=CLOSE, tol=0.012, rot_tol=0.06,
                max_steps=30, speed=0.8, any_roll=False, integral=False, straight=True)
    yield Phase("push", _fixed(tip + np.array([-0.12, -0.01, side[2]]), rot), grip=CLOSE,
                done=lambda c: c.joint("light_switch") <= -0.6, max_steps=40, speed=0.5, any_roll=False, integral=False)
    yield Phase("retreat", lambda c: (c.ee_pos + np.array([0, -0.12, 0]), rot), grip=CLOSE, tol=0.04, rot_tol=9,
                max_steps=15, freeze=True)


KETTLE_GOAL_HANDLE = np.array([-0.234, 0.748, 1.879])  # handle site with the kettle at its goal pose


def _glide(start: np.ndarray | None, goal: np.ndarray, rot: np.ndarray, steps: int, relative: bool = False):
    """A target that moves from ``start`` (None: where the hand is when the phase starts) to ``goal``
    (``relative``: an offset from the start) over ``steps`` steps with a smooth (cosine) speed
    profile, so carried objects are not jerked."""
    goal = np.asarray(goal, float)
    state = {"start": None if start is None else np.asarray(start, float)}

    def target(ctx: Context):
        if state["start"] is None:
            state["start"] = ctx.ee_pos
        a = state["start"]
        b = a + goal if relative else goal
        u = min(ctx.phase_step / steps, 1.0)
        return a + (b - a) * (0.5 - 0.5 * np.cos(np.pi * u)), rot

    return target


def kettle(ctx: Context) -> Iterator[Phase]:
    """Grasp the handle from the front (palm against it), lift, glide to the top-left burner, set
    it down, let go.  (From above, the knob panel over the top burners is in the way.)"""
    handle = ctx.site("kettle_site") + np.array([ctx.rng.uniform(-0.015, 0.015), 0, 0])
    rot = R_FORWARD_FLAT
    n = _approach_dir(rot)
    up = np.array([0.0, 0.0, 1.0])
    grasp = handle + np.array([0, ctx.rng.uniform(0.0, 0.01), 0])
    offset = grasp - ctx.site("kettle_site")
    yield Phase("pre-grasp", _fixed(grasp - ctx.rng.uniform(0.10, 0.14) * n, rot), tol=0.03, rot_tol=0.2)
    # follow the handle live: the arm may have nudged the kettle on its way
    yield Phase("reach", lambda c: (c.site("kettle_site") + offset, rot), tol=0.01, max_steps=25, speed=0.8,
                straight=True)
    yield _hold("grasp", CLOSE, 5)
    lift = ctx.rng.uniform(0.07, 0.09)
    n_lift = int(ctx.rng.integers(5, 8))
    yield Phase("lift", _glide(None, lift * up, rot, n_lift, relative=True), grip=CLOSE, done=_never,
                max_steps=n_lift + 2)
    goal = KETTLE_GOAL_HANDLE + np.array([ctx.rng.uniform(-0.01, 0.01), ctx.rng.uniform(-0.005, 0.015), 0.0])
    n_carry = int(ctx.rng.integers(18, 26))
    yield Phase("carry", _glide(None, goal + lift * up, rot, n_carry), grip=CLOSE, tol=0.02, rot_tol=0.3,
                min_steps=n_carry, max_steps=n_carry + 15)
    yield Phase("lower", _glide(None, goal + 0.005 * up, rot, n_lift), grip=CLOSE, done=_never,
                max_steps=n_lift + 2)
    yield _hold("release", OPEN, 6)  # the fingers need ~0.4 s to clear the thick handle

    def back_off(c: Context):  # straight back until the fingers are clear of the handle
        p = c.ee_pos
        p[1] = min(p[1], c.site("kettle_site")[1]) - 0.12
        return p, rot

    yield Phase("retreat", back_off, tol=0.03, rot_tol=9, max_steps=15, freeze=True)


SCRIPTS: dict[str, Callable[[Context], Iterator[Phase]]] = {
    "microwave": microwave,
    "kettle": kettle,
    "bottom burner": bottom_burner,
    "top burner": top_burner,
    "light switch": light_switch,
    "slide cabinet": slide_cabinet,
    "hinge cabinet": hinge_cabinet,
}


# --- the policy -----------------------------------------------------------------------------------
# Between subtasks the arm moves in joint space, straight to an inverse-kinematics solution of the
# next subtask's first target found from the rest posture (so the wrist arrives unwound, with the
# roll that leaves the last joint room).  The task-space resolved-rate moves these replace ran one
# joint into its velocity limit while the others idled (a joint saturated in 96% of those steps, the
# hand at 0.34 m/s against a 0.8 m/s command) and carried a wound-round wrist from one subtask to
# the next, leaving handles out of reach.  Measured on the 22 combinations (4, 8 and 6 seeds each):
# four-subtask success 67% / 65% -> 85% / 83% / 82%.
# A joint-space transit is used when the next target is more than TRANSIT_DISTANCE away, always
# before the hinge cabinet (after a knob the hinge's pre-grasp stalled with joint 6 at its limit),
# and before the microwave or the kettle when a wrist joint is more than WOUND (rad) from the rest
# posture (after the slide cabinet or the light switch their handles were out of reach).
TRANSIT_DISTANCE = 0.4
TRANSIT_ALWAYS = ("hinge cabinet",)
TRANSIT_IF_WOUND = ("microwave", "kettle")
WOUND = 0.8
TRANSIT_SPEED = 1.15  # multiplies Controller.JOINT_SPEED (most operators then move at the joints' limit)
TRANSIT_JITTER = 0.015  # m, std of the offset of the transit's end from the target (path variation)


@dataclasses.dataclass(frozen=True)
class Style:
    """One operator's habits for an episode (drawn by :meth:`Style.sample`)."""

    speed: float  # multiplies every phase's speed
    noise: float  # std of the smoothed action noise
    pause_prob: float  # chance of a short pause before a phase
    via_prob: float  # chance of a detour via a random point before an approach

    @staticmethod
    def sample(rng: np.random.Generator) -> "Style":
        return Style(
            speed=float(rng.uniform(0.9, 1.25)),
            noise=float(rng.uniform(0.01, 0.05)),
            pause_prob=float(rng.uniform(0.0, 0.15)),
            via_prob=float(rng.uniform(0.0, 0.3)),
        )


class Demonstrator:
    """Scripted policy solving ``subtasks`` in order; call :meth:`act` once per env step.

    The env must be reset before the policy is made.  ``rng`` drives every random choice.
    """

    def __init__(self, env, subtasks, rng: np.random.Generator, style: Style | None = None):
        self.env = env
        self.subtasks = list(subtasks)
        self.rng = rng
        self.style = style or Style.sample(rng)
        self.ctx = Context(env, rng)
        self.ctrl = Controller(env)
        self._noise = np.zeros(9)
        self._queue = self._phases()
        self._phase: Phase | None = None
        self._frozen = None
        self._flip = False
        self._steps = 0
        self._pause = 0
        self.current_subtask: str | None = None
        self.finished = False
        self.log: list[tuple] = []  # (subtask, phase, steps, final position error) of finished phases

    def _phases(self) -> Iterator[Phase]:
        for k, name in enumerate(self.subtasks):
            self.current_subtask = name
            first = True
            for ph in SCRIPTS[name](self.ctx):
                if first and k > 0:
                    pos, rot = ph.target(self.ctx)
                    far = np.linalg.norm(pos - self.ctx.ee_pos) > TRANSIT_DISTANCE
                    wound = name in TRANSIT_IF_WOUND and self._wrist_wound()
                    if far or wound or name in TRANSIT_ALWAYS:
                        q = self._transit_joints(pos + self.ctx.jitter(TRANSIT_JITTER), rot, ph)
                        yield Phase("transit", lambda c: (c.ee_pos, c.ee_rot), grip=ph.grip, joints=q, tol=0.15,
                                    max_steps=60, speed=TRANSIT_SPEED, freeze=True)
                if first and self.rng.random() < self.style.via_prob:
                    via = self.ctx.ee_pos + self.rng.uniform([-0.08, -0.1, -0.02], [0.08, 0.02, 0.1])
                    yield Phase("via", _fixed(via, self.ctx.ee_rot), grip=ph.grip, tol=0.04, rot_tol=9, max_steps=8)
                first = False
                yield ph
        self.current_subtask = None

    def _wrist_wound(self) -> bool:
        q = self.ctx.data.qpos[4:7]
        return float(np.abs(q - self.ctrl.posture[4:7]).max()) > WOUND

    def _transit_joints(self, pos: np.ndarray, rot: np.ndarray, phase: Phase) -> np.ndarray:
        """Arm joints (rad) putting the hand at ``pos``/``rot``, solved from the rest posture; of the
        two hand rolls (``phase.any_roll``) the one that reaches best and leaves the last joint room."""
        best, best_cost = None, np.inf
        for flip in (False, True) if phase.any_roll else (False,):
            q, err, rot_err = self.ctrl.solve_ik(pos, rot @ rot_z(np.pi) if flip else rot, self.ctrl.posture)
            room = min(q[6] - self.ctrl.lo[6], self.ctrl.hi[6] - q[6] - phase.roll_room)
            cost = err + 0.1 * rot_err + (1.0 if room < 0.2 else 0.0)
            if cost < best_cost:
                best, best_cost = q, cost
        return best

    def _next_phase(self) -> None:
        if self._phase is not None:
            pos, rot = self._target()
            self.log.append((self.current_subtask, self._phase.name, self._steps,
                             round(float(np.linalg.norm(pos - self.ctx.ee_pos)), 3)))
        try:
            self._phase = next(self._queue)
        except StopIteration:
            self._phase = None
            self.finished = True
            return
        self._steps = 0
        self.ctrl.reset()
        self._frozen = self._phase.target(self.ctx) if self._phase.freeze else None
        self._flip = False
        self._flip = self._phase.any_roll and self.ctrl.best_roll(self._target()[1], self._phase.roll_room)
        self._errs: list[float] = []
        self._retried = False
        if self.rng.random() < self.style.pause_prob:
            self._pause = int(self.rng.integers(1, 5))

    def _phase_over(self) -> bool:
        ph = self._phase
        self.ctx.phase_step = self._steps
        if self._steps >= ph.max_steps:
            return True
        if self._steps < ph.min_steps:
            return False
        if ph.joints is not None:
            return float(np.abs(ph.joints - self.ctx.env.data.qpos[:7]).max()) < ph.tol
        if ph.done is not None:
            return ph.done(self.ctx)
        pos, rot = self._target()
        return self.ctrl.reached(pos, rot, ph.tol, ph.rot_tol)

    def _target(self) -> tuple[np.ndarray, np.ndarray]:
        pos, rot = self._frozen if self._frozen is not None else self._phase.target(self.ctx)
        return pos, (rot @ rot_z(np.pi) if self._flip else rot)

    def act(self) -> np.ndarray:
        if self._phase is None and not self.finished:
            self._next_phase()
        while self._phase is not None and self._phase_over():
            self._next_phase()
        if self._phase is None:  # all done: hold still, gripper open
            hold = np.zeros(9)
            hold[7:] = OPEN
            return hold
        ph = self._phase
        self.ctx.phase_step = self._steps
        pos, rot = self._target()
        # stuck (a wrist joint at its limit)? try once with the hand turned the other way round
        self._errs.append(float(np.linalg.norm(pos - self.ctx.ee_pos)))
        if (ph.any_roll and ph.name.startswith("pre") and not self._retried and len(self._errs) > 8
                and self._errs[-1] > 2 * ph.tol and self._errs[-7] - self._errs[-1] < 0.005):
            self._flip, self._retried = not self._flip, True
            pos, rot = self._target()
        self._steps += 1
        if self._pause > 0:
            self._pause -= 1
            act = np.zeros(9)
            act[7:] = ph.grip
        elif ph.joints is not None:
            act = self.ctrl.joint_action(ph.joints, ph.grip, ph.speed * self.style.speed)
        else:
            act = self.ctrl.action(pos, rot, ph.grip, ph.speed * self.style.speed, ph.integral,
                                   ph.straight)
        self._noise = 0.7 * self._noise + 0.3 * self.rng.normal(0.0, self.style.noise, size=9)
        act[:7] += self._noise[:7]
        return np.clip(act, -1.0, 1.0).astype(np.float32)
