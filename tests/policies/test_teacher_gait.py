"""The default gait teacher: protocol contract, kinematics, terrain lookups, and walking
on flat ground in the real MuJoCo simulator."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from msta.collect.sim import robot
from msta.collect.sim.commands import CommandConfig
from msta.collect.sim.env import QuadrupedEnv
from msta.collect.sim.env_config import EnvConfig, NoiseConfig
from msta.collect.sim.randomization import RandomizationConfig
from msta.collect.sim.terrain import TerrainConfig
from msta.data import robot as robot_spec
from msta.data.sensors import HEIGHT_SCAN_X, HEIGHT_SCAN_Y, SENSORS
from msta.policies.teacher.base import Teacher, make_teacher
from msta.policies.teacher.gait import GaitConfig, GaitTeacher
from msta.policies.teacher.gait_kinematics import foot_jacobian, leg_ik
from msta.policies.teacher.gait_state import GaitState
from msta.policies.teacher.gait_terrain import (
    dilate,
    ground_at,
    ground_max_along,
    roughness,
    scan_grid,
)


def _env(n: int, seed: int = 0, terrain: str = "flat") -> QuadrupedEnv:
    # A 12 m border: a robot walking 20 s at 0.6 m/s must not leave the heightfield.
    cfg = EnvConfig(num_envs=n, seed=seed, nthread=1,
                    terrain=TerrainConfig(types=(terrain,), num_levels=1, border=12.0,
                                          max_init_level=0,
                                          curriculum=False),
                    commands=CommandConfig(use_heading=False, resample_s=1e6),
                    randomization=RandomizationConfig(enabled=False),
                    noise=NoiseConfig(enabled=False))
    return QuadrupedEnv(cfg)


def test_contract_shape_dtype_determinism_and_reset():
    env = _env(4)
    obs = env.reset()
    teacher = make_teacher("gait")
    assert isinstance(teacher, Teacher) and teacher.name == "gait"
    assert all(s in SENSORS for s in teacher.sensors)
    a = teacher.act(obs)
    assert a.shape == (4, 12) and a.dtype == np.float32 and np.isfinite(a).all()
    twin = GaitTeacher()
    np.testing.assert_array_equal(twin.act(obs), a)
    # A few steps on, env 2 restarts: its action equals a fresh teacher's.
    for _ in range(7):
        obs = env.step(teacher.act(obs)).obs
    teacher.reset(np.array([2]))
    fresh = GaitTeacher().act({k: v[2:3] for k, v in obs.items()})
    np.testing.assert_allclose(teacher.act(obs)[2], fresh[0], atol=1e-6)
    with pytest.raises(KeyError, match="height_scan"):
        teacher.act({k: v for k, v in obs.items() if k != "height_scan"})


def test_config_validation():
    with pytest.raises(ValueError, match="duty"):
        GaitConfig(duty=1.2)
    with pytest.raises(ValueError, match="raibert_gain"):
        GaitConfig(raibert_gain=(0.1,))
    with pytest.raises(ValueError, match="stance_ground"):
        GaitConfig(stance_ground="scan")
    with pytest.raises(ValueError, match="rough_max_speed"):
        GaitConfig(rough_max_speed=(0.5, 0.0, 1.0))


def test_fk_matches_mujoco_and_ik_round_trip():
    model = robot.build_model(None)
    data = mujoco.MjData(model)
    rng = np.random.default_rng(0)
    q = robot_spec.DEFAULT_POSE + rng.uniform(-0.4, 0.4, (20, 12))
    feet = robot_spec.foot_positions_body(q)
    for i in range(3):
        data.qpos[:7] = (0, 0, 0, 1, 0, 0, 0)
        data.qpos[7:] = q[i]
        mujoco.mj_kinematics(model, data)
        sim = np.array([data.geom(f"{leg}_foot").xpos for leg in robot_spec.LEGS])
        np.testing.assert_allclose(feet[i], sim, atol=1e-9)
    q2 = leg_ik(feet)
    np.testing.assert_allclose(q2, q, atol=1e-9)
    # Jacobian columns: the foot moves by J dq for a small dq.
    jac = foot_jacobian(q)
    dq = rng.normal(0, 1e-4, (20, 12))
    moved = robot_spec.foot_positions_body(q + dq) - feet
    pred = np.einsum("nkij,nkj->nki", jac, dq.reshape(20, 4, 3))
    np.testing.assert_allclose(moved, pred, atol=1e-7)
    # Unreachable targets are projected, never NaN.
    far = feet * 3.0
    assert np.isfinite(leg_ik(far)).all()


def test_height_scan_lookups():
    xs, ys = np.meshgrid(HEIGHT_SCAN_X, HEIGHT_SCAN_Y, indexing="ij")
    plane = 0.3 * xs - 0.2 * ys - 0.3                       # bilinear is exact on a plane
    grid = scan_grid(plane.reshape(1, -1))
    pts = np.array([[[0.13, -0.07], [-0.42, 0.33], [0.0, 0.0]]])
    np.testing.assert_allclose(ground_at(grid, pts), 0.3 * pts[..., 0] - 0.2 * pts[..., 1] - 0.3,
                               atol=1e-12)
    step = np.where(xs >= 0.3, 0.1, 0.0)                     # a 10 cm riser at x = 0.3
    g = scan_grid(step.reshape(1, -1))
    a, b = np.array([[[0.0, 0.1]]]), np.array([[[0.25, 0.1]]])
    assert ground_at(g, b)[0, 0] < 0.1 < ground_max_along(dilate(g), a, b)[0, 0] + 1e-9


def test_roughness_is_zero_on_planes_and_the_riser_height_at_a_step():
    xs, ys = np.meshgrid(HEIGHT_SCAN_X, HEIGHT_SCAN_Y, indexing="ij")
    plane = 0.35 * xs - 0.2 * ys - 0.3
    step = np.where(xs >= 0.3, 0.08, 0.0) - 0.3
    far_step = np.where(xs >= 0.75, 0.08, 0.0) - 0.3           # outside |x| <= 0.6
    r = roughness(scan_grid(np.stack([plane, step, far_step]).reshape(3, -1)))
    np.testing.assert_allclose(r, [0.0, 0.08, 0.0], atol=1e-12)


def test_rough_ground_caps_the_speed_and_lifts_the_feet():
    env = _env(2)
    obs = env.reset()
    xs, _ = np.meshgrid(HEIGHT_SCAN_X, HEIGHT_SCAN_Y, indexing="ij")
    flat = obs["height_scan"][0]
    # A 6 cm riser 0.6 m ahead: rough ground, but not under the feet or the body.
    stairs = flat + np.where(xs >= 0.55, 0.06, 0.0).ravel()
    teacher = GaitTeacher()
    cfg = teacher.cfg
    obs["height_scan"] = np.stack([flat, stairs]).astype(np.float32)
    obs["command"][:] = [1.0, 1.0, 0.0]
    lift = []
    for _ in range(60):
        teacher.act(obs)
        swing = ~teacher.stance
        lift.append(np.where(swing, teacher.feet[..., 2], -np.inf).max(axis=1))
    np.testing.assert_allclose(teacher.ref_cmd[0, :2], cfg.max_speed[:2])
    np.testing.assert_allclose(teacher.ref_cmd[1, :2], cfg.rough_max_speed[:2])
    top = np.max(lift, axis=0)                                  # highest swing foot (H frame)
    np.testing.assert_allclose(top[1] - top[0], cfg.rough_swing_height - cfg.swing_height,
                               atol=2e-3)


def test_climbs_and_descends_stairs():
    """8.6 cm stairs (legged_gym difficulty 0.2) in six directions for 12 s: no falls. The
    stance ground under the measured feet and the rough-ground mode are what make this pass
    (the planned-foot ground fell on these stairs)."""
    cmds = np.array([[0.8, 0, 0], [-0.8, 0, 0], [0, 0.6, 0], [0, -0.6, 0],
                     [0.6, 0.6, 0.3], [-0.6, -0.4, -0.3]])
    cfg = EnvConfig(num_envs=len(cmds), seed=1, nthread=1, episode_length_s=12.0,
                    terrain=TerrainConfig(types=("stairs_up",), num_levels=5, curriculum=False),
                    commands=CommandConfig(use_heading=False, resample_s=1e6),
                    randomization=RandomizationConfig(enabled=False),
                    noise=NoiseConfig(enabled=False))
    env = QuadrupedEnv(cfg)
    obs = env.reset(type_idx=np.zeros(len(cmds), dtype=np.int64),
                    level=np.ones(len(cmds), dtype=np.int64))
    teacher = GaitTeacher()
    start = env.meas["base_pos"][:, 2].copy()
    z = []
    for t in range(env.max_steps - 1):
        env.commands.command[:] = cmds
        obs["command"][:] = cmds
        res = env.step(teacher.act(obs))
        obs = res.obs
        assert not res.terminated.any(), f"env(s) {np.flatnonzero(res.terminated)} fell at {t}"
        z.append(env.meas["base_pos"][:, 2] - start)
    z = np.array(z)
    climbed = z.max(axis=0)
    descended = climbed - np.array([z[z[:, i].argmax():, i].min() for i in range(len(cmds))])
    # Everyone left the pit (at least three 8.5 cm steps up), and at least half walked on
    # over the rim and down the next tile's stairs (at least two steps down).
    assert (climbed > 0.25).all(), climbed.round(2)
    assert (descended > 0.17).sum() >= len(cmds) // 2, descended.round(2)


COMMANDS = np.array([[0.6, 0, 0], [-0.6, 0, 0], [0, 0.5, 0], [0, -0.5, 0],
                     [0, 0, 0.8], [0, 0, -0.8], [0.5, 0.3, 0.5], [0, 0, 0]])


def test_walks_flat_for_20s_under_8_commands():
    env = _env(len(COMMANDS), seed=3)
    obs = env.reset()
    teacher = GaitTeacher()
    lin_err, yaw_err = [], []
    for t in range(env.max_steps - 1):                       # 20 s without a time-out reset
        env.commands.command[:] = COMMANDS
        obs["command"][:] = COMMANDS
        res = env.step(teacher.act(obs))
        obs = res.obs
        assert not res.terminated.any(), f"env(s) {np.flatnonzero(res.terminated)} fell at {t}"
        if t >= 50:
            lin_err.append(np.linalg.norm(env.meas["base_lin_vel"][:, :2] - COMMANDS[:, :2], axis=1))
            yaw_err.append(np.abs(env.meas["base_ang_vel"][:, 2] - COMMANDS[:, 2]))
    lin, yaw = np.mean(lin_err, axis=0), np.mean(yaw_err, axis=0)
    assert (lin < 0.3).all(), f"planar velocity error per command {lin.round(3)}"
    assert (yaw < 0.5).all(), f"yaw-rate error per command {yaw.round(3)}"


def test_reset_accepts_ids_of_a_larger_batch_than_last_seen():
    """A teacher reused with another env count: reset before the next act must not fail."""
    teacher = make_teacher("gait")
    small = QuadrupedEnv(EnvConfig(num_envs=2, nthread=1))
    teacher.act(small.reset())
    teacher.reset(np.arange(6))
    big = QuadrupedEnv(EnvConfig(num_envs=6, nthread=1))
    assert teacher.act(big.reset()).shape == (6, 12)


def test_follow_robot_plans_stance_feet_from_where_they_are():
    """Another policy drives (a slower, scaled-down copy of the teacher's gait); the teacher
    shadows it. Its own plan drifts away from the feet; following the robot, a stance foot's
    plan starts at most ``follow_gap`` from the measured foot (plus one step of sweep)."""
    drift = {}
    for gap in (None, 0.0, 0.03):
        env = _env(4, seed=3)
        obs = env.reset()
        driver = GaitTeacher(GaitConfig(period=0.3))
        shadow = GaitTeacher(GaitConfig(follow_gap=gap or 0.0))
        shadow.follow_robot = gap is not None
        for _ in range(60):
            shadow.act(obs)
            obs = env.step(0.7 * driver.act(obs)).obs
        was_stance = shadow.stance.copy()
        shadow.act(obs)
        actual = GaitState.from_obs(obs).feet_actual[..., :2]
        gap_m = np.linalg.norm(shadow.feet[..., :2] - actual, axis=-1)[was_stance & shadow.stance]
        drift[gap] = float(gap_m.max())
    sweep = 0.05  # dt x the sweep velocity (<= 2.5 m/s)
    assert drift[0.0] < sweep and drift[0.03] < 0.03 + sweep, drift
    assert drift[None] > 2 * drift[0.0] and drift[None] > drift[0.03], drift
    with pytest.raises(ValueError, match="follow_gap"):
        GaitConfig(follow_gap=-0.1)
