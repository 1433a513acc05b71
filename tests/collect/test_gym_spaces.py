"""The Gymnasium views' spaces: finite ranges from the robot and the config, the normalized
action, the student's sensors by default, and rendering on a headless machine."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.wrappers import FlattenObservation

import msta.collect.sim  # noqa: F401  (registers msta/A1-v0)
from msta.collect.sim.env_config import EnvConfig
from msta.collect.sim.gym_env import MstaEnv, MstaVectorEnv
from msta.collect.sim.robot import joint_limits
from msta.collect.sim.spaces import JOINT_POS_MARGIN, ActionMap
from msta.collect.sim.terrain import TerrainConfig
from msta.data.robot import A1, ACTION_SCALE, DEFAULT_POSE
from msta.data.sensors import PRIVILEGED_SENSORS, SENSORS, STUDENT_SENSORS

FLAT = TerrainConfig(types=("flat",), num_levels=1, max_init_level=0, border=2.0,
                     curriculum=False)


def flat(**kw) -> EnvConfig:
    return EnvConfig(num_envs=kw.pop("num_envs", 1), nthread=1, terrain=FLAT, **kw)


def targets(a: np.ndarray, amap: ActionMap) -> np.ndarray:
    """Joint targets of normalized actions (the simulator: default + action_scale * action)."""
    return DEFAULT_POSE + ACTION_SCALE * amap.to_sim(a)


def test_default_observation_is_the_students_sensors_and_privileged_ones_on_request():
    env = MstaEnv(flat())
    assert env.sensors == STUDENT_SENSORS
    flat_env = FlattenObservation(env)
    obs, _ = flat_env.reset(seed=0)
    assert obs.shape == flat_env.observation_space.shape == (49,)
    privileged = tuple(s for s in PRIVILEGED_SENSORS if s in A1.sensors)  # not true_contact
    wide = MstaEnv(flat(), sensors=(*STUDENT_SENSORS, *privileged, "height_map"))
    obs, _ = wide.reset(seed=0)
    assert set(obs) == set(A1.sensors) and wide.observation_space.contains(obs)
    assert FlattenObservation(wide).observation_space.shape == (49 + 3 + 3 + 4 + 1 + 187 + 8
                                                                + 187,)


def test_spaces_state_the_robots_ranges():
    cfg = flat()
    env = MstaEnv(cfg, sensors=A1.sensors)  # every sensor the A1 offers
    for name, box in env.observation_space.items():
        assert np.isfinite(box.low).all() and np.isfinite(box.high).all(), name
        assert (box.low < box.high).all(), name
    lim = joint_limits(env.sim.model)  # the A1 joint ranges of assets/a1.xml
    assert lim[1].tolist() == pytest.approx([-1.0472, 4.1888])
    q, noise = env.observation_space["joint_pos"], SENSORS["joint_pos"].noise
    np.testing.assert_allclose(q.low, lim[:, 0] - JOINT_POS_MARGIN - noise, rtol=1e-6)
    np.testing.assert_allclose(q.high, lim[:, 1] + JOINT_POS_MARGIN + noise, rtol=1e-6)
    cmd = env.observation_space["command"]
    assert cmd.low.tolist() == [-1, -1, -1] and cmd.high.tolist() == [1, 1, 1]
    dyn = env.observation_space["dynamics"]
    assert dyn.low[0] == pytest.approx(0.5) and dyn.high[0] == pytest.approx(1.25)  # friction
    assert env.observation_space["foot_contact"].low.tolist() == [0.0] * 4
    assert env.action_space == gym.spaces.Box(-1.0, 1.0, (12,), np.float32)
    assert env.observation_space["last_action"] == env.action_space
    raw = MstaEnv(cfg, actions="simulator")
    assert raw.action_space.high.tolist() == [raw.sim.cfg.control.clip_actions] * 12
    assert raw.sim.cfg.control.clip_actions == A1.clip_actions  # unset: the robot's
    assert raw.observation_space["last_action"] == raw.action_space
    with pytest.raises(ValueError, match="actions='raw'; expected one of"):
        MstaEnv(cfg, actions="raw")


def test_normalized_actions_span_the_joint_range_with_zero_the_default_pose():
    env = MstaEnv(flat())
    amap, lim = env._map, joint_limits(env.sim.model)
    np.testing.assert_allclose(targets(np.ones(12), amap), lim[:, 1])
    np.testing.assert_allclose(targets(-np.ones(12), amap), lim[:, 0])
    np.testing.assert_allclose(targets(np.zeros(12), amap), DEFAULT_POSE)
    env.action_space.seed(0)
    for _ in range(100):  # action_space.sample() is a pose the joints can take
        t = targets(env.action_space.sample(), amap)
        assert ((t >= lim[:, 0] - 1e-6) & (t <= lim[:, 1] + 1e-6)).all()
    s = np.random.default_rng(0).uniform(-1, 1, (5, 12))
    np.testing.assert_allclose(amap.from_sim(amap.to_sim(s)), s, atol=1e-12)


def test_a_normalized_action_moves_the_robot_as_the_simulator_action_of_its_target():
    norm = MstaVectorEnv(flat(num_envs=2), sensors=A1.sensors)
    sim = MstaVectorEnv(flat(num_envs=2), sensors=A1.sensors, actions="simulator")
    a_obs, _ = norm.reset(seed=4)
    b_obs, _ = sim.reset(seed=4)
    norm.action_space.seed(1)
    for _ in range(15):
        a = 0.3 * norm.action_space.sample()
        a_obs, a_rew, a_term, _, _ = norm.step(a)
        b_obs, b_rew, b_term, _, _ = sim.step(norm._map.to_sim(a))
        for k in A1.sensors:
            if k != "last_action":
                np.testing.assert_array_equal(a_obs[k], b_obs[k], err_msg=k)
        np.testing.assert_allclose(a_obs["last_action"], a, atol=1e-6)  # in the action's units
        np.testing.assert_allclose(b_obs["last_action"], norm._map.to_sim(a), rtol=1e-6)
        np.testing.assert_array_equal(a_rew, b_rew)
        np.testing.assert_array_equal(a_term, b_term)


def test_observations_stay_inside_their_spaces_under_random_actions():
    """Random poses at every step on every terrain type at level 9: robots fall, and every
    simulator reading, with its noise, lies inside its space (the ranges hold the physics;
    clipping did not act); a reading beyond a range is clipped to it."""
    terrain = TerrainConfig(num_levels=10, border=2.0, curriculum=False)
    vec = MstaVectorEnv(EnvConfig(num_envs=12, nthread=1, terrain=terrain),
                        sensors=A1.sensors)
    obs, _ = vec.reset(seed=0, options={"level": np.full(12, 9)})
    assert vec.observation_space.contains(obs)
    vec.action_space.seed(0)
    falls = 0
    for _ in range(60):
        obs, _, _, _, infos = vec.step(vec.action_space.sample())
        assert vec.observation_space.contains(obs)
        raw = {k: v for k, v in vec.sim.last_obs.items() if k != "last_action"}
        for k, v in raw.items():
            box = vec.single_observation_space[k]
            assert ((v >= box.low) & (v <= box.high)).all(), (k, v.min(), v.max())
        falls += int((infos["reason"] == "fall").sum())
    assert falls > 0
    wild = {k: v.copy() for k, v in vec.sim.last_obs.items()}
    wild["joint_vel"][0, 0] = 1e4
    high = vec.single_observation_space["joint_vel"].high[0]
    assert vec._select(wild)["joint_vel"][0, 0] == high


def test_gym_make_steps_without_warnings():
    env = gym.make("msta/A1-v0", cfg=flat())  # wrapped in Gymnasium's passive env checker
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        env.reset(seed=0)
        env.step(env.action_space.sample())
    assert [str(w.message) for w in caught] == []


def test_the_spec_states_the_episode_length_the_env_truncates_at():
    """``env.spec.max_episode_steps`` (read by Gymnasium's tools and by RL libraries) is the
    simulator's time limit, for gym.make and make_vec, without a second TimeLimit."""
    env = gym.make("msta/A1-v0", cfg=EnvConfig(episode_length_s=0.4, seed=0))
    assert env.spec.max_episode_steps == 20 and gym.make("msta/A1-v0").spec.max_episode_steps == 1000
    env.reset(seed=0)
    steps, done = 0, False
    while not done:
        _, _, terminated, truncated, _ = env.step(np.zeros(12, dtype=np.float32))
        steps, done = steps + 1, terminated or truncated
    assert steps == 20 and truncated and not terminated
    vec = gym.make_vec("msta/A1-v0", num_envs=2, vectorization_mode="vector_entry_point")
    assert vec.spec.max_episode_steps == 1000
    assert MstaEnv().spec is None  # made directly, not through gym.make


@pytest.mark.parametrize("first", ["msta.collect.sim", "msta.collect.rollout",
                                   "msta.eval.apps.demo"])
def test_headless_render_goes_through_egl_and_draws_the_robot(first):
    """Without MUJOCO_GL, importing msta's simulator (or a module that loads MuJoCo itself
    before it, as the rollout loop, msta-eval and the demo do) picks EGL on Linux; an
    rgb_array frame shows the scene (not one flat colour) and the robot in it (moving it
    changes the frame). msta's suite runs on Linux with EGL, so this always runs."""
    code = (
        f"import json, os, numpy as np, {first}\n"
        "from msta.collect.sim.env import EnvConfig\n"
        "from msta.collect.sim.gym_env import MstaEnv\n"
        "from msta.collect.sim.randomization import RandomizationConfig\n"
        "from msta.collect.sim.terrain import TerrainConfig\n"
        "assert os.environ['MUJOCO_GL'] == 'egl'\n"
        "t = TerrainConfig(types=('flat',), num_levels=1, border=2.0, curriculum=False)\n"
        "env = MstaEnv(EnvConfig(terrain=t, randomization=RandomizationConfig(enabled=False)),\n"
        "              render_mode='rgb_array', width=96, height=72)\n"
        "env.reset(seed=0)\n"
        "a = env.render()\n"
        "for _ in range(10):\n"
        "    env.step(-np.ones(12, dtype=np.float32))\n"
        "b = env.render()\n"
        "env.close()\n"
        "print(json.dumps({'shape': a.shape, 'dtype': str(a.dtype), 'std': float(a.std()),\n"
        "    'colours': len(np.unique(a.reshape(-1, 3), axis=0)),\n"
        "    'moved': float(np.abs(a.astype(int) - b).mean())}))\n")
    environ = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "PYOPENGL_PLATFORM")}
    out = subprocess.run([sys.executable, "-c", code], env=environ, capture_output=True,
                         text=True, timeout=300, check=False)
    assert out.returncode == 0, out.stderr[-2000:]
    frame = json.loads(out.stdout.strip().splitlines()[-1])
    assert frame["shape"] == [72, 96, 3] and frame["dtype"] == "uint8", frame
    assert frame["std"] > 5 and frame["colours"] > 50, frame  # a scene, not a blank frame
    assert frame["moved"] > 1, frame  # the robot folded its legs: the picture changed


def test_glfw_without_a_display_is_a_one_line_error():
    """MUJOCO_GL=glfw (MuJoCo's default off Linux) needs a window: headless, the renderer
    says so and names EGL."""
    code = ("import mujoco\n"
            "from msta.collect.sim.render import make_renderer\n"
            "try:\n"
            "    make_renderer(mujoco.MjModel.from_xml_string('<mujoco/>'), 16, 16)\n"
            "except RuntimeError as e:\n"
            "    print(e)\n")
    environ = {k: v for k, v in os.environ.items()
               if k not in ("DISPLAY", "WAYLAND_DISPLAY", "PYOPENGL_PLATFORM")}
    out = subprocess.run([sys.executable, "-c", code], env={**environ, "MUJOCO_GL": "glfw"},
                         capture_output=True, text=True, timeout=120, check=False)
    assert out.returncode == 0, out.stderr[-2000:]
    message = out.stdout.strip().splitlines()
    assert len(message) == 1 and "there is no display (DISPLAY is not set): use egl" in message[0]
