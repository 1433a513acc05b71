"""The gait controller's view of one control step (:class:`GaitState`): the privileged
observations turned into the horizontal frame H the controller plans in, and the roll /
pitch rotation (:func:`rot_rp`) between H and the base frame."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from msta.data.math3d import quat_to_mat, yaw_of
from msta.data.robot import A1, RobotDescription
from msta.policies.teacher.gait_terrain import (
    body_reference,
    dilate,
    roughness,
    scan_grid,
)


@dataclass
class GaitState:
    """Privileged state of one control step, in the frames the gait controller uses
    (H: origin at the base, yaw-aligned, z up)."""

    n: int
    cmd: np.ndarray        # (N, 3)
    v: np.ndarray          # (N, 3) base velocity in H
    w: np.ndarray          # (N, 3) base angular velocity in H
    rot_rp: np.ndarray     # (N, 3, 3) base -> H (roll and pitch only)
    rp: np.ndarray         # (N, 2) roll, pitch (rad)
    grid: np.ndarray       # (N, 17, 11) height scan
    dilated: np.ndarray    # (N, 17, 11) height scan, 3 x 3 max filter
    ref: np.ndarray        # (N,) mean ground under the body, relative to the base
    height: np.ndarray     # (N,) base height above ref
    slope: np.ndarray      # (N, 2) ground gradient dz/dx, dz/dy in H
    dyn: np.ndarray        # (N, 8)
    rp_des: np.ndarray     # (N, 2) desired roll, pitch
    feet_actual: np.ndarray  # (N, 4, 3) measured foot positions in H (joint angles + attitude)
    roughness: np.ndarray  # (N,) largest second difference of the scan near the base (m)

    @classmethod
    def from_obs(cls, obs: dict[str, np.ndarray], robot: RobotDescription = A1,
                 slope_follow: float = 0.0) -> GaitState:
        """The state of a batch of (teacher-view) observations.

        Args:
            obs: registry-keyed observations holding the gait teacher's sensors.
            robot: whose legs (the measured feet's forward kinematics).
            slope_follow: fraction of the ground slope the desired attitude follows.
        """
        quat = np.asarray(obs["orientation"], dtype=np.float64)
        quat = quat / np.linalg.norm(quat, axis=1, keepdims=True)
        rot = quat_to_mat(quat)
        yaw = yaw_of(quat)
        c, s = np.cos(yaw), np.sin(yaw)
        rz_t = np.zeros_like(rot)
        rz_t[:, 0, 0], rz_t[:, 0, 1], rz_t[:, 1, 0], rz_t[:, 1, 1] = c, s, -s, c
        rz_t[:, 2, 2] = 1.0
        rot_rp = rz_t @ rot
        v = np.einsum("nij,nj->ni", rot_rp, obs["base_lin_vel"].astype(np.float64))
        w = np.einsum("nij,nj->ni", rot_rp, obs["base_ang_vel"].astype(np.float64))
        roll = np.arctan2(rot_rp[:, 2, 1], rot_rp[:, 2, 2])
        pitch = -np.arcsin(np.clip(rot_rp[:, 2, 0], -1, 1))
        grid = scan_grid(obs["height_scan"])
        ref = body_reference(grid)
        gx = (grid[:, 11:14].mean(axis=(1, 2)) - grid[:, 3:6].mean(axis=(1, 2))) / 0.8
        gy = (grid[:, :, 7:10].mean(axis=(1, 2)) - grid[:, :, 1:4].mean(axis=(1, 2))) / 0.6
        return cls(n=len(quat), cmd=obs["command"].astype(np.float64), v=v, w=w, rot_rp=rot_rp,
                   rp=np.column_stack([roll, pitch]), grid=grid, dilated=dilate(grid), ref=ref, height=-ref,
                   slope=np.column_stack([gx, gy]), dyn=obs["dynamics"].astype(np.float64),
                   rp_des=slope_follow * np.column_stack([np.arctan(gy), -np.arctan(gx)]),
                   feet_actual=np.einsum("nij,nkj->nki", rot_rp, robot.foot_positions_body(
                       obs["joint_pos"].astype(np.float64)).reshape(len(quat), 4, 3)),
                   roughness=roughness(grid))


def rot_rp(rp: np.ndarray) -> np.ndarray:
    """(N, 2) roll, pitch -> (N, 3, 3) rotation Ry(pitch) Rx(roll) (base -> H)."""
    cr, sr = np.cos(rp[:, 0]), np.sin(rp[:, 0])
    cp, sp = np.cos(rp[:, 1]), np.sin(rp[:, 1])
    out = np.zeros((len(rp), 3, 3))
    out[:, 0, 0], out[:, 0, 1], out[:, 0, 2] = cp, sp * sr, sp * cr
    out[:, 1, 1], out[:, 1, 2] = cr, -sr
    out[:, 2, 0], out[:, 2, 1], out[:, 2, 2] = -sp, cp * sr, cp * cr
    return out


__all__ = ["GaitState", "rot_rp"]
