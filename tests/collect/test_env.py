"""Contract and physics tests of the batched simulator (real MuJoCo)."""

from __future__ import annotations

import draccus
import mujoco
import numpy as np
import pytest

from msta.collect.sim.env import REASONS, QuadrupedEnv
from msta.collect.sim.env_config import EnvConfig, NoiseConfig
from msta.collect.sim.randomization import RandomizationConfig
from msta.collect.sim.rewards import RewardConfig, RewardScales
from msta.collect.sim.terrain import TERRAIN_TYPES, TerrainConfig
from msta.data.robot import A1
from msta.data.sensors import SENSORS


def flat_cfg(n: int = 4, **kw) -> EnvConfig:
    """Flat ground, no randomization or noise: a clean physics check."""
    base = {"num_envs": n, "seed": 0, "nthread": 1,
            "terrain": TerrainConfig(types=("flat",), num_levels=1, max_init_level=0,
                                     border=2.0, curriculum=False),
            "randomization": RandomizationConfig(enabled=False),
            "noise": NoiseConfig(enabled=False)}
    base.update(kw)
    return EnvConfig(**base)


def test_reset_and_step_shapes_and_dtypes_for_every_sensor():
    env = QuadrupedEnv(EnvConfig(num_envs=6, nthread=1))
    obs = env.reset()
    res = env.step(np.zeros((6, 12)))
    for o in (obs, res.obs):
        assert tuple(o) == env.robot.sensors  # the A1's: every sensor it lists, in order
        for name in env.robot.sensors:
            spec = SENSORS[name]
            assert o[name].shape == (6, spec.dim), name
            assert o[name].dtype == np.float32, name
            assert np.isfinite(o[name]).all(), name
    assert res.reward.shape == (6,) and res.terminated.dtype == bool
    for k in ("lin_vel_tracking", "ang_vel_tracking", "total"):
        assert res.metrics[k].shape == (6,)


def test_same_seed_gives_identical_trajectories_and_other_seed_differs():
    def run(seed):
        env = QuadrupedEnv(EnvConfig(num_envs=4, seed=seed, nthread=2))
        env.reset()
        rng = np.random.default_rng(1)
        out = []
        for _ in range(30):
            out.append(env.step(rng.normal(0, 0.5, (4, 12))).obs["joint_pos"])
        return np.stack(out), env.state.copy()

    a, sa = run(3)
    b, sb = run(3)
    c, _ = run(4)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(sa, sb)
    assert not np.array_equal(a, c)


@pytest.mark.parametrize("type_name", TERRAIN_TYPES)
def test_every_terrain_type_and_level_hosts_a_robot(type_name):
    cfg = EnvConfig(num_envs=10, nthread=1, terrain=TerrainConfig(curriculum=False))
    env = QuadrupedEnv(cfg)
    t = env.terrain.level_type_index(type_name)
    obs = env.reset(type_idx=np.full(10, t), level=np.arange(10))
    x, y = env.state[:, env.layout.base_pos][:, :2].T
    types, levels = env.terrain.tile_of(np.column_stack([x, y]))
    assert (types == t).all() and (levels == np.arange(10)).all()
    # spawned above the local ground, not inside it
    assert (obs["base_height"][:, 0] > 0.25).all()


def test_level_robot_standing_still_gravity_contacts_and_joint_sensors():
    env = QuadrupedEnv(flat_cfg(n=2))
    env.reset()
    for _ in range(100):  # 2 s with zero action
        res = env.step(np.zeros((2, 12)))
    obs = res.obs
    np.testing.assert_allclose(obs["gravity"], [[0, 0, -1]] * 2, atol=0.03)
    assert (obs["foot_contact"] == 1).all()
    lay = env.layout
    np.testing.assert_allclose(obs["joint_pos"], env.state[:, lay.joint_pos], atol=1e-6)
    np.testing.assert_allclose(obs["joint_vel"], env.state[:, lay.joint_vel], atol=1e-5)
    # base angular velocity in the base frame: MuJoCo's free-joint qvel[3:6] is local
    np.testing.assert_allclose(obs["ang_vel"], env.state[:, lay.base_angvel], atol=1e-5)


def test_joint_sensors_match_an_independent_mujoco_forward():
    env = QuadrupedEnv(flat_cfg(n=1))
    env.reset()
    rng = np.random.default_rng(0)
    for _ in range(20):
        res = env.step(rng.normal(0, 0.3, (1, 12)))
    data = mujoco.MjData(env.model)
    mujoco.mj_setState(env.model, data, env.state[0], mujoco.mjtState.mjSTATE_FULLPHYSICS)
    mujoco.mj_forward(env.model, data)
    np.testing.assert_allclose(res.obs["joint_pos"][0], data.qpos[7:], atol=1e-6)
    np.testing.assert_allclose(res.obs["joint_vel"][0], data.qvel[6:], atol=1e-4)
    rot = data.xmat[1].reshape(3, 3)
    np.testing.assert_allclose(res.obs["base_lin_vel"][0], rot.T @ data.qvel[:3], atol=1e-4)
    np.testing.assert_allclose(res.obs["gravity"][0], rot.T @ [0, 0, -1], atol=1e-5)
    np.testing.assert_allclose(res.obs["orientation"][0], data.qpos[3:7], atol=1e-6)


def test_zero_action_stands_at_least_five_seconds_on_flat():
    env = QuadrupedEnv(flat_cfg(n=3))
    env.reset()
    for _ in range(int(6.0 / env.dt)):
        res = env.step(np.zeros((3, 12)))
        assert not res.done.any()
    assert (res.obs["base_height"][:, 0] > 0.2).all()
    assert env.resets_by_reason.sum() == 0


