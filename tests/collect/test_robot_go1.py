"""The shipped Go1-class robot: its description loads, it stands in its default pose, and it
offers its own sensor set (joint torques and an accelerometer, no foot-contact switches)
while the A1's sensors, datasets and students stay as they were."""

from __future__ import annotations

import json
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest

from msta.collect.sim.env import QuadrupedEnv
from msta.collect.sim.env_config import EnvConfig, NoiseConfig
from msta.collect.sim.randomization import RandomizationConfig
from msta.collect.sim.robot import build_model, imu_sensor
from msta.collect.sim.spaces import ACCEL_MAX, observation_bounds
from msta.collect.sim.terrain import TerrainConfig
from msta.collect.simulate import main as sim_main
from msta.data.derived import STATE_COLUMN
from msta.data.features import build_features
from msta.data.robot import A1, load_robot, robot_names
from msta.data.sensors import (
    DEFAULT_RECORDED,
    EXTENSION_SENSORS,
    JOINT_NAMES,
    PHYSICAL_SENSORS,
    SENSORS,
    STUDENT_SENSORS,
)

FLAT = TerrainConfig(types=("flat",), num_levels=1, max_init_level=0, border=2.0,
                     curriculum=False)
#: The A1's sensors before the Go1's were added to the registry.
A1_SENSORS = ("joint_pos", "joint_vel", "ang_vel", "gravity", "foot_contact", "command",
              "last_action", "base_lin_vel", "base_ang_vel", "orientation", "base_height",
              "height_scan", "dynamics", "height_map")
GO1_TORQUES = (23.7, 23.7, 35.55) * 4
G = 9.81


def clean(robot: str = "go1", n: int = 4, **kw: object) -> EnvConfig:
    """Flat ground, no randomization or noise."""
    return EnvConfig(robot=robot, num_envs=n, nthread=1, terrain=FLAT,
                     randomization=RandomizationConfig(enabled=False),
                     noise=NoiseConfig(enabled=False), **kw)


def stand(env: QuadrupedEnv, seconds: float) -> dict[str, np.ndarray]:
    """Zero actions (the default pose) for ``seconds``; the last observation."""
    env.reset()
    for _ in range(int(round(seconds / env.dt))):
        res = env.step(np.zeros((env.num_envs, 12)))
        assert not res.done.any()
    return res.obs


def test_the_go1_is_shipped_and_loads_with_its_numbers():
    assert robot_names() == ("a1", "go1")
    go1 = load_robot("go1")
    assert go1.name == "go1" and go1.joints == JOINT_NAMES
    assert go1.joint_torque_limits == GO1_TORQUES and A1.joint_torque_limits == (33.5,) * 12
    assert (go1.thigh_length, go1.calf_length, go1.foot_radius) == (0.213, 0.213, 0.023)
    assert go1.hip_offsets[0] == (0.1881, 0.04675) and go1.thigh_offset_y[1] == -0.08
    assert go1.control_dt == pytest.approx(0.02) and (go1.kp, go1.kd) == (35.0, 0.5)
    assert "foot_contact" not in go1.sensors
    assert {"joint_torque", "base_accel"} <= set(go1.sensors)
    model = build_model(None, robot=go1)
    assert model.actuator_forcerange[:, 1].tolist() == list(GO1_TORQUES)
    assert imu_sensor(model, go1, "accel") == slice(25, 28)  # after the A1's 25 sensors
    assert imu_sensor(build_model(None), A1, "accel") is None
    assert model.body("trunk").mass[0] == pytest.approx(5.204)


def test_a_per_joint_torque_limit_needs_one_positive_number_per_joint(tmp_path):
    spec = tomllib.loads(load_robot("go1").spec_file.read_text())
    spec["mjcf"] = str(load_robot("go1").mjcf_path)
    for bad, words in (([23.7] * 11, "torque_limit has 11 values; one per joint needs 12"),
                       ([23.7] * 11 + [0.0], "torque_limit[11] = 0.0 must be > 0")):
        path = tmp_path / "bad.toml"
        path.write_text("".join(f"{k} = {json.dumps(v)}\n"
                                for k, v in (spec | {"torque_limit": bad}).items()))
        with pytest.raises(ValueError, match=re.escape(words)):
            load_robot(path)


def test_the_go1_stands_three_seconds_in_its_default_pose():
    env = QuadrupedEnv(clean())
    assert env.cfg.control.sim_dt == 0.004 and env.cfg.control.decimation == 5
    stand(env, 3.0)
    height = env.meas["base_height"][:, 0]
    assert ((height > 0.22) & (height < 0.30)).all(), height  # 0.288 m unloaded, PD sag
    assert (env.meas["gravity"][:, 2] < -0.99).all()
    assert env.meas["foot_contact"].all()  # measured for rewards and falls, not offered
    np.testing.assert_allclose(env.meas["joint_pos"], np.tile(env.robot.default_pose, (4, 1)),
                               atol=0.25)
    assert env.resets_by_reason.sum() == 0


