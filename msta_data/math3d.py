"""Batched quaternion helpers (MuJoCo's wxyz convention), pure numpy.

Below both the simulator (collect/sim) and the teachers (policies/teacher).
"""

from __future__ import annotations

import numpy as np


def quat_to_mat(q: np.ndarray) -> np.ndarray:
    """(N, 4) wxyz unit quaternions -> (N, 3, 3) rotation matrices (body -> world)."""
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    out = np.empty((len(q), 3, 3))
    out[:, 0, 0] = 1 - 2 * (y * y + z * z)
    out[:, 0, 1] = 2 * (x * y - w * z)
    out[:, 0, 2] = 2 * (x * z + w * y)
    out[:, 1, 0] = 2 * (x * y + w * z)
    out[:, 1, 1] = 1 - 2 * (x * x + z * z)
    out[:, 1, 2] = 2 * (y * z - w * x)
    out[:, 2, 0] = 2 * (x * z - w * y)
    out[:, 2, 1] = 2 * (y * z + w * x)
    out[:, 2, 2] = 1 - 2 * (x * x + y * y)
    return out


def yaw_of(q: np.ndarray) -> np.ndarray:
    """(N, 4) wxyz -> (N,) yaw angle (rad)."""
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    return np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def yaw_quat(yaw: np.ndarray) -> np.ndarray:
    """(N,) yaw -> (N, 4) wxyz quaternion."""
    return np.column_stack([np.cos(yaw / 2), np.zeros_like(yaw), np.zeros_like(yaw),
                            np.sin(yaw / 2)])


def world_to_body(rot: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate (N, 3) world vectors into the body frame given (N, 3, 3) body->world."""
    return np.einsum("nji,nj->ni", rot, v)
