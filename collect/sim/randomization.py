"""Domain randomization: per-environment physics parameters, pushes and latency.

MuJoCo keeps friction, masses and actuator gains in the model, and ``mujoco.rollout``
accepts one model per environment. The simulator therefore builds a pool of
``pool_size`` randomized copies of the model and gives each environment a random member
of the pool at every reset; the parameters an environment actually runs with are
reported in its privileged ``dynamics`` observation.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import mujoco
import numpy as np

from msta.data.sensors import DYNAMICS_NAMES


def _check_range(name: str, lo_hi: tuple[float, float]) -> None:
    lo, hi = lo_hi
    if not (np.isfinite(lo) and np.isfinite(hi)) or lo > hi:
        raise ValueError(f"randomization range {name}={lo_hi!r} must be finite with low <= high")


@dataclass
class RandomizationConfig:
    """Domain randomization ranges (uniform). ``enabled=False`` turns all of it off.

    Args:
        enabled: master switch.
        pool_size: number of randomized model copies environments draw from.
        friction: foot/ground friction coefficient range.
        added_mass: kg added to the trunk.
        com_offset: m, trunk centre-of-mass shift per axis.
        motor_strength: factor on the actuator gains and torque limit.
        kp_factor: factor on the position gain Kp.
        kd_factor: factor on the damping gain Kd.
        push_interval_s: seconds between random pushes (0 disables pushes).
        push_max_vel: m/s, maximum planar velocity added by a push.
        max_latency_steps: observation latency sampled per episode in 0..k control steps.
    """

    enabled: bool = True
    pool_size: int = 32
    friction: tuple[float, float] = (0.5, 1.25)
    added_mass: tuple[float, float] = (-1.0, 2.0)
    com_offset: tuple[float, float] = (-0.05, 0.05)
    motor_strength: tuple[float, float] = (0.9, 1.1)
    kp_factor: tuple[float, float] = (0.9, 1.1)
    kd_factor: tuple[float, float] = (0.9, 1.1)
    push_interval_s: float = 15.0
    push_max_vel: float = 1.0
    max_latency_steps: int = 1

    def __post_init__(self) -> None:
        for name in ("friction", "added_mass", "com_offset", "motor_strength", "kp_factor",
                     "kd_factor"):
            value = tuple(getattr(self, name))
            if len(value) != 2:
                raise ValueError(f"randomization range {name}={value!r} needs (low, high)")
            setattr(self, name, value)
            _check_range(name, value)
        if self.pool_size < 1:
            raise ValueError(f"pool_size={self.pool_size} must be >= 1")
        if self.friction[0] <= 0:
            raise ValueError(f"friction range {self.friction} must be positive")
        if self.max_latency_steps < 0 or self.push_interval_s < 0 or self.push_max_vel < 0:
            raise ValueError("max_latency_steps, push_interval_s and push_max_vel must be >= 0")


def nominal_params() -> np.ndarray:
    """The un-randomized parameter vector in ``DYNAMICS_NAMES`` order."""
    return np.array([0.8, 0.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0])


def sample_params(cfg: RandomizationConfig, n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, 8) parameter vectors in ``DYNAMICS_NAMES`` order."""
    if not cfg.enabled:
        return np.tile(nominal_params(), (n, 1))
    u = lambda r, size=n: rng.uniform(r[0], r[1], size)
    return np.column_stack([
        u(cfg.friction), u(cfg.added_mass), u(cfg.com_offset), u(cfg.com_offset),
        u(cfg.com_offset), u(cfg.motor_strength), u(cfg.kp_factor), u(cfg.kd_factor)])


def apply_params(base: mujoco.MjModel, params: np.ndarray, kp: float, kd: float) -> mujoco.MjModel:
    """A copy of ``base`` with one parameter vector applied.

    Args:
        base: the nominal model (robot + terrain).
        params: (8,) in ``DYNAMICS_NAMES`` order.
        kp, kd: nominal PD gains before the factors.
    """
    assert len(params) == len(DYNAMICS_NAMES)
    friction, mass, cx, cy, cz, strength, kp_f, kd_f = (float(v) for v in params)
    m = copy.copy(base)
    trunk = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "trunk")
    m.body_mass[trunk] = base.body_mass[trunk] + mass
    m.body_ipos[trunk] = base.body_ipos[trunk] + np.array([cx, cy, cz])
    # Friction between robot and terrain is the max of the two geoms' coefficients in
    # MuJoCo; set every robot geom and the terrain to the sampled value.
    m.geom_friction[:, 0] = friction
    k_p, k_d = kp * kp_f * strength, kd * kd_f * strength
    m.actuator_gainprm[:, 0] = k_p
    m.actuator_biasprm[:, 1] = -k_p
    m.actuator_biasprm[:, 2] = -k_d
    m.actuator_forcerange[:] = base.actuator_forcerange * strength
    return m


def build_pool(base: mujoco.MjModel, cfg: RandomizationConfig, kp: float, kd: float,
               rng: np.random.Generator) -> tuple[list[mujoco.MjModel], np.ndarray]:
    """Randomized model copies and their (pool, 8) parameters (one nominal copy if off)."""
    size = cfg.pool_size if cfg.enabled else 1
    params = sample_params(cfg, size, rng)
    return [apply_params(base, p, kp, kd) for p in params], params
