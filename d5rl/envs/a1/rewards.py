"""Reward terms of the A1 tasks (vectorized numpy, shared by the env and dataset relabelling)."""

from __future__ import annotations

import numpy as np

from d5rl.envs.a1.model import ACTION_SCALE, NOMINAL_POSE

SPEED_REWARD_SCALE = 10.0
ENERGY_COEF = 0.01  # walk / run
HIKING_ENERGY_COEF = 0.001
UPRIGHT_MIN = 0.9  # body z-axis "up" component for a full standing term


def tolerance(x, lower, upper, margin, sigmoid="linear", value_at_margin=0.0):
    """1 inside [lower, upper], falling to ``value_at_margin`` at ``margin`` outside (dm_control's
    ``rewards.tolerance``; ``margin`` may be an array, one per entry of ``x``): linear reaches 0 at
    ``margin / (1 - value_at_margin)``, quadratic at ``margin / sqrt(1 - value_at_margin)``, and gaussian
    never does (it needs ``0 < value_at_margin < 1``)."""
    x = np.asarray(x, dtype=np.float64)
    dist = np.where(x < lower, lower - x, np.where(x > upper, x - upper, 0.0))
    if np.ndim(margin) == 0 and margin <= 0:
        return (dist == 0).astype(np.float64)
    d = dist / margin
    if sigmoid == "linear":
        return np.clip(1.0 - d * (1.0 - value_at_margin), 0.0, 1.0)
    if sigmoid == "quadratic":
        s = d * np.sqrt(1.0 - value_at_margin)
        return np.where(s < 1.0, 1.0 - s * s, 0.0)
    if sigmoid == "gaussian":
        if not 0.0 < value_at_margin < 1.0:
            raise ValueError(f"a gaussian tolerance needs 0 < value_at_margin < 1, got {value_at_margin}")
        return np.exp(-0.5 * (d * np.sqrt(-2.0 * np.log(value_at_margin))) ** 2)
    raise ValueError(f"unknown sigmoid {sigmoid!r}")


def standing_term(upright, joint_pos):
    """Upright tolerance (quadratic) times the mean per-joint tolerance around the nominal pose.

    Joints anywhere inside the action range count fully; 0.5 rad beyond it they count 0.
    """
    up = tolerance(upright, UPRIGHT_MIN, np.inf, UPRIGHT_MIN, "quadratic")
    dev = np.asarray(joint_pos) - NOMINAL_POSE
    joints = tolerance(dev, -ACTION_SCALE, ACTION_SCALE, 0.5, "quadratic").mean(axis=-1)
    return up * joints


def standing_term_v1(upright, joint_pos):
    """The release's standing term (v1): upright tolerance (quadratic) times the PRODUCT over the 12
    joints of gaussian tolerances around the nominal pose (flat within ± [0.2, 0.4, 0.4] rad, 0.5 at as
    far again), so one joint far from its band lowers the whole term."""
    up = tolerance(upright, UPRIGHT_MIN, np.inf, UPRIGHT_MIN, "quadratic")
    q = np.asarray(joint_pos, dtype=np.float64)
    joints = tolerance(q, NOMINAL_POSE - ACTION_SCALE, NOMINAL_POSE + ACTION_SCALE, ACTION_SCALE, "gaussian", 0.5)
    return up * joints.prod(axis=-1)


def speed_term(forward_speed, target):
    """Tracking of ``target`` m/s within ±0.1, linear falloff over a margin of ``target``."""
    return tolerance(forward_speed, target - 0.1, target + 0.1, target, "linear")


def speed_reward(forward_speed, standing, energy, target, energy_coef=ENERGY_COEF):
    return SPEED_REWARD_SCALE * speed_term(forward_speed, target) * standing - energy_coef * energy


def heading_term(heading_error):
    return tolerance(heading_error, -np.pi / 12, np.pi / 12, np.pi, "linear")


def hiking_reward(forward_speed, standing, energy, heading_error, target, energy_coef=HIKING_ENERGY_COEF):
    return (
        SPEED_REWARD_SCALE * speed_term(forward_speed, target) * standing * heading_term(heading_error)
        - energy_coef * energy
    )
