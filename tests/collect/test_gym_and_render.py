"""The Gymnasium view and offscreen rendering of the simulator."""

from __future__ import annotations

import os

import numpy as np
import pytest

from collect.sim.env import EnvConfig
from collect.sim.gym_env import MstaVectorEnv
from collect.sim.randomization import RandomizationConfig
from collect.sim.terrain import TerrainConfig

FLAT = TerrainConfig(types=("flat",), num_levels=1, max_init_level=0, border=2.0,
                     curriculum=False)


def test_vector_env_follows_the_gymnasium_api():
    env = MstaVectorEnv(EnvConfig(num_envs=3, nthread=1, terrain=FLAT, episode_length_s=0.1),
                        sensors=("joint_pos", "gravity", "command", "height_scan"))
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


def test_unknown_sensor_is_rejected():
    with pytest.raises(KeyError, match="sonar"):
        MstaVectorEnv(EnvConfig(num_envs=1, nthread=1, terrain=FLAT), sensors=("sonar",))


def test_image_strip_and_video_are_written(tmp_path):
    os.environ.setdefault("MUJOCO_GL", "egl")
    from collect.sim.env import QuadrupedEnv
    from collect.sim.render import record, save_strip, save_video

    env = QuadrupedEnv(EnvConfig(num_envs=2, nthread=1,
                                 randomization=RandomizationConfig(enabled=False)))
    env.reset()
    frames = record(env, lambda obs: np.zeros((2, 12)), steps=20, every=5, height=96, width=128)
    assert len(frames) == 4 and frames[0].shape == (96, 128, 3)
    assert frames[0].std() > 5, "the frame should show a scene, not a flat colour"
    strip = save_strip(frames, tmp_path / "strip.png")
    video = save_video(frames, tmp_path / "clip.mp4", fps=5)
    assert strip.stat().st_size > 1000 and video.stat().st_size > 500
    import matplotlib.image

    img = matplotlib.image.imread(strip)
    assert img.shape[1] == 4 * 128