def test_fall_is_detected_and_counted():
    env = QuadrupedEnv(flat_cfg(n=2))
    env.reset()
    lay = env.layout
    # tip env 0 upside down: trunk hits the ground
    env.state[0, lay.base_quat] = [0.0, 1.0, 0.0, 0.0]
    ended = np.zeros(2, dtype=bool)
    for _ in range(50):
        res = env.step(np.zeros((2, 12)))
        ended |= res.terminated
        if res.terminated[0]:
            assert REASONS[res.reason[0]] == "fall"
    assert ended[0] and not ended[1]
    assert env.resets_by_reason[REASONS.index("fall")] >= 1


def test_termination_penalty_lands_on_the_fall_step_after_the_clip_and_not_on_timeouts():
    rewards = RewardConfig(scales=RewardScales(termination=-100.0))
    env = QuadrupedEnv(flat_cfg(n=2, rewards=rewards, episode_length_s=0.2))
    env.reset()
    env.state[0, env.layout.base_quat] = [0.0, 1.0, 0.0, 0.0]  # upside down: it falls
    falls = truncations = 0
    for _ in range(10):
        res = env.step(np.zeros((2, 12)))
        penalty = res.metrics["termination"]
        assert np.array_equal(penalty != 0, res.terminated)  # none on timeouts
        for i in np.flatnonzero(res.terminated):
            falls += 1
            assert penalty[i] == pytest.approx(-100.0 * env.dt)
            assert res.reward[i] < 0  # the only_positive clip does not hide it
        truncations += int(res.truncated.sum())
        assert (res.reward[~res.terminated] >= 0).all()
    assert falls >= 1 and truncations >= 1
    off = QuadrupedEnv(flat_cfg(n=1))
    off.reset()
    assert "termination" not in off.step(np.zeros((1, 12))).metrics  # off by default


def test_timeout_truncates_and_resets():
    env = QuadrupedEnv(flat_cfg(n=2, episode_length_s=0.2))
    env.reset()
    for i in range(10):
        res = env.step(np.zeros((2, 12)))
        if i < 9:
            assert not res.truncated.any()
    assert res.truncated.all() and not res.terminated.any()
    assert (res.final["length"] == 10).all()
    assert (env.episode_step == 0).all()


def test_physics_blow_up_ends_only_that_episode():
    env = QuadrupedEnv(flat_cfg(n=3))
    env.reset()
    env.state[1, env.layout.qvel.start] = np.nan
    res = env.step(np.zeros((3, 12)))
    assert res.terminated[1] and REASONS[res.reason[1]] == "nan"
    assert not res.done[0] and not res.done[2]
    assert env.resets_by_reason[REASONS.index("nan")] == 1
    for o in res.obs.values():
        assert np.isfinite(o).all()
    res = env.step(np.zeros((3, 12)))
    assert np.isfinite(env.state).all()


@pytest.mark.parametrize("bad", [np.zeros((3, 11)), np.zeros((2, 12)), np.zeros(12)])
def test_wrong_action_shape_errors(bad):
    env = QuadrupedEnv(flat_cfg(n=3))
    env.reset()
    with pytest.raises(ValueError, match="expected \\(3, 12\\)"):
        env.step(bad)


def test_non_finite_action_errors_naming_the_env():
    env = QuadrupedEnv(flat_cfg(n=3))
    env.reset()
    a = np.zeros((3, 12))
    a[2, 5] = np.inf
    with pytest.raises(ValueError, match="env 2 is not finite"):
        env.step(a)


def test_bad_terrain_inputs_error():
    with pytest.raises(ValueError, match="lava"):
        EnvConfig(terrain=TerrainConfig(types=("flat", "lava")))
    env = QuadrupedEnv(flat_cfg(n=2))
    with pytest.raises(ValueError, match="level 7 out of range"):
        env.reset(level=np.array([0, 7]))
    with pytest.raises(ValueError, match="type_idx 3 out of range"):
        env.reset(type_idx=np.array([3, 0]))


def test_unknown_config_key_is_an_error(capsys):
    with pytest.raises(SystemExit):
        draccus.parse(EnvConfig, args=["--num_envs=2", "--bogus=1"])
    assert "unrecognized arguments: --bogus=1" in capsys.readouterr().err
    cfg = draccus.parse(EnvConfig, args=["--num_envs=2", "--control.kp=25"])
    assert cfg.num_envs == 2 and cfg.control.kp == 25


def test_curriculum_moves_levels():
    cfg = EnvConfig(num_envs=4, nthread=1, episode_length_s=0.1,
                    terrain=TerrainConfig(types=("flat",), num_levels=4, max_init_level=2))
    env = QuadrupedEnv(cfg)
    env.reset(level=np.array([2, 2, 2, 2]))
    env.commands.command[:, :2] = [1.0, 0.0]   # asked to walk 1 m/s, stays put -> level down
    env.commands.cfg.use_heading = False
    for _ in range(5):
        env.step(np.zeros((4, 12)))
    assert (env.level == 1).all()


def test_ground_continues_beyond_the_terrain_grid():
    """A robot spawned outside the heightfield stands on the surrounding z = 0 ground."""
    env = QuadrupedEnv(flat_cfg(n=1))
    env.reset()
    lay = env.layout
    x_far = env.terrain.x0 - 5.0
    env.state[0, lay.base_pos] = [x_far, 1.0, A1.spawn_height]
    for _ in range(50):
        res = env.step(np.zeros((1, 12)))
        assert not res.done[0]
    assert 0.2 < env.state[0, lay.base_pos.start + 2] < 0.4
