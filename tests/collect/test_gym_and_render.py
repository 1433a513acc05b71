"""The Gymnasium view and offscreen rendering of the simulator."""

from __future__ import annotations

import os
import subprocess
import sys
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from gymnasium.vector import AutoresetMode
from gymnasium.wrappers import FlattenObservation, RecordEpisodeStatistics
from gymnasium.wrappers import vector as vector_wrappers

import msta.collect.sim  # noqa: F401  (registers msta/A1-v0)
from msta.collect.sim.env import REASONS
from msta.collect.sim.env_config import EnvConfig
from msta.collect.sim.gym_env import MstaEnv, MstaVectorEnv
from msta.collect.sim.randomization import RandomizationConfig
from msta.collect.sim.terrain import TerrainConfig

FLAT = TerrainConfig(types=("flat",), num_levels=1, max_init_level=0, border=2.0,
                     curriculum=False)
SOME = ("joint_pos", "gravity", "command", "last_action", "height_scan")


def flat(episode_length_s: float = 20.0, **kw) -> EnvConfig:
    """A small flat-ground config; 0.06 s episodes are 3 control steps (dt 0.02 s)."""
    return EnvConfig(num_envs=kw.pop("num_envs", 2), nthread=1, terrain=FLAT,
                     episode_length_s=episode_length_s, **kw)


def test_same_step_autoreset_keeps_the_final_obs_in_infos():
    env = MstaVectorEnv(EnvConfig(num_envs=3, nthread=1, terrain=FLAT, episode_length_s=0.1),
                        sensors=("joint_pos", "gravity", "command", "height_scan"),
                        autoreset_mode=AutoresetMode.SAME_STEP)
    assert env.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
    obs, _info = env.reset(seed=1)
    assert env.observation_space.contains(obs)
    assert set(obs) == {"joint_pos", "gravity", "command", "height_scan"}
    for i in range(5):
        action = env.action_space.sample() * 0.0
        obs, reward, term, trunc, infos = env.step(action)
        assert reward.shape == (3,) and term.shape == (3,) and trunc.shape == (3,)
        assert env.observation_space.contains(obs)
    assert trunc.all()  # 0.1 s episodes end on step 5
    assert infos["_final_obs"].all()
    assert infos["final_obs"]["joint_pos"].shape == (3, 12)
    assert (infos["reason"] == "timeout").all()
    # SAME_STEP: the final observation is the simulator's, the returned one its next episode's
    for k in obs:
        np.testing.assert_array_equal(infos["final_obs"][k], env.sim.final_obs[k])
        np.testing.assert_array_equal(obs[k], env.sim.last_obs[k])
    assert infos["_final_info"].all() and (infos["final_info"]["reason"] == "timeout").all()
    assert (env.sim.episode_step == 0).all()


def test_unknown_sensor_is_rejected():
    with pytest.raises(KeyError, match="sonar"):
        MstaVectorEnv(EnvConfig(num_envs=1, nthread=1, terrain=FLAT), sensors=("sonar",))


def test_importing_the_package_registers_the_id_without_loading_mujoco():
    code = ("import sys, gymnasium as gym, msta.collect.sim; "
            "assert 'msta/A1-v0' in gym.registry and 'mujoco' not in sys.modules")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_ids_make_the_single_and_the_vector_env():
    env = gym.make("msta/A1-v0", cfg=flat(), sensors=SOME)
    assert isinstance(env.unwrapped, MstaEnv) and env.unwrapped.sim.num_envs == 1
    obs, info = env.reset(seed=0)
    assert set(obs) == set(SOME) and env.observation_space.contains(obs) and info == {}
    obs, reward, term, trunc, info = env.step(np.zeros(12, dtype=np.float32))
    assert isinstance(reward, float) and term is False and trunc is False
    assert info["reason"] == "running"
    env.close()
    vec = gym.make_vec("msta/A1-v0", num_envs=3, vectorization_mode="vector_entry_point",
                       cfg=flat(), sensors=SOME)
    assert isinstance(vec, MstaVectorEnv) and vec.num_envs == vec.sim.num_envs == 3
    assert vec.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    assert vec.spec.id == "msta/A1-v0"
    obs, _ = vec.reset(seed=0)
    assert obs["joint_pos"].shape == (3, 12) and vec.observation_space.contains(obs)
    vec.close()


