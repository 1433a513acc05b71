"""A1-class robot constants and leg kinematics, free of MuJoCo.

The simulator (collect/sim) builds its model from these numbers and the teachers
(policies/teacher) plan with them; both import this module, neither imports the other.
Joint order everywhere is :data:`msta.data.sensors.JOINT_NAMES` (hip, thigh, calf per leg,
legs FL, FR, RL, RR).
"""

from __future__ import annotations

import numpy as np

from msta.data.sensors import JOINT_NAMES, LEGS

#: Joints (= action channels) of the robot.
NUM_JOINTS = len(JOINT_NAMES)
#: legged_gym default pose: hip +0.1 (left) / -0.1 (right); thigh 0.8 front / 1.0 rear; calf -1.5.
DEFAULT_POSE = np.array(
    [0.1, 0.8, -1.5, -0.1, 0.8, -1.5, 0.1, 1.0, -1.5, -0.1, 1.0, -1.5], dtype=np.float64)
TORQUE_LIMIT = 33.5
VELOCITY_LIMIT = 21.0
THIGH_LENGTH = 0.2
CALF_LENGTH = 0.2
FOOT_RADIUS = 0.02
#: Calf collision capsule length (m) in the "full" collision set (to the foot sphere).
CALF_COLLISION_FULL = 0.17
HIP_OFFSETS = np.array([[0.183, 0.047], [0.183, -0.047], [-0.183, 0.047], [-0.183, -0.047]])
THIGH_OFFSET_Y = np.array([0.08505, -0.08505, 0.08505, -0.08505])
#: Trunk height above flat ground in the default pose, plus a small drop margin.
SPAWN_HEIGHT = 0.34

# Control defaults: the simulator's ControlConfig starts from these and the teachers plan
# with them (paper: PD gains 30 / 0.7, 50 Hz control over a 200 Hz physics step).
#: Position gain of the joint actuators.
KP = 30.0
#: Damping gain of the joint actuators.
KD = 0.7
#: Joint target = default pose + ACTION_SCALE * action.
ACTION_SCALE = 0.25
#: Actions are clipped to +-CLIP_ACTIONS before scaling.
CLIP_ACTIONS = 100.0
#: Physics step (s).
SIM_DT = 0.005
#: Physics steps per control step.
DECIMATION = 4
#: Control period (s): SIM_DT * DECIMATION = 0.02 (50 Hz).
CONTROL_DT = SIM_DT * DECIMATION


def foot_positions_body(q: np.ndarray) -> np.ndarray:
    """Forward kinematics of the feet in the base frame.

    Args:
        q: (N, 12) joint angles in registry order.
    Returns:
        (N, 4, 3) foot sphere centres in the base frame.
    """
    q = q.reshape(-1, 4, 3)
    hip, thigh, calf = q[..., 0], q[..., 1], q[..., 2]
    # Leg plane: thigh and calf rotate about y; x forward, z down.
    x = -THIGH_LENGTH * np.sin(thigh) - CALF_LENGTH * np.sin(thigh + calf)
    z_leg = -THIGH_LENGTH * np.cos(thigh) - CALF_LENGTH * np.cos(thigh + calf)
    y_leg = THIGH_OFFSET_Y[None, :]
    # Hip rotation about x.
    c, s = np.cos(hip), np.sin(hip)
    y = c * y_leg - s * z_leg
    z = s * y_leg + c * z_leg
    out = np.stack([x + HIP_OFFSETS[None, :, 0], y + HIP_OFFSETS[None, :, 1], z], axis=-1)
    return out


__all__ = [
    "ACTION_SCALE", "CALF_COLLISION_FULL", "CALF_LENGTH", "CLIP_ACTIONS", "CONTROL_DT",
    "DECIMATION", "DEFAULT_POSE", "FOOT_RADIUS", "HIP_OFFSETS", "KD", "KP", "LEGS", "NUM_JOINTS",
    "SIM_DT", "SPAWN_HEIGHT", "THIGH_LENGTH", "THIGH_OFFSET_Y", "TORQUE_LIMIT", "VELOCITY_LIMIT",
    "foot_positions_body",
]
