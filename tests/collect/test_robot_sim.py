"""The simulator builds the robot its config names (``EnvConfig.robot``): a shipped robot or
a spec file anywhere, its numbers read from the description (docs/robots.md)."""

from __future__ import annotations

import json
import tomllib
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from msta.collect.sim.env import QuadrupedEnv
from msta.collect.sim.env_config import ControlConfig, EnvConfig, NoiseConfig
from msta.collect.sim.randomization import RandomizationConfig
from msta.collect.sim.robot import build_model, spawn_footprint
from msta.collect.sim.terrain import TerrainConfig
from msta.collect.simulate import SimRunConfig
from msta.collect.simulate import main as sim_main
from msta.data.robot import (
    A1,
    ACTION_SCALE,
    CLIP_ACTIONS,
    DECIMATION,
    KD,
    KP,
    SIM_DT,
    load_robot,
)
from msta.policies.teacher.config import TeacherConfig

FLAT = TerrainConfig(types=("flat",), num_levels=1, max_init_level=0, border=2.0,
                     curriculum=False)
#: A robot no shipped file names: the A1's MJCF with other numbers.
OTHER = {"name": "other", "spawn_height": 0.40, "kp": 40.0, "kd": 1.0, "torque_limit": 25.0,
         "default_pose": [0.05, 0.9, -1.6, -0.05, 0.9, -1.6, 0.05, 1.1, -1.6, -0.05, 1.1, -1.6],
         "sim_dt": 0.004, "decimation": 5, "action_scale": 0.3, "clip_actions": 50.0,
         "calf_collision_full": 0.15}


def write_spec(folder: Path, stem: str = "robot", **changes: object) -> Path:
    """The A1's spec with ``changes``, its ``mjcf`` made absolute, written as ``<stem>.toml``."""
    data = tomllib.loads(A1.spec_file.read_text()) | {"mjcf": str(A1.mjcf_path)} | changes
    path = folder / f"{stem}.toml"
    path.write_text("".join(f"{k} = {json.dumps(v)}\n" for k, v in data.items()))
    return path


def clean(robot: str, n: int = 2, **kw: object) -> EnvConfig:
    """Flat ground, no randomization or noise."""
    return EnvConfig(robot=robot, num_envs=n, nthread=1, terrain=FLAT,
                     randomization=RandomizationConfig(enabled=False),
                     noise=NoiseConfig(enabled=False), **kw)


def rollout(cfg: EnvConfig, steps: int) -> dict[str, np.ndarray]:
    env = QuadrupedEnv(cfg)
    first = env.reset()
    t = np.arange(cfg.num_envs * 12).reshape(cfg.num_envs, 12)
    obs, states = [], []
    for i in range(steps):
        res = env.step(0.8 * np.sin(0.07 * i + 0.3 * t))
        obs.append(np.concatenate([res.obs[k].reshape(cfg.num_envs, -1) for k in sorted(res.obs)],
                                  axis=1))
        states.append(env.state.copy())
    return {"first": np.concatenate([first[k] for k in sorted(first)], axis=1),
            "obs": np.stack(obs), "state": np.stack(states), "reasons": env.resets_by_reason}


def test_the_default_robot_is_the_a1_with_its_numbers():
    cfg = EnvConfig(num_envs=1)
    assert cfg.robot == "a1" and cfg.robot_description == A1
    assert cfg.control == ControlConfig()  # every field unset: the robot's
    assert cfg.resolved().control == ControlConfig(KP, KD, ACTION_SCALE, CLIP_ACTIONS, SIM_DT,
                                                   DECIMATION)
    assert cfg.dt == SIM_DT * DECIMATION


def test_the_a1_by_name_and_by_a_copy_of_its_spec_give_identical_rollouts(tmp_path):
    """Randomized, noisy, on rough ground: every observation and state bit for bit."""
    terrain = TerrainConfig(types=("rough_slope", "stairs_up"), num_levels=2, tile_size=4.0,
                            border=2.0)
    base = EnvConfig(num_envs=3, seed=7, nthread=1, terrain=terrain, collision="full",
                     randomization=RandomizationConfig(pool_size=3))
    copy = replace(base, robot=str(write_spec(tmp_path, "a1_copy")))
    assert replace(copy.robot_description, mjcf=A1.mjcf) == A1
    assert copy.robot_description.mjcf_path.samefile(A1.mjcf_path)
    by_name, by_file = rollout(base, 120), rollout(copy, 120)
    for key in by_name:
        assert np.array_equal(by_name[key], by_file[key]), key


def test_the_simulator_uses_a_spec_files_numbers(tmp_path):
    cfg = clean(str(write_spec(tmp_path, **OTHER)))
    env = QuadrupedEnv(cfg)
    assert env.robot.name == "other" and env.cfg.robot == cfg.robot
    assert env.cfg.control == ControlConfig(40.0, 1.0, 0.3, 50.0, 0.004, 5)
    assert env.dt == pytest.approx(0.02) and env.model.opt.timestep == 0.004
    obs = env.reset()
    pose = np.array(OTHER["default_pose"])
    np.testing.assert_allclose(obs["joint_pos"], np.tile(pose, (2, 1)), atol=1e-6)
    assert np.allclose(env.state[:, env.layout.base_pos][:, 2], 0.40)  # flat ground at z = 0
    model = env.pool[0]
    assert (model.actuator_gainprm[:, 0] == 40.0).all()
    assert (model.actuator_biasprm[:, 2] == -1.0).all()
    assert (model.actuator_forcerange == [-25.0, 25.0]).all()
    a1 = QuadrupedEnv(clean("a1"))
    a1.reset()
    action = np.full((2, 12), 0.5)
    env.step(action), a1.step(action)
    assert not np.allclose(env.meas["torques"], a1.meas["torques"])  # other gains and pose
    full = build_model(None, collision="full", robot=env.robot)
    assert full.geom("FL_calf").size[1] == pytest.approx(0.15 / 2)  # capsule half-length


