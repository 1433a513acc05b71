"""Bounds of the simulator's observations and the normalized action of its Gymnasium views.

Every registry sensor (``msta_data/sensors.py``) gets a finite range, from the robot model
where it has one and from measurement where it has none; the Gymnasium views
(``gym_env.py``) state these ranges in their ``Box`` spaces and clip readings to them, so an
observation is always inside its space. Every range is widened by the sensor's uniform
observation noise (registry half-width x ``--env.noise.scale``).

========================  ==========================================================
sensor                    range
========================  ==========================================================
joint_pos                 the MJCF's joint range (``a1.xml``'s) +- ``JOINT_POS_MARGIN``
joint_vel                 +- ``JOINT_VEL_MAX``
ang_vel, base_ang_vel     +- ``ANG_VEL_MAX``
gravity, orientation      [-1, 1] (unit vectors)
foot_contact              [0, 1]
command                   the config's command ranges (and 0: short commands are zeroed)
last_action               the action space's range
base_lin_vel              +- ``LIN_VEL_MAX``
base_height               ``BASE_HEIGHT``
height_scan, height_map   the terrain's height span, less/plus the ``BASE_HEIGHT`` range
dynamics                  the config's randomization ranges (and the nominal values)
joint_torque              +- each actuator's force limit (``torque_limit`` x the largest
                          randomized motor strength)
base_accel                +- ``ACCEL_MAX``
========================  ==========================================================

The measured figures behind the constants: 1,024 robots on all six terrain types, levels
0-9, full randomization, joint targets drawn uniformly in the joint range or at the stops
(bang-bang) every 5 control steps, 800 steps (47,711 falls). Joints went up to 0.51 rad past
a stop (MuJoCo's limits are soft and a falling trunk drives a leg into them), joint speeds
up to 93 rad/s (the A1 motor's rated 21 rad/s is not enforced by the simulator), the trunk
turned at up to 33.5 rad/s and moved at up to 4.7 m/s, and stood 0.05-0.89 m above the
ground below it. ``ACCEL_MAX`` is an IMU accelerometer's full scale, not a measured figure.
Readings beyond a range are clipped to it.

The normalized action (``ActionMap``): ``a`` in [-1, 1] per joint; 0 is the default pose
(the robot description's ``default_pose``), +1 the joint's upper stop and -1 its lower stop,
linear on each side. It maps to the simulator's action ``(target - default) / action_scale``, so a
normalized action and the simulator action of the same joint target move the robot alike.
"""

from __future__ import annotations

import numpy as np

from msta.collect.sim.randomization import nominal_params
from msta.collect.sim.robot import joint_limits
from msta.data.sensors import SENSORS, get

#: rad past a joint stop still inside the joint_pos range (0.51 rad measured; module docstring).
JOINT_POS_MARGIN = 0.6
#: rad/s, joint speed range (93 rad/s measured).
JOINT_VEL_MAX = 120.0
#: rad/s, trunk turn rate range (33.5 rad/s measured).
ANG_VEL_MAX = 40.0
#: m/s, trunk speed range (4.7 m/s measured).
LIN_VEL_MAX = 10.0
#: m, trunk height above the ground below it (0.05-0.89 m measured).
BASE_HEIGHT = (-0.25, 1.5)
#: m/s^2, accelerometer range: +-16 g, a common IMU full scale (e.g. the MPU-6050's largest).
ACCEL_MAX = 16 * 9.81
#: The two action conventions of the Gymnasium views.
ACTION_MODES: tuple[str, ...] = ("normalized", "simulator")


class ActionMap:
    """Normalized joint actions <-> the simulator's (offsets from the default pose in units of
    ``action_scale``).

    Args:
        limits: (12, 2) joint ranges (``msta.collect.sim.robot.joint_limits``).
        action_scale: the simulator's ``control.action_scale``.
        default_pose: (12,) the robot's default pose (its description's ``default_pose``).
    """

    def __init__(self, limits: np.ndarray, action_scale: float,
                 default_pose: np.ndarray) -> None:
        pose = np.asarray(default_pose, dtype=np.float64)
        self.up = (limits[:, 1] - pose) / action_scale    # (12,) simulator units of +1
        self.down = (pose - limits[:, 0]) / action_scale  # (12,) simulator units of -1

    def to_sim(self, a: np.ndarray) -> np.ndarray:
        """(..., 12) normalized actions (clipped to [-1, 1]) -> simulator actions."""
        a = np.clip(a, -1.0, 1.0)
        return np.where(a >= 0, a * self.up, a * self.down)

    def from_sim(self, s: np.ndarray) -> np.ndarray:
        """(..., 12) simulator actions -> normalized actions (clipped to [-1, 1])."""
        return np.clip(np.where(s >= 0, s / self.up, s / self.down), -1.0, 1.0)