def test_next_step_autoreset_resets_on_the_step_after_the_end():
    env = MstaVectorEnv(flat(0.06), sensors=SOME)  # NEXT_STEP by default; 3-step episodes
    sim = env.sim
    env.reset(seed=3)
    sim.episode_step[1] = 1  # env 1 ends one step before env 0
    zero = np.zeros((2, 12))
    _, _, term, trunc, _ = env.step(zero)
    assert not (term | trunc).any()
    # env 1 ends: its observation is the simulator's last one of that episode
    obs, _, term, trunc, infos = env.step(zero)
    assert trunc.tolist() == [False, True] and not term.any()
    assert sim.final_ids.tolist() == [1] and infos["reason"][1] == "timeout"
    for k in SOME:
        np.testing.assert_array_equal(obs[k][1], sim.final_obs[k][0])
    assert "final_obs" not in infos
    # the simulator has already respawned it; render() still shows the state that ended it
    assert sim.state[1, 0] == 0.0 and env._render_state(1)[0] == pytest.approx(2 * sim.dt)
    # env 1 is reset (its action ignored, even a NaN one); env 0 ends
    act = zero.copy()
    act[1] = np.nan
    obs, reward, term, trunc, infos = env.step(act)
    assert trunc.tolist() == [True, False] and not term.any() and reward[1] == 0.0
    assert infos["_reason"].tolist() == [True, False] and infos["reason"][0] == "timeout"
    assert sim.episode_step[1] == 0 and sim.state[1, 0] == 0.0  # at its spawn, clock at 0
    assert env._render_state(1)[0] == 0.0
    for k in SOME:
        np.testing.assert_array_equal(obs[k][1], sim.last_obs[k][1])
        np.testing.assert_array_equal(obs[k][0], sim.final_obs[k][0])
    np.testing.assert_array_equal(obs["last_action"][1], 0.0)
    first = {k: v[1].copy() for k, v in obs.items()}
    # env 1's first action is applied from that first observation; env 0 is reset
    sim.latency[1] = 0  # a fresh frame next step: the restart left the latency history live
    act = zero.copy()
    act[1] = 0.5
    obs, reward, term, trunc, _ = env.step(act)
    assert reward[0] == 0.0 and not (term | trunc).any()
    assert sim.episode_step.tolist() == [0, 1]
    np.testing.assert_allclose(obs["last_action"][1], 0.5)
    assert not np.array_equal(obs["joint_pos"][1], first["joint_pos"])
    # the new episode of env 1 lasts its full 3 steps
    _, _, _, trunc, _ = env.step(zero)
    assert trunc.tolist() == [False, False]
    _, _, _, trunc, _ = env.step(zero)
    assert trunc.tolist() == [False, True]


def test_next_step_restart_does_not_count_the_ignored_step():
    """1-step episodes: the ignored step ends the new episode too; that end is undone."""
    from msta.collect.sim.commands import CommandConfig

    terrain = TerrainConfig(types=("flat",), num_levels=3, max_init_level=2, border=2.0)
    cmd = CommandConfig(lin_vel_x=(1.0, 1.0), lin_vel_y=(0.0, 0.0), use_heading=False)
    env = MstaVectorEnv(EnvConfig(num_envs=2, nthread=1, terrain=terrain, commands=cmd,
                                  episode_length_s=0.02))
    env.reset(seed=0, options={"level": np.array([2, 2])})
    levels = []
    for t in range(4):
        _, reward, term, trunc, _ = env.step(np.zeros((2, 12)))
        assert trunc.all() == (t % 2 == 0) and not term.any()
        if t % 2:
            assert (reward == 0.0).all() and (env.sim.episode_step == 0).all()
        levels.append(env.sim.level.tolist())
    assert env.sim.resets_by_reason[REASONS.index("timeout")] == 4  # 2 episodes x 2 envs
    assert levels == [[1, 1], [1, 1], [0, 0], [0, 0]]  # one level down per real episode


def test_bad_arguments_are_rejected():
    with pytest.raises(ValueError, match="autoreset_mode"):
        MstaVectorEnv(flat(), autoreset_mode=AutoresetMode.DISABLED)
    with pytest.raises(ValueError, match="render_mode"):
        MstaEnv(flat(), render_mode="human")
    env = MstaEnv(flat(0.02))
    with pytest.raises(ValueError, match="unknown reset option"):
        env.reset(options={"levle": 1})
    env.reset(seed=0)
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(11))
    assert env.step(np.zeros(12))[3] is True
    with pytest.raises(RuntimeError, match="call reset"):
        env.step(np.zeros(12))


def test_single_env_passes_gymnasium_check_env():
    env = gym.make("msta/A1-v0", cfg=flat(), render_mode="rgb_array", width=64, height=48)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped)
    # finite observation ranges, a normalized action, a render: no advice, no warning at all
    assert [str(w.message) for w in caught] == []
    env.close()


