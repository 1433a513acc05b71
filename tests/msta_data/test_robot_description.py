"""Robot descriptions: the shipped A1 spec reproduces the A1 constants bit for bit, a spec
file in any folder loads, and every kind of bad spec is a one-line ValueError that names the
file and the field."""

from __future__ import annotations

import dataclasses
import json
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from msta.data.robot import (
    A1,
    ACTION_SCALE,
    CALF_COLLISION_FULL,
    CALF_LENGTH,
    CLIP_ACTIONS,
    CONTROL_DT,
    DECIMATION,
    DEFAULT_POSE,
    FOOT_RADIUS,
    HIP_OFFSETS,
    KD,
    KP,
    NUM_JOINTS,
    SIM_DT,
    SPAWN_HEIGHT,
    SPEC_FIELDS,
    THIGH_LENGTH,
    THIGH_OFFSET_Y,
    TORQUE_LIMIT,
    VELOCITY_LIMIT,
    RobotDescription,
    foot_positions_body,
    load_robot,
    robot_names,
)
from msta.data.sensors import FOOT_NAMES, JOINT_NAMES, SENSORS

REPO = Path(__file__).resolve().parents[2]
A1_POSE = [0.1, 0.8, -1.5, -0.1, 0.8, -1.5, 0.1, 1.0, -1.5, -0.1, 1.0, -1.5]
A1_HIPS = [[0.183, 0.047], [0.183, -0.047], [-0.183, 0.047], [-0.183, -0.047]]
A1_THIGH_Y = [0.08505, -0.08505, 0.08505, -0.08505]


def same(a: object, b: object) -> bool:
    """Equal value and type; arrays: equal dtype, shape and bytes."""
    if isinstance(a, np.ndarray):
        return (isinstance(b, np.ndarray) and a.dtype == b.dtype and a.shape == b.shape
                and a.tobytes() == b.tobytes())
    return type(a) is type(b) and a == b


def test_the_a1_spec_reproduces_the_constants_bit_for_bit():
    expected = {
        NUM_JOINTS: 12, TORQUE_LIMIT: 33.5, VELOCITY_LIMIT: 21.0, THIGH_LENGTH: 0.2,
        CALF_LENGTH: 0.2, FOOT_RADIUS: 0.02, CALF_COLLISION_FULL: 0.17, SPAWN_HEIGHT: 0.34,
        KP: 30.0, KD: 0.7, ACTION_SCALE: 0.25, CLIP_ACTIONS: 100.0, SIM_DT: 0.005,
        DECIMATION: 4, CONTROL_DT: 0.005 * 4,
    }
    for got, want in expected.items():
        assert same(got, want), (got, want)
    assert same(DEFAULT_POSE, np.array(A1_POSE, dtype=np.float64))
    assert same(HIP_OFFSETS, np.array(A1_HIPS))
    assert same(THIGH_OFFSET_Y, np.array(A1_THIGH_Y))
    assert A1.contact_threshold == 1.0 and A1.imu_site == "imu" and A1.name == "a1"
    assert A1.joints == JOINT_NAMES and A1.feet == FOOT_NAMES
    # every sensor of the registry but the Go1's joint torques and accelerometer, and the
    # teachers' stand-in for foot_contact (the A1 offers foot_contact itself)
    assert A1.sensors == tuple(s for s in SENSORS
                               if s not in ("joint_torque", "base_accel", "true_contact"))


def reference_feet(q: np.ndarray) -> np.ndarray:
    """The A1's foot kinematics with its numbers written out (the previous function)."""
    hips, thigh_y = np.array(A1_HIPS), np.array(A1_THIGH_Y)
    q = q.reshape(-1, 4, 3)
    hip, thigh, calf = q[..., 0], q[..., 1], q[..., 2]
    x = -0.2 * np.sin(thigh) - 0.2 * np.sin(thigh + calf)
    z_leg = -0.2 * np.cos(thigh) - 0.2 * np.cos(thigh + calf)
    c, s = np.cos(hip), np.sin(hip)
    y = c * thigh_y[None, :] - s * z_leg
    z = s * thigh_y[None, :] + c * z_leg
    return np.stack([x + hips[None, :, 0], y + hips[None, :, 1], z], axis=-1)


def test_foot_positions_match_the_reference_on_random_joint_angles():
    q = np.random.default_rng(0).uniform(-2.5, 2.5, size=(64, 12))
    want = reference_feet(q)
    assert want.shape == (64, 4, 3)
    assert foot_positions_body(q).tobytes() == want.tobytes()
    assert A1.foot_positions_body(q).tobytes() == want.tobytes()


def test_the_shipped_robots_load_by_name_and_name_their_mjcf():
    assert robot_names() == ("a1", "go1")
    for name in robot_names():
        assert load_robot(name).name == name
    assert load_robot("a1") == A1
    assert A1.mjcf_path.samefile(REPO / "collect" / "sim" / "assets" / "a1.xml")
    root = ET.parse(A1.mjcf_path).getroot()
    names = {tag: {e.get("name") for e in root.iter(tag)} for tag in ("joint", "geom", "site")}
    assert set(A1.joints) <= names["joint"]
    assert set(A1.feet) <= names["geom"]
    assert A1.imu_site in names["site"]


def toml_value(value: object) -> str:
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    if isinstance(value, str):
        return json.dumps(value)
    return repr(value)


