"""The sensor registry: every signal msta knows is named here once.

The simulator's observations, the dataset's Parquet columns, the normalizer's keys,
the MSTA tokenizer's sensor-type vocabulary and the evaluation's "remove sensor X"
experiments all read this registry. Adding a sensor is one entry here plus a producer
(for a sensor read from a quantity the simulator already measures, ``source`` names it and
the simulator produces it with the entry's noise), and its name in the ``sensors`` of each
robot description that has it; nothing else needs an edit.

Extension sensors (``extension=True``: ``height_map``, ``joint_torque``, ``base_accel``) are
student inputs the paper's students do not read: default students, recorded datasets and
``observation.state`` leave them out; a dataset records them when asked (``msta-collect
--extra_sensors=height_map``) and a student reads them when its ``input_sensors`` name them.
``true_contact`` is a privileged extension: the simulator's own foot contacts, which the
teachers read in place of ``foot_contact`` on a robot that offers no contact switches
(``msta.policies.teacher.base.teacher_view``); recorded only when asked.
A robot offers the sensors its description lists (``RobotDescription.sensors``,
docs/robots.md): the simulator's observations hold those and no others.

Units are raw SI (rad, rad/s, m, m/s, N m, m/s^2); nothing here is normalized.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

Group = Literal["proprio", "command", "action", "extero", "privileged"]
GROUPS: tuple[str, ...] = ("proprio", "command", "action", "extero", "privileged")

LEGS: tuple[str, ...] = ("FL", "FR", "RL", "RR")
JOINT_NAMES: tuple[str, ...] = tuple(f"{leg}_{j}" for leg in LEGS for j in ("hip", "thigh", "calf"))
FOOT_NAMES: tuple[str, ...] = tuple(f"{leg}_foot" for leg in LEGS)
XYZ = ("x", "y", "z")

# Height scan grid (legged_gym): 17 x 11 points, x in [-0.8, 0.8], y in [-0.5, 0.5].
HEIGHT_SCAN_X: tuple[float, ...] = tuple(round(-0.8 + 0.1 * i, 3) for i in range(17))
HEIGHT_SCAN_Y: tuple[float, ...] = tuple(round(-0.5 + 0.1 * i, 3) for i in range(11))

DYNAMICS_NAMES: tuple[str, ...] = (
    "friction", "added_mass", "com_x", "com_y", "com_z", "motor_strength", "kp_factor", "kd_factor",
)


@dataclass(frozen=True)
class SensorSpec:
    """One signal.

    Args:
        name: registry key, e.g. ``"joint_pos"``.
        group: ``proprio`` (student input), ``command``, ``action`` (the previous action,
            a student input), ``extero`` (exteroception, a student input) or
            ``privileged`` (teacher only).
        names: one name per channel; ``dim == len(names)``.
        noise: half-width of the default uniform observation noise in raw units.
        scale: a typical magnitude, used for documentation and imported-teacher specs.
        binary: channel values are 0/1.
        description: one line for humans.
        extension: a signal beyond the paper's (a student input, or the privileged
            ``true_contact``): left out of the default student inputs, of the default
            recorded sensors and of ``observation.state``.
        source: the simulator measurement this sensor reads (plus uniform noise of
            half-width ``noise``), e.g. ``height_scan``; "" = the simulator produces it itself.
        encoder_tokens: how an MSTA student tokenizes it: 0 = one token per scalar (the
            paper's); k > 0 = each step's channels go through a small MLP to k tokens.
    """

    name: str
    group: Group
    names: tuple[str, ...]
    noise: float = 0.0
    scale: float = 1.0
    binary: bool = False
    description: str = ""
    extension: bool = False
    source: str = ""
    encoder_tokens: int = 0

    @property
    def dim(self) -> int:
        return len(self.names)

    @property
    def column(self) -> str:
        """Dataset column. Student inputs live under ``observation.``; privileged signals
        do not, because lerobot treats every ``observation.*`` column as a policy input."""
        prefix = "privileged" if self.group == "privileged" else "observation"
        return f"{prefix}.{self.name}"

    @property
    def is_student_input(self) -> bool:
        return self.group != "privileged"


def _specs() -> tuple[SensorSpec, ...]:
    return (
        SensorSpec("joint_pos", "proprio", JOINT_NAMES, 0.01, 1.0,
                   description="joint angles q (rad)"),
        SensorSpec("joint_vel", "proprio", JOINT_NAMES, 1.5, 10.0,
                   description="joint velocities (rad/s)"),
        SensorSpec("ang_vel", "proprio", XYZ, 0.2, 1.0,
                   description="IMU gyro, base angular velocity in the base frame (rad/s)"),
        SensorSpec("gravity", "proprio", XYZ, 0.05, 1.0,
                   description="gravity direction projected into the base frame (unit vector)"),
        SensorSpec("foot_contact", "proprio", FOOT_NAMES, 0.0, 1.0, binary=True,
                   description="foot contact flags (0/1)"),
        SensorSpec("command", "command", ("vx", "vy", "wz"), 0.0, 1.0,
                   description="velocity command: vx, vy (m/s, base frame), yaw rate (rad/s)"),
        SensorSpec("last_action", "action", JOINT_NAMES, 0.0, 1.0,
                   description="previous action a_{t-1} (scaled offsets from the default pose)"),
        SensorSpec("base_lin_vel", "privileged", XYZ, 0.0, 1.0,
                   description="true base linear velocity in the base frame (m/s)"),
        SensorSpec("base_ang_vel", "privileged", XYZ, 0.0, 1.0,
                   description="true base angular velocity in the base frame (rad/s)"),
        SensorSpec("orientation", "privileged", ("w", "x", "y", "z"), 0.0, 1.0,
                   description="base orientation quaternion (world frame, wxyz)"),
        SensorSpec("base_height", "privileged", ("z",), 0.0, 0.3,
                   description="base height above the terrain directly below it (m)"),
        SensorSpec(
            "height_scan", "privileged",
            tuple(f"h_{x:+.1f}_{y:+.1f}" for x in HEIGHT_SCAN_X for y in HEIGHT_SCAN_Y),
            0.0, 0.1,
            description="terrain height minus base height at 17x11 points, yaw-aligned base "
                        "frame, x-major (m)"),
        SensorSpec("dynamics", "privileged", DYNAMICS_NAMES, 0.0, 1.0,
                   description="randomized parameters: friction, added mass (kg), CoM offset "
                               "(m), motor strength, Kp and Kd factors"),
        SensorSpec(
            "height_map", "extero",
            tuple(f"h_{x:+.1f}_{y:+.1f}" for x in HEIGHT_SCAN_X for y in HEIGHT_SCAN_Y),
            0.02, 0.1, extension=True, source="height_scan", encoder_tokens=4,
            description="onboard elevation map: the height scan with +-2 cm noise, as a student "
                        "extension input (MSTA: an MLP encodes each step's 187 points into 4 "
                        "tokens) (m)"),
        SensorSpec("joint_torque", "proprio", JOINT_NAMES, 0.5, 10.0, extension=True,
                   source="torques",
                   description="joint torques: the actuators' force, mean over the control "
                               "step (on the robot, the motor drivers' current estimate) (N m)"),
        SensorSpec("base_accel", "proprio", XYZ, 0.2, 10.0, extension=True, source="accel",
                   description="IMU accelerometer: specific force (acceleration minus gravity) "
                               "at the IMU in the base frame, +9.81 on z standing still, mean "
                               "over the control step; 0 in an episode's first frame (m/s^2)"),
        SensorSpec("true_contact", "privileged", FOOT_NAMES, 0.0, 1.0, binary=True,
                   extension=True, source="foot_contact",
                   description="the simulator's foot contact flags (0/1) at the end of the "
                               "control step, without latency: the teachers' contacts on a "
                               "robot that offers no foot_contact"),
    )


SENSORS: dict[str, SensorSpec] = {s.name: s for s in _specs()}

#: The paper's 49 proprioceptive scalars, in the paper's order.
STUDENT_SENSORS: tuple[str, ...] = tuple(
    s.name for s in SENSORS.values() if s.is_student_input and not s.extension)
#: Signals beyond the paper's: student inputs read only when a student's config names them,
#: and the privileged ``true_contact``; each recorded only when asked.
EXTENSION_SENSORS: tuple[str, ...] = tuple(s.name for s in SENSORS.values() if s.extension)
#: What a dataset records unless asked for more: everything but the extensions.
DEFAULT_RECORDED: tuple[str, ...] = tuple(s.name for s in SENSORS.values() if not s.extension)
#: The student inputs a physical sensor measures, which can fail (msta-eval's sensor faults,
#: the guard); command and last_action are software.
PHYSICAL_SENSORS: tuple[str, ...] = tuple(s for s in STUDENT_SENSORS
                                          if SENSORS[s].group == "proprio")
#: A joint encoder's channels: its angle (q) and velocity (q-dot), indexed by joint.
JOINT_ENCODER_SENSORS: tuple[str, ...] = ("joint_pos", "joint_vel")
PRIVILEGED_SENSORS: tuple[str, ...] = tuple(
    s.name for s in SENSORS.values() if s.group == "privileged")
NUM_JOINTS = len(JOINT_NAMES)
ACTION_DIM = NUM_JOINTS


def get(name: str) -> SensorSpec:
    """Look a sensor up by name, with an error that lists the known names."""
    try:
        return SENSORS[name]
    except KeyError:
        raise KeyError(f"unknown sensor {name!r}; known sensors: {sorted(SENSORS)}") from None


def by_group(*groups: Group) -> tuple[SensorSpec, ...]:
    """Sensors of the given groups, in registry order."""
    for g in groups:
        if g not in GROUPS:
            raise ValueError(f"unknown sensor group {g!r}")
    return tuple(s for s in SENSORS.values() if s.group in groups)


def total_dim(names: tuple[str, ...] | list[str]) -> int:
    return sum(get(n).dim for n in names)
