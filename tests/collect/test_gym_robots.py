"""The Gymnasium views on another robot than the A1: the ``msta/Go1-v0`` id simulates the Go1,
the default sensors are the student's the robot offers, and a sensor it does not offer is
refused in one line when the env is made."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import msta.collect.sim  # noqa: F401  (registers msta/A1-v0 and msta/Go1-v0)
from msta.collect.sim.env_config import EnvConfig
from msta.collect.sim.gym_env import MstaEnv, view_sensors
from msta.collect.sim.terrain import TerrainConfig
from msta.data.robot import A1, load_robot
from msta.data.sensors import STUDENT_SENSORS

FLAT = TerrainConfig(types=("flat",), num_levels=1, max_init_level=0, border=2.0,
                     curriculum=False)


def flat(**kw) -> EnvConfig:
    return EnvConfig(num_envs=kw.pop("num_envs", 1), nthread=1, terrain=FLAT, **kw)


def test_the_default_sensors_are_the_students_the_robot_offers():
    assert view_sensors(A1, None) == STUDENT_SENSORS  # the A1: the paper's 49 scalars, as before
    go1 = load_robot("go1")
    assert view_sensors(go1, None) == tuple(s for s in STUDENT_SENSORS if s != "foot_contact")
    assert view_sensors(go1, ("joint_torque", "true_contact")) == ("joint_torque", "true_contact")


def test_a_sensor_the_robot_does_not_offer_is_a_one_line_error():
    with pytest.raises(ValueError) as err:
        MstaEnv(flat(robot="go1"), sensors=("joint_pos", "foot_contact"))
    msg = str(err.value)
    assert "\n" not in msg and "'go1'" in msg and "foot_contact" in msg, msg
    with pytest.raises(ValueError, match="joint_torque"):  # the A1 lists no torques
        MstaEnv(flat(), sensors=("joint_torque",))
    with pytest.raises(KeyError, match="bogus"):
        MstaEnv(flat(), sensors=("bogus",))


def test_the_go1_id_simulates_the_go1_and_steps():
    env = gym.make("msta/Go1-v0", cfg=flat(episode_length_s=0.1))
    assert env.spec.id == "msta/Go1-v0" and env.unwrapped.sim.robot.name == "go1"
    assert "foot_contact" not in env.observation_space.spaces
    obs, _ = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    assert obs["joint_pos"].shape == (12,)
    assert env.unwrapped.sim.cfg.control.kp == load_robot("go1").kp  # the Go1's numbers
    for _ in range(3):
        obs, reward, *_ = env.step(np.zeros(12, np.float32))
        assert env.observation_space.contains(obs) and np.isfinite(reward)
    env.close()
    vec = gym.make_vec("msta/Go1-v0", num_envs=2, vectorization_mode="vector_entry_point",
                       cfg=flat(episode_length_s=0.1))
    assert vec.unwrapped.sim.robot.name == "go1" and vec.num_envs == 2
    obs, _ = vec.reset(seed=0)
    assert vec.observation_space.contains(obs)
    vec.close()


def test_a_robot_given_twice_must_be_the_same():
    with pytest.raises(ValueError) as err:
        MstaEnv(flat(robot=str(load_robot("go1").spec_file)), robot="a1")
    assert "\n" not in str(err.value) and "cfg.robot" in str(err.value)
    env = MstaEnv(flat(robot="go1"), robot="go1")  # the same robot twice is fine
    assert env.sim.robot.name == "go1"
    env.close()
