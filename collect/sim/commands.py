"""Velocity commands: vx, vy and a yaw rate that steers toward a sampled heading."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class CommandConfig:
    """Command sampling (legged_gym style, the paper's ranges by default).

    Args:
        lin_vel_x: m/s range of the forward command.
        lin_vel_y: m/s range of the sideways command.
        heading: rad range of the sampled heading; the yaw-rate command is
            ``clip(heading_gain * wrap(heading - yaw), *ang_vel_yaw)``.
        ang_vel_yaw: rad/s cap of the yaw-rate command.
        heading_gain: proportional gain from heading error to yaw rate.
        resample_s: seconds between resamples.
        min_norm: planar commands shorter than this are zeroed (standing still is a command too).
        use_heading: if False, the yaw rate is sampled directly in ``ang_vel_yaw``.
    """

    lin_vel_x: tuple[float, float] = (-1.0, 1.0)
    lin_vel_y: tuple[float, float] = (-1.0, 1.0)
    heading: tuple[float, float] = (-np.pi, np.pi)
    ang_vel_yaw: tuple[float, float] = (-1.0, 1.0)
    heading_gain: float = 0.5
    resample_s: float = 10.0
    min_norm: float = 0.2
    use_heading: bool = True

    def __post_init__(self) -> None:
        for name in ("lin_vel_x", "lin_vel_y", "heading", "ang_vel_yaw"):
            lo, hi = getattr(self, name)
            if not (np.isfinite(lo) and np.isfinite(hi)) or lo > hi:
                raise ValueError(f"command range {name}=({lo}, {hi}) must be finite, low <= high")
            setattr(self, name, (float(lo), float(hi)))
        if self.resample_s <= 0:
            raise ValueError(f"resample_s={self.resample_s} must be > 0")


def wrap_angle(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


class CommandSampler:
    """Holds the (N, 3) command and (N,) target heading of every environment."""

    def __init__(self, cfg: CommandConfig, num_envs: int) -> None:
        self.cfg = cfg
        self.command = np.zeros((num_envs, 3))
        self.heading = np.zeros(num_envs)

    def resample(self, ids: np.ndarray, rng: np.random.Generator) -> None:
        """Draw new commands for environments ``ids``."""
        n = len(ids)
        if n == 0:
            return
        c = self.cfg
        cmd = np.column_stack([rng.uniform(*c.lin_vel_x, n), rng.uniform(*c.lin_vel_y, n),
                               rng.uniform(*c.ang_vel_yaw, n)])
        small = np.linalg.norm(cmd[:, :2], axis=1) < c.min_norm
        cmd[small, :2] = 0.0
        self.command[ids] = cmd
        self.heading[ids] = rng.uniform(*c.heading, n)

    def update_yaw_rate(self, yaw: np.ndarray, ids: np.ndarray | None = None) -> None:
        """Steer toward the target heading (no-op when ``use_heading`` is False).

        Args:
            yaw: (N,) current yaw of all environments, or (len(ids),) with ``ids``.
            ids: update only these environments.
        """
        if not self.cfg.use_heading:
            return
        sel = slice(None) if ids is None else ids
        err = wrap_angle(self.heading[sel] - yaw)
        self.command[sel, 2] = np.clip(self.cfg.heading_gain * err, *self.cfg.ang_vel_yaw)
