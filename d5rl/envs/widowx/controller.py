"""Analytic inverse kinematics of the WidowX 250 with its gripper pointing straight down.

The controlled end-effector pose is ``(x, y, z, yaw)``: the position of the ``tip``
site (``ee_gripper_link``) in the robot base frame and ``yaw``, the world angle of
the fingers' closing axis.  With the gripper vertical the six joints follow in
closed form: the waist points at the target, shoulder and elbow solve a planar
two-link problem (elbow up) for the wrist, the wrist angle keeps the gripper
vertical, the forearm roll stays 0 and the wrist rotation sets the yaw.

The env stores the joint targets in ``data.ctrl``, so the commanded pose is always
``fk(ctrl)``: the stored simulator state alone determines what the next action
does (no hidden controller state).
"""

from __future__ import annotations

import math

import numpy as np

from d5rl.envs.widowx.model import FOREARM, SHOULDER_HEIGHT, UPPER_ARM, WRIST_TO_TIP

L1 = math.hypot(*UPPER_ARM)
L2 = FOREARM
ALPHA_U = math.atan2(UPPER_ARM[1], UPPER_ARM[0])  # direction of the upper arm at shoulder = 0

# Reachable box for the tip (m); the IK is exact inside it.
WORKSPACE_LOW = np.array([0.10, -0.36, 0.02])
WORKSPACE_HIGH = np.array([0.45, 0.36, 0.27])
RADIUS_RANGE = (0.14, 0.45)
WRIST_ROTATE_LIMIT = math.pi - 0.05


def clip_to_workspace(pos: np.ndarray) -> np.ndarray:
    p = np.clip(np.asarray(pos, dtype=np.float64), WORKSPACE_LOW, WORKSPACE_HIGH)
    r = math.hypot(p[0], p[1])
    # the wrist must stay within the arm's length of the shoulder
    dz = p[2] + WRIST_TO_TIP - SHOULDER_HEIGHT
    r_max = min(RADIUS_RANGE[1], math.sqrt(max((L1 + L2 - 0.005) ** 2 - dz * dz, 0.0)))
    r_clipped = min(max(r, RADIUS_RANGE[0]), r_max)
    if r > 1e-9 and r_clipped != r:
        p[:2] *= r_clipped / r
    return p


def wrap_yaw(yaw: float, waist: float) -> float:
    """The equivalent closing-axis yaw (mod pi) whose wrist rotation is within limits and closest to 0."""
    psi = waist + math.pi / 2 - yaw
    psi = (psi + math.pi / 2) % math.pi - math.pi / 2  # the gripper is symmetric: psi mod pi
    return waist + math.pi / 2 - psi


def ik(pose: np.ndarray) -> np.ndarray:
    """Joint angles (6) putting the tip at ``pose[:3]`` with closing-axis yaw ``pose[3]``, gripper down."""
    x, y, z, yaw = (float(v) for v in pose)
    waist = math.atan2(y, x)
    r = math.hypot(x, y)
    # wrist_angle joint sits WRIST_TO_TIP above the tip
    dr, dz = r, z + WRIST_TO_TIP - SHOULDER_HEIGHT
    d = math.hypot(dr, dz)
    d = min(max(d, abs(L1 - L2) + 1e-6), L1 + L2 - 1e-6)
    beta = math.acos(max(-1.0, min(1.0, (L1 * L1 + d * d - L2 * L2) / (2 * L1 * d))))
    a1 = math.atan2(dz, dr) + beta  # upper-arm direction, elbow up
    er, ez = L1 * math.cos(a1), L1 * math.sin(a1)
    a2 = math.atan2(dz - ez, dr - er)  # forearm direction
    shoulder = ALPHA_U - a1
    elbow = -a2 - shoulder
    wrist_angle = math.pi / 2 - shoulder - elbow
    psi = waist + math.pi / 2 - yaw
    psi = max(-WRIST_ROTATE_LIMIT, min(WRIST_ROTATE_LIMIT, psi))
    return np.array([waist, shoulder, elbow, 0.0, wrist_angle, psi])


def fk(q: np.ndarray) -> np.ndarray:
    """``(x, y, z, yaw)`` of the tip for arm joints ``q`` (6), assuming the gripper points down."""
    waist, shoulder, elbow, _, _, psi = (float(v) for v in q[:6])
    a1 = ALPHA_U - shoulder
    a2 = -(shoulder + elbow)
    r = L1 * math.cos(a1) + L2 * math.cos(a2)
    z = SHOULDER_HEIGHT + L1 * math.sin(a1) + L2 * math.sin(a2) - WRIST_TO_TIP
    return np.array([r * math.cos(waist), r * math.sin(waist), z, waist + math.pi / 2 - psi])
