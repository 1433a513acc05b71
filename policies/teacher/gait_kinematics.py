"""Leg kinematics of the A1-class robot for the gait teacher: batched analytic inverse
kinematics and the foot Jacobian (forward kinematics is ``msta.data.robot``).

Conventions follow ``msta.data.robot.foot_positions_body``: per leg, the hip joint
rotates about the body x axis, thigh and calf about the (hip-rotated) y axis; a positive
thigh angle swings the foot backward; the calf is bent with negative angles.
"""

from __future__ import annotations

import numpy as np

from msta.data.robot import (
    CALF_LENGTH,
    HIP_OFFSETS,
    NUM_JOINTS,
    THIGH_LENGTH,
    THIGH_OFFSET_Y,
    foot_positions_body,
)

#: Closest and farthest hip-to-foot distance (in the leg plane) the IK allows.
MIN_REACH = 0.12
MAX_REACH = THIGH_LENGTH + CALF_LENGTH - 0.015


def leg_ik(feet: np.ndarray) -> np.ndarray:
    """Joint angles that put the feet at the given body-frame positions.

    Unreachable targets are projected onto the reachable shell (the leg straightens or
    folds as far as allowed), so the output is always finite.

    Args:
        feet: (N, 4, 3) foot sphere centres in the base frame, legs FL, FR, RL, RR.
    Returns:
        (N, 12) joint angles in registry order (hip, thigh, calf per leg).
    """
    rel = feet - np.concatenate([HIP_OFFSETS, np.zeros((4, 1))], axis=1)[None]
    x, y, z = rel[..., 0], rel[..., 1], rel[..., 2]
    yo = THIGH_OFFSET_Y[None, :]
    # Hip roll: [y, z] = R(hip) [yo, z_leg] with z_leg < 0 the in-plane leg height.
    r2 = np.maximum(y * y + z * z, yo * yo + MIN_REACH ** 2 * 0.25)
    z_leg = -np.sqrt(r2 - yo * yo)
    hip = np.arctan2(z, y) - np.arctan2(z_leg, yo)
    hip = (hip + np.pi) % (2 * np.pi) - np.pi
    # Planar two-link leg in (x, z_leg).
    d = np.hypot(x, z_leg)
    scale = np.clip(d, MIN_REACH, MAX_REACH) / np.maximum(d, 1e-9)
    x, z_leg, d = x * scale, z_leg * scale, np.clip(d, MIN_REACH, MAX_REACH)
    l1, l2 = THIGH_LENGTH, CALF_LENGTH
    cos_c = np.clip((d * d - l1 * l1 - l2 * l2) / (2 * l1 * l2), -1.0, 1.0)
    calf = -np.arccos(cos_c)
    a, b = l1 + l2 * np.cos(calf), l2 * np.sin(calf)
    thigh = np.arctan2(-x, -z_leg) - np.arctan2(b, a)
    return np.stack([hip, thigh, calf], axis=-1).reshape(len(feet), NUM_JOINTS)


def foot_jacobian(q: np.ndarray, eps: float = 1e-5) -> np.ndarray:
    """Per-leg foot Jacobians d(foot position in base frame) / d(leg joint angles).

    Args:
        q: (N, 12) joint angles.
        eps: central-difference step (rad).
    Returns:
        (N, 4, 3, 3): [n, leg, xyz, joint (hip, thigh, calf)].
    """
    n = len(q)
    jac = np.empty((n, 4, 3, 3))
    for j in range(3):
        dq = np.zeros(NUM_JOINTS)
        dq[j::3] = eps
        plus = foot_positions_body(q + dq).reshape(n, 4, 3)
        minus = foot_positions_body(q - dq).reshape(n, 4, 3)
        jac[..., j] = (plus - minus) / (2 * eps)
    return jac


__all__ = ["MAX_REACH", "MIN_REACH", "foot_jacobian", "leg_ik"]