def action_bounds(sim, mode: str) -> tuple[np.ndarray, np.ndarray]:
    """(12,) low and high of the action in ``mode`` ("normalized" or "simulator")."""
    if mode not in ACTION_MODES:
        raise ValueError(f"actions={mode!r}; expected one of {list(ACTION_MODES)}")
    lim = 1.0 if mode == "normalized" else sim.cfg.control.clip_actions
    nj = sim.robot.num_joints
    return np.full(nj, -lim), np.full(nj, lim)


def _ranges(sim) -> dict[str, tuple[np.ndarray | float, np.ndarray | float]]:
    """Each sensor's range before noise, for the simulator ``sim`` (a ``QuadrupedEnv``)."""
    cfg = sim.cfg
    q = joint_limits(sim.model)
    cmd = cfg.commands
    cmd_lo = np.array([min(cmd.lin_vel_x[0], 0), min(cmd.lin_vel_y[0], 0), cmd.ang_vel_yaw[0]])
    cmd_hi = np.array([max(cmd.lin_vel_x[1], 0), max(cmd.lin_vel_y[1], 0), cmd.ang_vel_yaw[1]])
    rnd = cfg.randomization
    spans = [rnd.friction, rnd.added_mass, rnd.com_offset, rnd.com_offset, rnd.com_offset,
             rnd.motor_strength, rnd.kp_factor, rnd.kd_factor]
    nominal = nominal_params()
    dyn_lo = np.array([min(r[0], v) for r, v in zip(spans, nominal)])
    dyn_hi = np.array([max(r[1], v) for r, v in zip(spans, nominal)])
    force = np.max([m.actuator_forcerange[:, 1] for m in sim.pool], axis=0)  # (nu,)
    ground = sim.terrain.heights
    span = float(max(ground.max(), 0.0) - min(ground.min(), 0.0))  # beyond the grid: z = 0
    return {
        "joint_pos": (q[:, 0] - JOINT_POS_MARGIN, q[:, 1] + JOINT_POS_MARGIN),
        "joint_vel": (-JOINT_VEL_MAX, JOINT_VEL_MAX),
        "ang_vel": (-ANG_VEL_MAX, ANG_VEL_MAX),
        "gravity": (-1.0, 1.0),
        "foot_contact": (0.0, 1.0),
        "command": (cmd_lo, cmd_hi),
        "base_lin_vel": (-LIN_VEL_MAX, LIN_VEL_MAX),
        "base_ang_vel": (-ANG_VEL_MAX, ANG_VEL_MAX),
        "orientation": (-1.0, 1.0),
        "base_height": BASE_HEIGHT,
        "height_scan": (-span - BASE_HEIGHT[1], span - BASE_HEIGHT[0]),
        "dynamics": (dyn_lo, dyn_hi),
        "torques": (-force, force),
        "accel": (-ACCEL_MAX, ACCEL_MAX),
    }


def observation_bounds(sim, mode: str) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Every registry sensor's (dim,) float32 low and high for the simulator ``sim``.

    Args:
        sim: the ``QuadrupedEnv`` (its model, terrain and config set the ranges).
        mode: the action convention ("normalized" or "simulator"), for ``last_action``.
    """
    ranges = _ranges(sim)
    ranges["last_action"] = action_bounds(sim, mode)
    noise = sim.cfg.noise
    out = {}
    for name, spec in SENSORS.items():
        lo, hi = ranges[spec.source or name]
        width = spec.noise * noise.scale if noise.enabled else 0.0
        low = np.broadcast_to(np.asarray(lo, dtype=np.float64) - width, (spec.dim,))
        high = np.broadcast_to(np.asarray(hi, dtype=np.float64) + width, (spec.dim,))
        out[name] = (low.astype(np.float32), high.astype(np.float32))
    sources = {spec.source for spec in SENSORS.values()}
    for name in ranges:
        if name not in sources:
            get(name)  # a range for a sensor the registry no longer has is a bug here
    return out