def write_spec(folder: Path, name: str = "quad", **changes: object) -> Path:
    """A spec file in ``folder``: the A1's values, an MJCF beside it, then ``changes``
    (a value of ``None`` leaves the field out)."""
    (folder / f"{name}.xml").write_text("<mujoco/>\n")
    spec = {f: getattr(A1, f) for f in SPEC_FIELDS} | {"name": name, "mjcf": f"{name}.xml"}
    spec |= changes
    path = folder / f"{name}.toml"
    path.write_text("".join(f"{k} = {toml_value(v)}\n" for k, v in spec.items() if v is not None))
    return path


def test_a_spec_in_any_folder_loads_and_its_legs_move_its_feet(tmp_path):
    path = write_spec(tmp_path, "long_legs", thigh_length=0.3, calf_length=0.35)
    robot = load_robot(str(path))
    assert "long_legs" not in robot_names()
    assert robot.name == "long_legs" and robot.mjcf_path == (tmp_path / "long_legs.xml").resolve()
    assert load_robot(path) == robot and robot.spec_file == path.resolve()
    q = np.zeros((1, 12))  # straight legs: each foot straight below its thigh
    feet = robot.foot_positions_body(q)[0]
    np.testing.assert_allclose(feet[:, 2], -0.65)
    np.testing.assert_allclose(A1.foot_positions_body(q)[0][:, 2], -0.4)
    np.testing.assert_allclose(feet[:, 0], HIP_OFFSETS[:, 0])
    np.testing.assert_allclose(feet[:, 1], HIP_OFFSETS[:, 1] + THIGH_OFFSET_Y)
    pose = robot.foot_positions_body(np.array(robot.default_pose))
    assert not np.allclose(pose, A1.foot_positions_body(DEFAULT_POSE))


BAD_SPECS = {
    "missing field": ({"kp": None}, "missing field(s) ['kp']"),
    "unknown field": ({"kpp": 30.0}, "unknown field(s) ['kpp']"),
    "short default_pose": ({"default_pose": A1_POSE[:11]},
                           "default_pose has 11 values; one per joint needs 12"),
    "negative kp": ({"kp": -30.0}, "kp = -30.0 must be > 0"),
    "negative kd": ({"kd": -0.1}, "kd = -0.1 must be >= 0"),
    "infinite torque": ({"torque_limit": float("inf")}, "torque_limit = inf is not a finite number"),
    "nan in the pose": ({"default_pose": [float("nan"), *A1_POSE[1:]]},
                        "default_pose[0] = nan is not a finite number"),
    "text gain": ({"kd": "0.7"}, "kd = '0.7' is not a finite number"),
    "duplicate joint": ({"joints": ["FL_hip", *JOINT_NAMES[:11]]},
                        "joints: duplicate name(s) ['FL_hip']"),
    "joints vs feet": ({"joints": list(JOINT_NAMES[:9])}, "joints has 9 names; 4 feet need 12"),
    "three hips": ({"hip_offsets": A1_HIPS[:3]}, "hip_offsets has 3 pairs"),
    "short thigh offsets": ({"thigh_offset_y": A1_THIGH_Y[:2]}, "thigh_offset_y has 2 values"),
    "zero decimation": ({"decimation": 0}, "decimation = 0 must be a whole number >= 1"),
    "unknown sensor": ({"sensors": ["joint_pos", "lidar"]}, "unknown sensor(s) ['lidar']"),
    "missing mjcf": ({"mjcf": "nowhere.xml"}, "mjcf = 'nowhere.xml' resolves to"),
}


@pytest.mark.parametrize("case", sorted(BAD_SPECS))
def test_a_bad_spec_is_a_one_line_error_naming_file_and_field(tmp_path, case):
    changes, message = BAD_SPECS[case]
    path = write_spec(tmp_path, **changes)
    with pytest.raises(ValueError) as err:
        load_robot(path)
    text = str(err.value)
    assert "\n" not in text and message in text and str(path) in text, text


def test_a_file_that_is_not_toml_and_a_missing_file_are_named(tmp_path):
    path = tmp_path / "broken.toml"
    path.write_text("kp = = 30\n")
    with pytest.raises(ValueError, match=r"broken\.toml: not a TOML file"):
        load_robot(path)
    with pytest.raises(ValueError, match=r"robot spec file .*absent\.toml does not exist"):
        load_robot(tmp_path / "absent.toml")


def test_an_unknown_robot_name_lists_the_shipped_ones():
    with pytest.raises(ValueError) as err:
        load_robot("b2")
    assert str(err.value).startswith("unknown robot 'b2'; shipped robots: ['a1', 'go1']")
    assert "\n" not in str(err.value)


def test_a_description_built_in_code_is_checked_normalized_and_frozen():
    values = {f: getattr(A1, f) for f in SPEC_FIELDS}
    robot = RobotDescription(**values | {"default_pose": DEFAULT_POSE, "kp": 30,
                                         "hip_offsets": HIP_OFFSETS, "joints": list(JOINT_NAMES)})
    assert robot == A1 and robot.spec_file is None  # arrays, ints and lists normalized
    assert type(robot.kp) is float and isinstance(robot.hip_offsets[0], tuple)
    assert robot.num_joints == 12 and robot.control_dt == CONTROL_DT
    with pytest.raises(dataclasses.FrozenInstanceError):
        robot.kp = 1.0  # type: ignore[misc]
    with pytest.raises(ValueError, match=r"^decimation = True must be a whole number"):
        RobotDescription(**values | {"decimation": True})
    with pytest.raises(ValueError, match=r"^feet = 'FL_foot' is not a list of names$"):
        RobotDescription(**values | {"feet": "FL_foot"})