def test_wrappers_work_on_both_envs():
    env = RecordEpisodeStatistics(FlattenObservation(
        gym.make("msta/A1-v0", cfg=flat(0.06), sensors=SOME)))
    obs, _ = env.reset(seed=0)
    assert obs.shape == (12 + 3 + 3 + 12 + 187,)
    for _ in range(3):
        obs, _, _, trunc, info = env.step(np.zeros(12))
    assert trunc and info["episode"]["l"] == 3
    vec = MstaVectorEnv(flat(0.06, num_envs=3), sensors=SOME)
    vec = vector_wrappers.RecordEpisodeStatistics(vector_wrappers.FlattenObservation(vec))
    obs, _ = vec.reset(seed=0)
    assert obs.shape == (3, 12 + 3 + 3 + 12 + 187)
    lengths, total = [], np.zeros(3)
    for _ in range(7):  # two episodes: 3 steps, a reset step (reward 0), 3 steps
        obs, reward, _, _, infos = vec.step(np.zeros((3, 12)))
        assert obs.shape == (3, 217)
        total += reward
        if "episode" in infos:
            lengths.append(infos["episode"]["l"].tolist())
    assert lengths == [[3, 3, 3], [3, 3, 3]]
    np.testing.assert_allclose(np.reshape(vec.return_queue, (2, 3)).sum(0), total, rtol=1e-5)


def test_render_returns_an_rgb_frame():
    env = gym.make("msta/A1-v0", cfg=flat(randomization=RandomizationConfig(enabled=False)),
                   render_mode="rgb_array", width=128, height=96)
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (96, 128, 3) and frame.dtype == np.uint8
    assert frame.std() > 5, "the frame should show a scene, not a flat colour"
    env.close()
    with pytest.warns(UserWarning, match="render_mode"):  # nothing rendered, as Gymnasium
        assert MstaEnv(flat()).render() is None
    vec = MstaVectorEnv(flat(num_envs=2), render_mode="rgb_array", width=64, height=48)
    vec.reset(seed=0)
    frames = vec.render()
    assert len(frames) == 2 and all(f.shape == (48, 64, 3) for f in frames)
    vec.close()


def test_image_strip_and_video_are_written(tmp_path):
    os.environ.setdefault("MUJOCO_GL", "egl")
    from msta.collect.rollout import film
    from msta.collect.sim.env import QuadrupedEnv
    from msta.collect.sim.render import save_strip, save_video

    env = QuadrupedEnv(EnvConfig(num_envs=2, nthread=1,
                                 randomization=RandomizationConfig(enabled=False)))
    env.reset()
    frames = film(env, lambda obs: np.zeros((2, 12)), steps=20, every=5, size=(96, 128))
    assert len(frames) == 4 and frames[0].shape == (96, 128, 3)
    assert frames[0].std() > 5, "the frame should show a scene, not a flat colour"
    strip = save_strip(frames, tmp_path / "strip.png")
    video = save_video(frames, tmp_path / "clip.mp4", fps=5)
    assert strip.stat().st_size > 1000 and video.stat().st_size > 500
    import matplotlib.image

    img = matplotlib.image.imread(strip)
    assert img.shape[1] == 4 * 128


@pytest.mark.parametrize("terrain", [TerrainConfig(),  # every type; flat ground alone:
                                     TerrainConfig(types=("flat",), columns_per_type=1)])
def test_the_patch_renderer_draws_the_full_terrains_picture(terrain):
    """The env's frames (the terrain within 8 m of the robot) against frames of the whole
    heightfield, for robots on every terrain type and on flat ground far from the origin,
    also after the robot moved far enough that the patch is cut again: the same picture up
    to the far background."""
    import mujoco

    from msta.collect.sim.env import QuadrupedEnv
    from msta.collect.sim.render import PatchRenderer, make_renderer, render_state

    env = QuadrupedEnv(EnvConfig(num_envs=5, nthread=1, seed=1, terrain=terrain,
                                 randomization=RandomizationConfig(enabled=False)))
    env.reset()
    patch = PatchRenderer(env.model, env.terrain, env.cfg.collision, 96, 128)
    full = make_renderer(env.model, 96, 128)
    data = mujoco.MjData(env.model)
    diffs = []
    for i in range(env.num_envs):
        state = env.state[i].copy()
        for shift in (0.0, 3.0):  # 3 m east: beyond radius / 4, a new patch
            state[1] += shift
            a = patch.render(state).astype(np.int16)
            b = render_state(full, env.model, data, state).astype(np.int16)
            lower = slice(a.shape[0] // 2, None)  # the ground near the robot, and the robot
            diffs.append(np.abs(a[lower] - b[lower]).mean())
            assert np.abs(a - b).mean() < 8, (i, shift)  # up to the far background
    assert max(diffs) < 0.5, diffs
    assert patch.centre[0] == pytest.approx(env.state[4, 1] + 3, abs=0.51)
    patch.close()
    full.close()
