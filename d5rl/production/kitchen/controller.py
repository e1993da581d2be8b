"""Resolved-rate control of the kitchen Franka's ``end_effector`` site (damped least squares on the
site Jacobian, null-space pull to a comfortable posture, joint-limit weighting) and the inverse
kinematics that shares its step; rotation helpers and the gripper orientations the scripts use."""

from __future__ import annotations

import mujoco
import numpy as np

from d5rl.envs.kitchen import model as km
from d5rl.envs.kitchen.task import ACTION_SCALE


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

    def action(
        self,
        pos: np.ndarray,
        rot: np.ndarray,
        grip: float,
        speed: float = 1.0,
        integral: bool = True,
        straight: bool = False,
    ) -> np.ndarray:
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