def test_the_go1_offers_joint_torques_and_an_accelerometer_but_no_foot_contact():
    env = QuadrupedEnv(clean())
    first = env.reset()
    assert set(first) == set(env.robot.sensors) and "foot_contact" not in first
    np.testing.assert_array_equal(first["base_accel"], 0.0)  # dropped: in free fall
    obs = stand(env, 1.0)
    assert obs["joint_torque"].shape == (4, 12) and obs["base_accel"].shape == (4, 3)
    assert obs["joint_torque"].dtype == obs["base_accel"].dtype == np.float32
    np.testing.assert_allclose(obs["base_accel"][:, 2], G, atol=0.2)  # specific force: up
    assert (np.abs(obs["base_accel"][:, :2]) < 1.0).all()
    tau = obs["joint_torque"].reshape(4, 4, 3)
    assert (np.abs(tau[..., 2]) > 2.0).all()  # the knees hold the trunk up
    assert (np.abs(obs["joint_torque"]) <= np.array(GO1_TORQUES)).all()
    np.testing.assert_allclose(obs["joint_torque"], env.meas["torques"], rtol=1e-6)


def test_noisy_and_per_environment_readings_stay_inside_their_spaces():
    cfg = EnvConfig(robot="go1", num_envs=3, nthread=1, terrain=FLAT)  # noise, randomization
    env = QuadrupedEnv(cfg)
    bounds = observation_bounds(env, "simulator")
    assert bounds["base_accel"][1][2] == pytest.approx(ACCEL_MAX + 0.2)
    assert bounds["joint_torque"][1][2] > 35.55
    rng = np.random.default_rng(0)
    for streams in (None, np.arange(3)):
        obs = env.reset(streams=streams)
        for _ in range(25):
            obs = env.step(rng.uniform(-1.0, 1.0, (3, 12))).obs
            for k in ("joint_torque", "base_accel"):
                low, high = bounds[k]
                assert ((obs[k] >= low) & (obs[k] <= high)).all(), k
        gap = obs["joint_torque"] - env.meas["torques"]
        assert 0 < np.abs(gap).max() <= 0.5 + 1e-5  # the registry's +-0.5 N m


def test_a_robot_listing_base_accel_needs_an_accelerometer(tmp_path):
    data = tomllib.loads(A1.spec_file.read_text()) | {"mjcf": str(A1.mjcf_path),
                                                      "sensors": [*A1_SENSORS, "base_accel"]}
    path = tmp_path / "a1_accel.toml"
    path.write_text("".join(f"{k} = {json.dumps(v)}\n" for k, v in data.items()))
    with pytest.raises(ValueError, match="'base_accel', which needs an accelerometer sensor at "
                                         "its IMU site 'imu'; the MJCF has none") as err:
        QuadrupedEnv(clean(str(path)))
    assert "\n" not in str(err.value)


def test_the_a1s_sensors_datasets_and_students_are_unchanged():
    assert A1.sensors == A1_SENSORS
    assert STUDENT_SENSORS == ("joint_pos", "joint_vel", "ang_vel", "gravity", "foot_contact",
                               "command", "last_action")
    assert PHYSICAL_SENSORS == STUDENT_SENSORS[:5]
    assert DEFAULT_RECORDED == tuple(s for s in A1_SENSORS if s != "height_map")
    assert EXTENSION_SENSORS == ("height_map", "joint_torque", "base_accel", "true_contact")
    assert all(SENSORS[s].group == "proprio" for s in ("joint_torque", "base_accel"))
    state = build_features(None, derived=True)[STATE_COLUMN]
    assert state["shape"] == (49,) and state["names"][-1] == "last_action.RR_calf"
    assert not any(n.startswith(("joint_torque", "base_accel")) for n in state["names"])
    env = QuadrupedEnv(clean("a1", n=2))
    assert tuple(env.reset()) == A1_SENSORS  # every one, in the same order, no others
    assert set(env.step(np.zeros((2, 12))).obs) == set(A1_SENSORS)
    assert "accel" not in env.meas


def test_msta_sim_runs_the_go1(tmp_path: Path, capsys):
    sim_main(["--robot=go1", "--teacher.type=zero", "--seconds=0.2", "--env.num_envs=2",
              "--env.terrain.types=[flat]", "--env.terrain.num_levels=1", "--image=false",
              "--progress=false", f"--output_dir={tmp_path / 'out'}"])
    out = capsys.readouterr().out
    assert "robot=go1" in out and "'fall': 0" in out
