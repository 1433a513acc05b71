"""Each randomization changes what it claims to (real MuJoCo)."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from msta.collect.sim import robot
from msta.collect.sim.env import QuadrupedEnv
from msta.collect.sim.env_config import EnvConfig, NoiseConfig
from msta.collect.sim.randomization import (
    RandomizationConfig,
    apply_params,
    build_pool,
    nominal_params,
)
from msta.collect.sim.terrain import TerrainConfig
from msta.data.robot import DEFAULT_POSE
from msta.data.sensors import DYNAMICS_NAMES

FLAT = TerrainConfig(types=("flat",), num_levels=1, max_init_level=0, border=2.0,
                     curriculum=False)


@pytest.fixture(scope="module")
def base_model():
    return robot.build_model(None)


def _params(**kw) -> np.ndarray:
    p = nominal_params()
    for k, v in kw.items():
        p[DYNAMICS_NAMES.index(k)] = v
    return p


def _stand_height(model: mujoco.MjModel, seconds: float = 1.5) -> float:
    data = mujoco.MjData(model)
    mujoco.mj_setState(model, data, robot.default_state(model), mujoco.mjtState.mjSTATE_FULLPHYSICS)
    data.ctrl[:] = DEFAULT_POSE
    for _ in range(int(seconds / model.opt.timestep)):
        mujoco.mj_step(model, data)
    return float(data.qpos[2])


def test_model_parameters_follow_the_sampled_values(base_model):
    trunk = mujoco.mj_name2id(base_model, mujoco.mjtObj.mjOBJ_BODY, "trunk")
    m = apply_params(base_model, _params(friction=1.1, added_mass=1.5, com_x=0.03,
                                         motor_strength=0.9, kp_factor=1.1, kd_factor=0.95),
                     kp=30, kd=0.7)
    assert np.allclose(m.geom_friction[:, 0], 1.1)
    assert m.body_mass[trunk] == pytest.approx(base_model.body_mass[trunk] + 1.5)
    assert m.body_ipos[trunk][0] == pytest.approx(base_model.body_ipos[trunk][0] + 0.03)
    assert np.allclose(m.actuator_gainprm[:, 0], 30 * 1.1 * 0.9)
    assert np.allclose(m.actuator_biasprm[:, 1], -30 * 1.1 * 0.9)
    assert np.allclose(m.actuator_biasprm[:, 2], -0.7 * 0.95 * 0.9)
    assert np.allclose(m.actuator_forcerange, base_model.actuator_forcerange * 0.9)
    # the base model is untouched
    assert np.allclose(base_model.actuator_gainprm[:, 0], 30)


def test_gains_and_mass_change_the_physics(base_model):
    nominal = _stand_height(apply_params(base_model, _params(), 30, 0.7))
    stiff = _stand_height(apply_params(base_model, _params(kp_factor=2.0), 30, 0.7))
    heavy = _stand_height(apply_params(base_model, _params(added_mass=2.0), 30, 0.7))
    weak = _stand_height(apply_params(base_model, _params(motor_strength=0.8), 30, 0.7))
    assert stiff > nominal + 0.005
    assert heavy < nominal - 0.005
    assert weak < nominal - 0.002


def test_friction_changes_sliding(base_model):
    """A block of the robot pushed sideways slides farther on low friction."""
    def slide(mu):
        m = apply_params(base_model, _params(friction=mu), 30, 0.7)
        d = mujoco.MjData(m)
        mujoco.mj_setState(m, d, robot.default_state(m), mujoco.mjtState.mjSTATE_FULLPHYSICS)
        d.ctrl[:] = DEFAULT_POSE
        for _ in range(200):
            mujoco.mj_step(m, d)
        d.qvel[0] = 1.5
        for _ in range(100):
            mujoco.mj_step(m, d)
        return d.qpos[0]

    assert slide(0.3) > slide(1.2) + 0.02


def test_pool_and_dynamics_observation_agree():
    env = QuadrupedEnv(EnvConfig(num_envs=8, nthread=1, terrain=FLAT,
                                 randomization=RandomizationConfig(pool_size=4)))
    obs = env.reset()
    assert len(env.pool) == 4
    np.testing.assert_allclose(obs["dynamics"], env.pool_params[env.variant], rtol=1e-6)
    for i in range(8):
        assert env._models[i] is env.pool[env.variant[i]]
    lo, hi = env.cfg.randomization.added_mass
    assert (env.pool_params[:, 1] >= lo).all() and (env.pool_params[:, 1] <= hi).all()
    # disabled -> a single nominal model
    env2 = QuadrupedEnv(EnvConfig(num_envs=2, nthread=1, terrain=FLAT,
                                  randomization=RandomizationConfig(enabled=False)))
    assert len(env2.pool) == 1
    np.testing.assert_allclose(env2.pool_params[0], nominal_params())


def test_pushes_change_base_velocity():
    rc = RandomizationConfig(pool_size=1, friction=(0.8, 0.8), added_mass=(0, 0),
                             com_offset=(0, 0), motor_strength=(1, 1), kp_factor=(1, 1),
                             kd_factor=(1, 1), push_interval_s=0.2, push_max_vel=1.0,
                             max_latency_steps=0)
    env = QuadrupedEnv(EnvConfig(num_envs=4, nthread=1, terrain=FLAT, randomization=rc,
                                 noise=NoiseConfig(enabled=False)))
    env.reset()
    speeds = []
    for _ in range(40):
        env.step(np.zeros((4, 12)))
        speeds.append(np.linalg.norm(env.meas["base_lin_vel"][:, :2], axis=1).max())
    assert max(speeds) > 0.3
    no_push = QuadrupedEnv(EnvConfig(num_envs=4, nthread=1, terrain=FLAT,
                                     randomization=RandomizationConfig(enabled=False),
                                     noise=NoiseConfig(enabled=False)))
    no_push.reset()
    for _ in range(40):
        no_push.step(np.zeros((4, 12)))
    assert np.linalg.norm(no_push.meas["base_lin_vel"][:, :2], axis=1).max() < 0.1


def test_latency_delays_proprioception_by_the_sampled_steps():
    rc = RandomizationConfig(pool_size=1, max_latency_steps=3, push_interval_s=0)
    env = QuadrupedEnv(EnvConfig(num_envs=6, nthread=1, terrain=FLAT, randomization=rc,
                                 noise=NoiseConfig(enabled=False)))
    env.reset()
    rng = np.random.default_rng(0)
    truth, seen = [], []
    for _ in range(12):
        res = env.step(rng.normal(0, 0.3, (6, 12)))
        truth.append(env.meas["joint_pos"].copy())
        seen.append(res.obs["joint_pos"].copy())
    assert set(env.latency.tolist()) - {0}, "expected some env with latency > 0"
    for i, lat in enumerate(env.latency):
        np.testing.assert_allclose(seen[-1][i], truth[-1 - lat][i], atol=1e-6)
    # the command and privileged signals are not delayed
    np.testing.assert_allclose(res.obs["base_lin_vel"], env.meas["base_lin_vel"], atol=1e-6)


def test_observation_noise_is_bounded_by_the_registry():
    env = QuadrupedEnv(EnvConfig(num_envs=8, nthread=1, terrain=FLAT,
                                 randomization=RandomizationConfig(enabled=False)))
    env.reset()
    res = env.step(np.zeros((8, 12)))
    err = res.obs["joint_pos"] - env.meas["joint_pos"]
    assert np.abs(err).max() <= 0.01 + 1e-6 and np.abs(err).max() > 0.001
    verr = res.obs["joint_vel"] - env.meas["joint_vel"]
    assert np.abs(verr).max() <= 1.5 + 1e-5 and np.abs(verr).std() > 0.3


def test_bad_randomization_ranges_error():
    with pytest.raises(ValueError, match="friction"):
        RandomizationConfig(friction=(1.0, 0.5))
    with pytest.raises(ValueError, match="added_mass"):
        RandomizationConfig(added_mass=(0.0, float("nan")))
    with pytest.raises(ValueError, match="pool_size"):
        RandomizationConfig(pool_size=0)


def test_build_pool_is_deterministic(base_model):
    cfg = RandomizationConfig(pool_size=3)
    _, a = build_pool(base_model, cfg, 30, 0.7, np.random.default_rng(5))
    _, b = build_pool(base_model, cfg, 30, 0.7, np.random.default_rng(5))
    np.testing.assert_array_equal(a, b)
