"""Robot descriptions (one TOML spec file per robot) and the leg kinematics, free of MuJoCo.

A robot is its MJCF plus one spec file holding its joints, feet, gains, default pose,
limits, leg geometry and the sensors it has (docs/robots.md lists the fields and units).
:func:`load_robot` reads a shipped robot by name (:func:`robot_names`) or any ``.toml``
spec by path and checks it (:class:`RobotDescription`).

The module-level constants below are the shipped A1-class robot's numbers (``A1``): the
simulator (collect/sim) builds its model from them and the teachers (policies/teacher)
plan with them; both import this module, neither imports the other. Joint order
everywhere is :data:`msta.data.sensors.JOINT_NAMES` (hip, thigh, calf per leg, legs FL,
FR, RL, RR).
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass, field, fields
from importlib import resources
from pathlib import Path

import numpy as np

from msta.data.sensors import JOINT_NAMES, LEGS, SENSORS

#: The package folder (of msta.data) holding the shipped spec files, ``<name>.toml``.
ROBOTS_FOLDER = "robots"
SPEC_SUFFIX = ".toml"
#: Numbers that must be > 0 and the one that may be 0 (a pure P controller).
_POSITIVE = ("kp", "action_scale", "clip_actions", "velocity_limit",
             "spawn_height", "contact_threshold", "sim_dt", "thigh_length", "calf_length",
             "foot_radius", "calf_collision_full")
_NON_NEGATIVE = ("kd",)
#: Joints per leg the leg kinematics assume (hip, thigh, calf).
JOINTS_PER_LEG = 3


@dataclass(frozen=True)
class RobotDescription:
    """One legged robot: what the simulator builds and the teachers plan with.

    Lists may be given as any sequence; they are stored as tuples of str / float.

    Args:
        name: the robot's name, e.g. ``"a1"``.
        mjcf: the MJCF file: a path relative to the spec file's folder, or absolute.
        joints: actuated joint names in action order (also the MJCF's joint and
            actuator names); ``JOINTS_PER_LEG`` (hip, thigh, calf) per leg, legs in
            ``feet`` order.
        feet: foot geom names of the MJCF, one per leg.
        imu_site: the MJCF site the IMU (gyro, gravity) is read at.
        default_pose: joint angles (rad) of the default pose, one per joint.
        kp: position gain of the joint PD controllers (N m / rad).
        kd: damping gain of the joint PD controllers (N m s / rad).
        action_scale: joint target = default pose + ``action_scale`` * action (rad).
        clip_actions: actions are clipped to +-``clip_actions`` before scaling.
        torque_limit: joint torque limit (N m): one number for every joint, or one per joint
            (e.g. the Go1's knees are geared for more torque than its hips and thighs).
        velocity_limit: joint velocity limit (rad/s).
        spawn_height: trunk height above flat ground at a reset (m).
        contact_threshold: touch-sensor force above which a foot is in contact (N).
        sim_dt: physics step (s).
        decimation: physics steps per control step.
        thigh_length: hip-pitch axis to knee (m).
        calf_length: knee to foot-sphere centre (m).
        foot_radius: foot sphere radius (m).
        calf_collision_full: calf collision capsule length in the "full" collision set (m).
        hip_offsets: (x, y) of each hip in the base frame (m), one pair per leg.
        thigh_offset_y: lateral offset of each thigh from its hip (m), one per leg.
        sensors: names of :data:`msta.data.sensors.SENSORS` this robot has (the simulator's
            observations hold these and no others).
        spec_file: the spec file it was read from (``None`` when built in code); relative
            ``mjcf`` paths resolve from its folder. Not part of equality.
    """

    name: str
    mjcf: str
    joints: tuple[str, ...]
    feet: tuple[str, ...]
    imu_site: str
    default_pose: tuple[float, ...]
    kp: float
    kd: float
    action_scale: float
    clip_actions: float
    torque_limit: float | tuple[float, ...]
    velocity_limit: float
    spawn_height: float
    contact_threshold: float
    sim_dt: float
    decimation: int
    thigh_length: float
    calf_length: float
    foot_radius: float
    calf_collision_full: float
    hip_offsets: tuple[tuple[float, float], ...]
    thigh_offset_y: tuple[float, ...]
    sensors: tuple[str, ...]
    spec_file: Path | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        for name in ("name", "mjcf", "imu_site"):
            self._set(name, _text(name, getattr(self, name)))
        for name in ("joints", "feet", "sensors"):
            self._set(name, _names(name, getattr(self, name)))
        for name in _POSITIVE + _NON_NEGATIVE:
            self._set(name, _number(name, getattr(self, name), strict=name in _POSITIVE))
        self._set("decimation", _count("decimation", self.decimation))
        legs = len(self.feet)
        if len(self.joints) != JOINTS_PER_LEG * legs:
            raise ValueError(f"joints has {len(self.joints)} names; {legs} feet need "
                             f"{JOINTS_PER_LEG * legs} ({JOINTS_PER_LEG} per leg)")
        self._set("default_pose",
                  _vector("default_pose", self.default_pose, len(self.joints), "joint"))
        self._set("thigh_offset_y", _vector("thigh_offset_y", self.thigh_offset_y, legs, "leg"))
        self._set("torque_limit", _limit("torque_limit", self.torque_limit, len(self.joints)))
        self._set("hip_offsets", _pairs("hip_offsets", self.hip_offsets, legs))
        unknown = [s for s in self.sensors if s not in SENSORS]
        if unknown:
            raise ValueError(f"sensors: unknown sensor(s) {unknown}; known: {sorted(SENSORS)}")

    def _set(self, name: str, value: object) -> None:
        object.__setattr__(self, name, value)  # frozen: normalizing during __post_init__

    @property
    def num_joints(self) -> int:
        """Actuated joints (= action channels)."""
        return len(self.joints)

    @property
    def joint_torque_limits(self) -> tuple[float, ...]:
        """The torque limit (N m) of each joint, in ``joints`` order."""
        if isinstance(self.torque_limit, tuple):
            return self.torque_limit
        return (self.torque_limit,) * len(self.joints)

    @property
    def control_dt(self) -> float:
        """Control period (s): ``sim_dt * decimation``."""
        return self.sim_dt * self.decimation

    @property
    def mjcf_path(self) -> Path:
        """The MJCF file: ``mjcf`` resolved from the spec file's folder when relative."""
        path = Path(self.mjcf)
        if path.is_absolute() or self.spec_file is None:
            return path
        return (self.spec_file.parent / path).resolve()

    def foot_positions_body(self, q: np.ndarray) -> np.ndarray:
        """Forward kinematics of the feet in the base frame.

        Args:
            q: (N, num_joints) joint angles in ``joints`` order.
        Returns:
            (N, legs, 3) foot sphere centres in the base frame.
        """
        hip_offsets = np.asarray(self.hip_offsets, dtype=np.float64)  # (legs, 2)
        thigh_offset_y = np.asarray(self.thigh_offset_y, dtype=np.float64)  # (legs,)
        q = q.reshape(-1, len(self.feet), JOINTS_PER_LEG)
        hip, thigh, calf = q[..., 0], q[..., 1], q[..., 2]
        # Leg plane: thigh and calf rotate about y; x forward, z down.
        x = -self.thigh_length * np.sin(thigh) - self.calf_length * np.sin(thigh + calf)
        z_leg = -self.thigh_length * np.cos(thigh) - self.calf_length * np.cos(thigh + calf)
        y_leg = thigh_offset_y[None, :]
        # Hip rotation about x.
        c, s = np.cos(hip), np.sin(hip)
        y = c * y_leg - s * z_leg
        z = s * y_leg + c * z_leg
        return np.stack([x + hip_offsets[None, :, 0], y + hip_offsets[None, :, 1], z], axis=-1)


def _text(name: str, value: object) -> str:
    if not isinstance(value, str) or not value.strip():
        raise ValueError(f"{name} = {value!r} must be a non-empty text")
    return value


def _names(name: str, value: object) -> tuple[str, ...]:
    value = _sequence(name, value, "names")
    if not value:
        raise ValueError(f"{name} is empty; it needs at least one name")
    names = tuple(_text(f"{name}[{i}]", v) for i, v in enumerate(value))
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ValueError(f"{name}: duplicate name(s) {dup}")
    return names


def _number(name: str, value: object, strict: bool = False) -> float:
    """A finite float: > 0 when ``strict``, else >= 0."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(value):
        raise ValueError(f"{name} = {value!r} is not a finite number")
    number = float(value)
    if strict and number <= 0:
        raise ValueError(f"{name} = {value!r} must be > 0")
    if not strict and number < 0:
        raise ValueError(f"{name} = {value!r} must be >= 0")
    return number


def _count(name: str, value: object) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f"{name} = {value!r} must be a whole number >= 1")
    return value


def _sequence(name: str, value: object, what: str) -> Sequence:
    """``value`` as a sequence (a numpy array becomes a list), else a ValueError."""
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, (str, bytes)) or not isinstance(value, Sequence):
        # a spec file's value of the wrong type is a bad value like any other: ValueError
        raise ValueError(f"{name} = {value!r} is not a list of {what}")  # noqa: TRY004
    return value


def _vector(name: str, value: object, size: int, per: str) -> tuple[float, ...]:
    """``size`` finite floats (any sign), one per ``per``."""
    value = _sequence(name, value, "numbers")
    if len(value) != size:
        raise ValueError(f"{name} has {len(value)} values; one per {per} needs {size}")
    out = []
    for i, v in enumerate(value):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ValueError(f"{name}[{i}] = {v!r} is not a finite number")
        out.append(float(v))
    return tuple(out)


def _limit(name: str, value: object, size: int) -> float | tuple[float, ...]:
    """A number > 0, or ``size`` numbers > 0 (one per joint)."""
    if isinstance(value, (int, float, bool)):
        return _number(name, value, strict=True)
    limits = _vector(name, value, size, "joint")
    for i, v in enumerate(limits):
        _number(f"{name}[{i}]", v, strict=True)
    return limits


def _pairs(name: str, value: object, size: int) -> tuple[tuple[float, float], ...]:
    """``size`` (x, y) pairs of finite floats, one per leg."""
    value = _sequence(name, value, "(x, y) pairs")
    if len(value) != size:
        raise ValueError(f"{name} has {len(value)} pairs; one (x, y) per leg needs {size}")
    return tuple(_vector(f"{name}[{i}]", pair, 2, "coordinate") for i, pair in enumerate(value))


#: The spec file's keys: every field but ``spec_file``.
SPEC_FIELDS: tuple[str, ...] = tuple(f.name for f in fields(RobotDescription)
                                     if f.name != "spec_file")


def robot_names() -> tuple[str, ...]:
    """The shipped robots' names (their spec files in ``msta.data``'s ``robots/``)."""
    folder = resources.files("msta.data").joinpath(ROBOTS_FOLDER)
    return tuple(sorted(p.name.removesuffix(SPEC_SUFFIX) for p in folder.iterdir()
                        if p.name.endswith(SPEC_SUFFIX)))


def load_robot(name_or_path: str | Path) -> RobotDescription:
    """Read and check a robot description.

    Args:
        name_or_path: a shipped robot's name (one of :func:`robot_names`), or the path of
            a ``.toml`` spec file (a :class:`~pathlib.Path`, or a text ending in
            ``.toml`` or holding a ``/``).
    Returns:
        The checked description; ``spec_file`` is the file read.
    Raises:
        ValueError: (one line) an unknown name, a missing or unreadable file, a missing or
            unknown field, a bad value, or an MJCF path that is not a file; the message
            names the file and the field.
    """
    text = str(name_or_path)
    if isinstance(name_or_path, Path) or text.endswith(SPEC_SUFFIX) or "/" in text:
        return _load_file(Path(name_or_path))
    if text not in robot_names():
        raise ValueError(f"unknown robot {text!r}; shipped robots: {list(robot_names())} "
                         f"(or give the path of a {SPEC_SUFFIX} spec file)")
    spec = resources.files("msta.data").joinpath(ROBOTS_FOLDER, text + SPEC_SUFFIX)
    with resources.as_file(spec) as path:
        return _load_file(Path(path))


def _load_file(path: Path) -> RobotDescription:
    if not path.is_file():
        raise ValueError(f"robot spec file {path} does not exist")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise ValueError(f"{path}: not a TOML file: {err}") from None
    missing = [k for k in SPEC_FIELDS if k not in data]
    if missing:
        raise ValueError(f"{path}: missing field(s) {missing} (docs/robots.md lists them)")
    unknown = sorted(k for k in data if k not in SPEC_FIELDS)
    if unknown:
        raise ValueError(f"{path}: unknown field(s) {unknown} (docs/robots.md lists them)")
    try:
        robot = RobotDescription(**data, spec_file=path.resolve())
    except ValueError as err:
        raise ValueError(f"{path}: {err}") from None
    if not robot.mjcf_path.is_file():
        raise ValueError(f"{path}: mjcf = {robot.mjcf!r} resolves to {robot.mjcf_path}, "
                         "which is not a file")
    return robot


#: The shipped A1-class robot (msta_data/robots/a1.toml); the constants below are its numbers.
A1 = load_robot("a1")
#: The robot of a dataset or checkpoint that records none: msta simulated only the A1 before
#: datasets (``meta/msta.json``'s ``robot``) and students (``PolicyConfig.robots``) said.
LEGACY_ROBOT = A1.name

#: Joints (= action channels) of the robot.
NUM_JOINTS = A1.num_joints
#: legged_gym default pose: hip +0.1 (left) / -0.1 (right); thigh 0.8 front / 1.0 rear; calf -1.5.
DEFAULT_POSE = np.array(A1.default_pose, dtype=np.float64)
TORQUE_LIMIT = A1.torque_limit
VELOCITY_LIMIT = A1.velocity_limit
THIGH_LENGTH = A1.thigh_length
CALF_LENGTH = A1.calf_length
FOOT_RADIUS = A1.foot_radius
#: Calf collision capsule length (m) in the "full" collision set (to the foot sphere).
CALF_COLLISION_FULL = A1.calf_collision_full
HIP_OFFSETS = np.array(A1.hip_offsets, dtype=np.float64)
THIGH_OFFSET_Y = np.array(A1.thigh_offset_y, dtype=np.float64)
#: Trunk height above flat ground in the default pose, plus a small drop margin.
SPAWN_HEIGHT = A1.spawn_height

# The A1's control numbers, which the teachers plan with (the simulator reads the
# description it is given; paper: PD gains 30 / 0.7, 50 Hz control over a 200 Hz physics step).
#: Position gain of the joint actuators.
KP = A1.kp
#: Damping gain of the joint actuators.
KD = A1.kd
#: Joint target = default pose + ACTION_SCALE * action.
ACTION_SCALE = A1.action_scale
#: Actions are clipped to +-CLIP_ACTIONS before scaling.
CLIP_ACTIONS = A1.clip_actions
#: Physics step (s).
SIM_DT = A1.sim_dt
#: Physics steps per control step.
DECIMATION = A1.decimation
#: Control period (s): SIM_DT * DECIMATION = 0.02 (50 Hz).
CONTROL_DT = A1.control_dt


def foot_positions_body(q: np.ndarray) -> np.ndarray:
    """Forward kinematics of the A1's feet in the base frame.

    Args:
        q: (N, 12) joint angles in registry order.
    Returns:
        (N, 4, 3) foot sphere centres in the base frame.
    """
    return A1.foot_positions_body(q)


__all__ = [
    "A1", "ACTION_SCALE", "CALF_COLLISION_FULL", "CALF_LENGTH", "CLIP_ACTIONS", "CONTROL_DT",
    "DECIMATION", "DEFAULT_POSE", "FOOT_RADIUS", "HIP_OFFSETS", "JOINTS_PER_LEG",
    "JOINT_NAMES", "KD", "KP", "LEGS", "NUM_JOINTS", "SIM_DT", "SPAWN_HEIGHT", "SPEC_FIELDS",
    "THIGH_LENGTH", "THIGH_OFFSET_Y", "TORQUE_LIMIT", "VELOCITY_LIMIT", "RobotDescription",
    "foot_positions_body", "load_robot", "robot_names",
]
