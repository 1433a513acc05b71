"""Leg kinematics for the gait teacher: batched analytic inverse kinematics and the foot
Jacobian of a robot's legs (forward kinematics is ``RobotDescription.foot_positions_body``).

Conventions follow :meth:`msta.data.robot.RobotDescription.foot_positions_body`: per leg,
the hip joint rotates about the body x axis, thigh and calf about the (hip-rotated) y
axis; a positive thigh angle swings the foot backward; the calf is bent with negative
angles. Every function takes the robot (default: the A1).
"""

from __future__ import annotations

import numpy as np

from msta.data.robot import A1, JOINTS_PER_LEG, RobotDescription

#: Closest hip-to-foot distance (in the leg plane) the IK allows.
MIN_REACH = 0.12
#: How much shorter than the straight leg the farthest reach is (m).
REACH_MARGIN = 0.015


def max_reach(robot: RobotDescription = A1) -> float:
    """Farthest hip-to-foot distance (in the leg plane) the IK allows (m).

    Args:
        robot: whose leg lengths.
    """
    return robot.thigh_length + robot.calf_length - REACH_MARGIN


#: The A1's farthest reach.
MAX_REACH = max_reach(A1)


def leg_ik(feet: np.ndarray, robot: RobotDescription = A1) -> np.ndarray:
    """Joint angles that put the feet at the given body-frame positions.

    Unreachable targets are projected onto the reachable shell (the leg straightens or
    folds as far as allowed), so the output is always finite.

    Args:
        feet: (N, legs, 3) foot sphere centres in the base frame, legs in ``robot.feet`` order.
        robot: whose legs.
    Returns:
        (N, joints) joint angles in ``robot.joints`` order (hip, thigh, calf per leg).
    """
    hips = np.asarray(robot.hip_offsets, dtype=np.float64)               # (legs, 2)
    rel = feet - np.concatenate([hips, np.zeros((len(hips), 1))], axis=1)[None]
    x, y, z = rel[..., 0], rel[..., 1], rel[..., 2]
    yo = np.asarray(robot.thigh_offset_y, dtype=np.float64)[None, :]
    # Hip roll: [y, z] = R(hip) [yo, z_leg] with z_leg < 0 the in-plane leg height.
    r2 = np.maximum(y * y + z * z, yo * yo + MIN_REACH ** 2 * 0.25)
    z_leg = -np.sqrt(r2 - yo * yo)
    hip = np.arctan2(z, y) - np.arctan2(z_leg, yo)
    hip = (hip + np.pi) % (2 * np.pi) - np.pi
    # Planar two-link leg in (x, z_leg).
    reach = max_reach(robot)
    d = np.hypot(x, z_leg)
    scale = np.clip(d, MIN_REACH, reach) / np.maximum(d, 1e-9)
    x, z_leg, d = x * scale, z_leg * scale, np.clip(d, MIN_REACH, reach)
    l1, l2 = robot.thigh_length, robot.calf_length
    cos_c = np.clip((d * d - l1 * l1 - l2 * l2) / (2 * l1 * l2), -1.0, 1.0)
    calf = -np.arccos(cos_c)
    a, b = l1 + l2 * np.cos(calf), l2 * np.sin(calf)
    thigh = np.arctan2(-x, -z_leg) - np.arctan2(b, a)
    return np.stack([hip, thigh, calf], axis=-1).reshape(len(feet), robot.num_joints)


def foot_jacobian(q: np.ndarray, robot: RobotDescription = A1, eps: float = 1e-5) -> np.ndarray:
    """Per-leg foot Jacobians d(foot position in base frame) / d(leg joint angles).

    Args:
        q: (N, joints) joint angles.
        robot: whose legs.
        eps: central-difference step (rad).
    Returns:
        (N, legs, 3, 3): [n, leg, xyz, joint (hip, thigh, calf)].
    """
    n, legs = len(q), len(robot.feet)
    jac = np.empty((n, legs, 3, JOINTS_PER_LEG))
    for j in range(JOINTS_PER_LEG):
        dq = np.zeros(robot.num_joints)
        dq[j::JOINTS_PER_LEG] = eps
        plus = robot.foot_positions_body(q + dq).reshape(n, legs, 3)
        minus = robot.foot_positions_body(q - dq).reshape(n, legs, 3)
        jac[..., j] = (plus - minus) / (2 * eps)
    return jac


__all__ = ["MAX_REACH", "MIN_REACH", "REACH_MARGIN", "foot_jacobian", "leg_ik", "max_reach"]