def test_a_set_control_field_wins_over_the_robots(tmp_path):
    cfg = clean(str(write_spec(tmp_path, **OTHER)), control=ControlConfig(kp=25.0))
    control = cfg.resolved().control
    assert (control.kp, control.kd, control.decimation) == (25.0, 1.0, 5)
    assert cfg.control.kp == 25.0 and cfg.control.kd is None  # the config keeps what was set


def test_the_contact_threshold_is_the_robots(tmp_path):
    """A robot whose feet count as in contact only above 1 MN never touches the ground."""
    cfg = clean(str(write_spec(tmp_path, contact_threshold=1e6)))
    standing = {}
    for name, config in (("a1", clean("a1")), ("numb", cfg)):
        env = QuadrupedEnv(config)
        env.reset()
        for _ in range(20):
            res = env.step(np.zeros((2, 12)))
        standing[name] = res.obs["foot_contact"]
    assert standing["a1"].all() and not standing["numb"].any()


@pytest.mark.parametrize(("robot", "words"), [
    ("b2", "env.robot=b2: unknown robot 'b2'; shipped robots: ['a1', 'go1']"),
    ("{bad}", "kp = -1.0 must be > 0"),
    ("{legs}", "sized for 12 joints and 4 feet"),
    ("{missing}", "does not exist"),
])
def test_a_bad_robot_is_a_one_line_error_at_config_construction(tmp_path, robot, words):
    specs = {"{bad}": write_spec(tmp_path, "bad", kp=-1.0),
             "{legs}": write_spec(tmp_path, "legs", joints=A1.joints[:9], feet=A1.feet[:3],
                                  default_pose=A1.default_pose[:9],
                                  hip_offsets=[list(p) for p in A1.hip_offsets[:3]],
                                  thigh_offset_y=A1.thigh_offset_y[:3]),
             "{missing}": tmp_path / "missing.toml"}
    name = str(specs.get(robot, robot))
    with pytest.raises(ValueError) as err:
        EnvConfig(robot=name)
    message = str(err.value)
    assert words in message and "\n" not in message and message.startswith(f"env.robot={name}")


def test_an_mjcf_whose_joints_differ_from_the_spec_is_refused_when_built(tmp_path):
    joints = A1.joints[3:6] + A1.joints[:3] + A1.joints[6:]  # FR before FL
    cfg = clean(str(write_spec(tmp_path, joints=joints)))
    with pytest.raises(ValueError, match="joints after the free joint are .* needs"):
        QuadrupedEnv(cfg)


def test_msta_sim_passes_robot_through(tmp_path, capsys):
    spec = str(write_spec(tmp_path, **OTHER))
    assert SimRunConfig(robot=spec, teacher=TeacherConfig(type="zero")).env.robot == spec
    assert SimRunConfig().env.robot == "a1"
    in_env = SimRunConfig(env=EnvConfig(robot=spec), teacher=TeacherConfig(type="zero"))
    assert in_env.robot == in_env.env.robot == spec  # named in env alone, it is not undone
    sim_main([f"--robot={spec}", "--teacher.type=zero", "--seconds=0.1", "--env.num_envs=2",
              "--env.terrain.types=[flat]", "--env.terrain.num_levels=1", "--image=false",
              "--progress=false", f"--output_dir={tmp_path / 'out'}"])
    assert "robot=other" in capsys.readouterr().out
    with pytest.raises(SystemExit) as e:
        sim_main(["--env.robot=b2", f"--output_dir={tmp_path / 'out'}"])
    err = capsys.readouterr().err.strip()
    assert e.value.code == 2 and len(err.splitlines()) == 1 and "unknown robot 'b2'" in err


def test_the_spawn_probe_is_derived_from_the_hips_and_the_a1s_is_as_before(tmp_path):
    """A reset probes the ground at the hips grown out to 5 cm (and the base centre): on the
    A1 exactly the points it probed before they were derived; a wider robot probes wider."""
    before = np.array([[0.2, 0.15], [0.2, -0.15], [-0.2, 0.15], [-0.2, -0.15], [0, 0]])
    assert np.array_equal(spawn_footprint(A1), before)  # the same numbers, bit for bit
    assert np.array_equal(spawn_footprint(load_robot("go1")), before)  # 0.188 / 0.127 m
    spec = write_spec(tmp_path, "wide", name="wide",
                      hip_offsets=[[0.31, 0.1], [0.31, -0.1], [-0.25, 0.1], [-0.25, -0.1]])
    wide = spawn_footprint(load_robot(spec))  # y: 0.1 + 0.08505 -> 0.2
    np.testing.assert_array_equal(wide, [[0.35, 0.2], [0.35, -0.2], [-0.25, 0.2], [-0.25, -0.2],
                                         [0, 0]])
    env = QuadrupedEnv(EnvConfig(num_envs=1, nthread=1, terrain=FLAT, robot=str(spec)))
    np.testing.assert_array_equal(env._footprint, wide)  # what its resets probe
