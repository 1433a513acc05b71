"""legged_gym-style rewards. Each scale key ``k`` maps to a function ``_reward_k``.

Every term is multiplied by its scale and by the control dt, as in legged_gym. The paper's
three per-step metrics are reported separately: the linear- and angular-velocity tracking
terms and the total.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields

import numpy as np


@dataclass
class RewardScales:
    """Scale per reward term (0 disables a term). Names follow legged_gym.

    Args:
        tracking_lin_vel: exp(-|v_xy - cmd_xy|^2 / sigma) linear-velocity tracking.
        tracking_ang_vel: exp(-(w_z - cmd_yaw)^2 / sigma) yaw-rate tracking.
        lin_vel_z: penalty on the base's vertical speed squared.
        ang_vel_xy: penalty on roll and pitch rates squared.
        torques: penalty on the summed squared joint torques.
        dof_acc: penalty on the summed squared joint accelerations.
        feet_air_time: bonus (air time - air_time_target) per touchdown while the command
            asks to move (|cmd_xy| > 0.1 m/s).
        collision: penalty per thigh or calf in contact.
        action_rate: penalty on the squared change of the action.
        dof_pos_limits: penalty on the summed distance of joints beyond their soft limits.
        termination: penalty (a negative scale) on a step that ends its episode in a fall, not
            in a timeout. It is added after the ``only_positive`` clip, as in legged_gym, so
            the clip cannot hide it. Off by default.
    """

    tracking_lin_vel: float = 1.0
    tracking_ang_vel: float = 0.5
    lin_vel_z: float = -2.0
    ang_vel_xy: float = -0.05
    torques: float = -2e-4
    dof_acc: float = -2.5e-7
    feet_air_time: float = 1.0
    collision: float = -1.0
    action_rate: float = -0.01
    dof_pos_limits: float = -10.0
    termination: float = 0.0


@dataclass
class RewardConfig:
    """Args:
        scales: per-term scales.
        tracking_sigma: sigma^2 of the exp(-err^2 / sigma) tracking kernels.
        only_positive: clip the total at 0 (legged_gym ``only_positive_rewards``).
        soft_dof_pos_limit: fraction of the joint range inside which no limit penalty applies.
        air_time_target: s, feet-air-time bonus is (air time - target) at touchdown.
    """

    scales: RewardScales = field(default_factory=RewardScales)
    tracking_sigma: float = 0.25
    only_positive: bool = True
    soft_dof_pos_limit: float = 0.9
    air_time_target: float = 0.5


@dataclass
class RewardInputs:
    """Quantities of one control step, all batched over N environments."""

    lin_vel: np.ndarray        # (N, 3) base frame
    ang_vel: np.ndarray        # (N, 3) base frame
    command: np.ndarray        # (N, 3)
    torques: np.ndarray        # (N, 12)
    joint_pos: np.ndarray      # (N, 12)
    joint_vel: np.ndarray      # (N, 12)
    last_joint_vel: np.ndarray  # (N, 12)
    action: np.ndarray         # (N, 12)
    last_action: np.ndarray    # (N, 12)
    leg_collisions: np.ndarray  # (N, 8) contact force on thighs and calves
    first_contact: np.ndarray  # (N, 4) bool, touchdown this step
    air_time: np.ndarray       # (N, 4) s in the air before this touchdown
    soft_limits: np.ndarray    # (12, 2)
    dt: float
    sigma: float
    air_time_target: float
    fell: np.ndarray           # (N,) bool, the episode ends in a fall this step


def _reward_tracking_lin_vel(x: RewardInputs) -> np.ndarray:
    err = np.sum((x.command[:, :2] - x.lin_vel[:, :2]) ** 2, axis=1)
    return np.exp(-err / x.sigma)


def _reward_tracking_ang_vel(x: RewardInputs) -> np.ndarray:
    return np.exp(-((x.command[:, 2] - x.ang_vel[:, 2]) ** 2) / x.sigma)


def _reward_lin_vel_z(x: RewardInputs) -> np.ndarray:
    return x.lin_vel[:, 2] ** 2


def _reward_ang_vel_xy(x: RewardInputs) -> np.ndarray:
    return np.sum(x.ang_vel[:, :2] ** 2, axis=1)


def _reward_torques(x: RewardInputs) -> np.ndarray:
    return np.sum(x.torques ** 2, axis=1)


def _reward_dof_acc(x: RewardInputs) -> np.ndarray:
    return np.sum(((x.joint_vel - x.last_joint_vel) / x.dt) ** 2, axis=1)


def _reward_feet_air_time(x: RewardInputs) -> np.ndarray:
    bonus = np.sum((x.air_time - x.air_time_target) * x.first_contact, axis=1)
    return bonus * (np.linalg.norm(x.command[:, :2], axis=1) > 0.1)


def _reward_collision(x: RewardInputs) -> np.ndarray:
    return np.sum(x.leg_collisions > 0.1, axis=1).astype(np.float64)


def _reward_action_rate(x: RewardInputs) -> np.ndarray:
    return np.sum((x.action - x.last_action) ** 2, axis=1)


def _reward_dof_pos_limits(x: RewardInputs) -> np.ndarray:
    lo, hi = x.soft_limits[:, 0], x.soft_limits[:, 1]
    out = -np.clip(x.joint_pos - lo, None, 0.0) + np.clip(x.joint_pos - hi, 0.0, None)
    return np.sum(out, axis=1)


def _reward_termination(x: RewardInputs) -> np.ndarray:
    return x.fell.astype(np.float64)


REWARD_TERMS = {f.name: globals()[f"_reward_{f.name}"] for f in fields(RewardScales)}


def soft_limits(limits: np.ndarray, fraction: float) -> np.ndarray:
    """Shrink (12, 2) joint limits around their midpoints to ``fraction`` of the range."""
    mid = limits.mean(axis=1, keepdims=True)
    half = (limits[:, 1:] - limits[:, :1]) / 2 * fraction
    return np.hstack([mid - half, mid + half])


def compute_rewards(cfg: RewardConfig, x: RewardInputs) -> dict[str, np.ndarray]:
    """Per-term scaled rewards plus ``total``, ``lin_vel_tracking`` and ``ang_vel_tracking``.

    Returns:
        dict of (N,) arrays. ``total`` is clipped at 0 when ``only_positive``, before the
        termination penalty is added.
    """
    out: dict[str, np.ndarray] = {}
    total = np.zeros(len(x.command))
    for name, fn in REWARD_TERMS.items():
        scale = getattr(cfg.scales, name)
        if scale == 0.0:
            continue
        out[name] = fn(x) * scale * x.dt
        if name != "termination":
            total += out[name]
    if cfg.only_positive:
        total = np.clip(total, 0.0, None)
    out["total"] = total + out.get("termination", 0.0)
    lin = _reward_tracking_lin_vel(x) * cfg.scales.tracking_lin_vel * x.dt
    ang = _reward_tracking_ang_vel(x) * cfg.scales.tracking_ang_vel * x.dt
    out["lin_vel_tracking"], out["ang_vel_tracking"] = lin, ang
    return out
