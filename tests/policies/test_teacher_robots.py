"""Teachers built for a robot: the gait controller plans with the robot's description, every
teacher reads the simulator's ``true_contact`` on a robot without ``foot_contact``, and on the
A1 nothing changes (docs/robots.md, docs/teachers.md)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from msta_test_helpers import write_robot_spec  # registered by tests/conftest.py

from msta.collect.rollout import run
from msta.collect.sim.env import QuadrupedEnv
from msta.collect.sim.env_config import ControlConfig, EnvConfig
from msta.collect.sim.randomization import RandomizationConfig
from msta.collect.sim.terrain import TerrainConfig
from msta.data.robot import A1, load_robot
from msta.policies.teacher.base import make_teacher, teacher_view
from msta.policies.teacher.config import (
    SHIPPED_RMA,
    SHIPPED_RMA_PPO,
    TeacherConfig,
    build_teacher,
    teacher_revision,
)
from msta.policies.teacher.gait import GaitConfig, GaitTeacher
from msta.policies.teacher.gait_kinematics import leg_ik, max_reach

FLAT = TerrainConfig(types=("flat",), num_levels=1, max_init_level=0, border=2.0,
                     curriculum=False)
GO1 = load_robot("go1")


def flat_env(robot: str, n: int = 4) -> QuadrupedEnv:
    return QuadrupedEnv(EnvConfig(robot=robot, num_envs=n, seed=0, nthread=1, terrain=FLAT,
                                  randomization=RandomizationConfig(pool_size=2)))


def test_the_go1s_observations_hold_the_simulators_contacts_for_teachers():
    env = flat_env("go1")
    obs = env.reset()
    assert "foot_contact" not in obs and "true_contact" in obs
    for _ in range(20):
        obs = env.step(np.zeros((4, 12))).obs
    assert np.array_equal(obs["true_contact"], env.meas["foot_contact"].astype(np.float32))
    assert obs["true_contact"].all()  # standing: every foot down
    view = teacher_view(obs)
    assert view["foot_contact"] is obs["true_contact"] and "foot_contact" not in obs
    a1_obs = flat_env("a1").reset()
    assert "true_contact" not in a1_obs and teacher_view(a1_obs) is a1_obs


def test_the_gait_teacher_plans_with_the_robots_description():
    a1, go1 = GaitTeacher(), make_teacher("gait", robot=GO1)
    assert a1.robot is A1 and a1.cfg == GaitConfig()  # the A1's: the defaults, unchanged
    assert go1.robot is GO1 and (go1.cfg.kp, go1.cfg.dt) == (35.0, 0.02)
    assert np.allclose(go1.nominal_xy[:, 0], [0.1881, 0.1881, -0.1881, -0.1881])
    assert max_reach(GO1) == pytest.approx(0.411)
    feet = GO1.foot_positions_body(np.array([GO1.default_pose]))
    assert np.allclose(leg_ik(feet, GO1), [GO1.default_pose], atol=1e-9)
    assert not np.allclose(leg_ik(feet), [GO1.default_pose], atol=1e-3)  # the A1's legs differ
    assert teacher_revision(TeacherConfig(type="gait"), GO1) != teacher_revision(
        TeacherConfig(type="gait"))


def test_the_teacher_follows_the_control_numbers_in_force():
    robot = EnvConfig(control=ControlConfig(kp=25.0)).teacher_robot
    assert robot.kp == 25.0 and robot.name == "a1"
    assert build_teacher(TeacherConfig(type="gait"), robot).cfg.kp == 25.0
    assert EnvConfig().teacher_robot == A1


def test_a_robot_without_any_contacts_is_refused_in_one_line(tmp_path: Path):
    sensors = tuple(s for s in GO1.sensors if s != "true_contact")
    robot = load_robot(write_robot_spec(tmp_path, "blind", base=GO1, sensors=sensors))
    with pytest.raises(ValueError) as err:
        build_teacher(TeacherConfig(type="gait"), robot)
    msg = str(err.value)
    assert "\n" not in msg and "'blind'" in msg and "foot_contact" in msg and "joint_pos" in msg
    assert build_teacher(TeacherConfig(type="zero"), robot).act(
        {"joint_pos": np.zeros((3, 12), dtype=np.float32)}).shape == (3, 12)


@pytest.mark.parametrize("kind", ["gait", "rma"])
def test_every_teacher_acts_on_the_go1(kind: str):
    env = flat_env("go1", n=2)
    teacher = build_teacher(TeacherConfig(type=kind).for_robot("go1"), env.cfg.teacher_robot)
    a = teacher.act(env.reset())
    assert a.shape == (2, 12) and np.isfinite(a).all()


@pytest.mark.parametrize("path", [SHIPPED_RMA, SHIPPED_RMA_PPO])
def test_an_a1_checkpoint_is_refused_on_the_go1_in_one_line(path: Path):
    """Its joint angles read about the A1's pose: on the Go1 it would act on offsets of
    0.1-0.3 rad in every joint, so it is refused wherever it is built."""
    with pytest.raises(ValueError) as err:
        build_teacher(TeacherConfig(type="rma", path=str(path)), GO1)
    msg = str(err.value)
    assert "\n" not in msg and str(path) in msg and "not robot 'go1'" in msg
    assert build_teacher(TeacherConfig(type="rma", path=str(path)), A1) is not None


def test_the_gait_teacher_walks_the_go1_on_flat_ground():
    """No falls in 3 s, and the velocity error well below standing still's (zero teacher)."""
    rows = {}
    for kind in ("gait", "zero"):
        env = QuadrupedEnv(EnvConfig(robot="go1", num_envs=4, seed=0, nthread=1, terrain=FLAT,
                                     episode_length_s=3.0))
        env.reset()
        teacher = build_teacher(TeacherConfig(type=kind), env.cfg.teacher_robot)
        rows[kind] = run(env, teacher, 150, progress=False).per_type["flat"].row()
        assert env.resets_by_reason[1] == 0  # no falls
    assert rows["gait"]["vel_err"] < 0.75 * rows["zero"]["vel_err"]
    assert rows["gait"]["lin_tracking"] > rows["zero"]["lin_tracking"]
