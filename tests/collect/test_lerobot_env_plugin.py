"""lerobot_env_msta: msta's simulator as LeRobot's ``--env.type=msta_a1`` (the contract
lerobot-eval relies on, and lerobot-eval itself on a stock ACT policy in a subprocess)."""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
import tomllib
import warnings
from pathlib import Path

import numpy as np
import pytest
from lerobot.envs.configs import EnvConfig
from lerobot.envs.utils import (
    NEW_ROLLOUT_OPTION,
    check_env_attributes_and_types,
    env_to_policy_features,
    preprocess_observation,
)

from lerobot_env_msta import MstaA1EnvConfig  # installed by the Makefile's venv step
from lerobot_env_msta.vector_env import VIDEO_OFF_WARNING, A1VectorEnv
from msta.data import derived
from msta.data.robot import load_robot
from msta.data.sensors import SENSORS, STUDENT_SENSORS

LEROBOT_EVAL = Path(sys.executable).with_name("lerobot-eval")


def offline_env(tmp_path: Path) -> dict[str, str]:
    """Environment of a lerobot subprocess: offline, caches under tmp_path."""
    return {**os.environ, "HF_HUB_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1",
            "WANDB_MODE": "disabled", "HF_HOME": str(tmp_path / "hf"),
            "HF_LEROBOT_HOME": str(tmp_path / "lerobot"), "TORCH_HOME": str(tmp_path / "torch")}


def test_env_type_is_registered_with_the_dataset_features():
    cfg = EnvConfig.get_choice_class("msta_a1")()
    assert isinstance(cfg, MstaA1EnvConfig) and cfg.fps == 50
    feats = env_to_policy_features(cfg)
    want = derived.features([s.column for s in SENSORS.values()])
    assert feats[derived.STATE_COLUMN].shape == tuple(want[derived.STATE_COLUMN]["shape"]) == (49,)
    assert feats[derived.ENV_STATE_COLUMN].shape == (3,)
    assert feats["action"].shape == (12,)


def test_only_the_robots_lerobot_keeps_are_filmed():
    """video_robots robots get real frames, the others gray ones (lerobot-eval keeps the
    first --eval.max_episodes_rendered and drops the rest)."""
    cfg = MstaA1EnvConfig(terrains=("flat",), levels=(0,), episode_length_s=0.1,
                          randomization=False, video_robots=2, video_width=64,
                          video_height=48)
    env = cfg.create_envs(n_envs=4)["flat"][0]
    try:
        env.reset(seed=[1, 2, 3, 4])
        frames = env.call("render")
        assert [f.shape for f in frames] == [(48, 64, 3)] * 4
        assert frames[0].std() > 5 and frames[1].std() > 5  # pictures of the robots
        assert all((f == 128).all() for f in frames[2:])
    finally:
        env.close()


def test_the_robot_option_takes_the_rate_and_the_sensors_from_its_description(tmp_path):
    assert MstaA1EnvConfig().robot == "a1" and MstaA1EnvConfig().fps == 50  # the A1's 0.005 x 4
    cfg = MstaA1EnvConfig(robot="go1", terrains=("flat",), levels=(0,), episode_length_s=0.1,
                          video=False, randomization=False)
    go1 = load_robot("go1")
    assert cfg.fps == round(1 / (go1.sim_dt * go1.decimation)) == 50  # 0.004 s x 5
    offered = [s for s in STUDENT_SENSORS if s != "foot_contact"]
    width = sum(SENSORS[s].dim for s in offered)
    assert env_to_policy_features(cfg)[derived.STATE_COLUMN].shape == (width,) == (45,)
    env = cfg.create_envs(n_envs=2)["flat"][0]
    try:
        assert env.sim_env.sim.robot.name == "go1"
        obs, _ = env.reset(seed=[1, 2])
        raw = env.sim_env.sim.last_obs
        np.testing.assert_array_equal(
            obs["agent_pos"], np.concatenate([raw[s] for s in offered], axis=1))
        assert env.observation_space.contains(obs)
        obs, *_ = env.step(np.zeros((2, 12), np.float32))
        assert obs["agent_pos"].shape == (2, width)
    finally:
        env.close()
    # a robot whose description runs at another rate: its rate, and no other
    data = tomllib.loads(go1.spec_file.read_text()) | {
        "name": "slow", "mjcf": str(go1.mjcf_path), "decimation": 10}
    spec = tmp_path / "slow.toml"
    spec.write_text("".join(f"{k} = {json.dumps(v)}\n" for k, v in data.items()))
    assert MstaA1EnvConfig(robot=str(spec)).fps == 25
    with pytest.raises(ValueError, match="fps=50: robot 'slow' runs at 25 Hz"):
        MstaA1EnvConfig(robot=str(spec), fps=50)
    with pytest.raises(ValueError, match="robot=b2: unknown robot 'b2'"):
        MstaA1EnvConfig(robot="b2")


@pytest.mark.parametrize(("option", "message"), [
    ({"terrains": ("ice",)}, "unknown terrain 'ice'"),
    ({"terrains": ()}, "terrains is empty"),
    ({"levels": (0, 10)}, r"levels \[0, 10\] must be levels in \[0, 10\)"),
    ({"fps": 30}, "robot 'a1' runs at 50 Hz"),
    ({"episode_length_s": 0.0}, "episode_length_s=0.0 must be > 0"),
    ({"platform_size": 9.0}, r"platform_size=9.0 must be in \[0, 8.0\] m"),
    ({"video_robots": -1}, "video_robots=-1 must be >= 0"),
])
def test_bad_options_are_one_line_errors(option, message):
    with pytest.raises(ValueError, match=message):
        MstaA1EnvConfig(**option)


def test_vector_env_gives_lerobot_what_the_datasets_hold(caplog):
    cfg = MstaA1EnvConfig(terrains=("flat", "stairs_up"), levels=(0, 3), episode_length_s=0.1,
                          video=False, randomization=False)
    envs = cfg.create_envs(n_envs=3)
    assert list(envs) == ["flat", "stairs_up"]
    env = envs["flat"][0]
    try:
        obs, _ = env.reset(seed=[7, 8, 9], options={NEW_ROLLOUT_OPTION: True})
        raw = env.sim_env.sim.last_obs
        np.testing.assert_array_equal(
            obs["agent_pos"], np.concatenate([raw[s] for s in STUDENT_SENSORS], axis=1))
        np.testing.assert_array_equal(obs["environment_state"], raw["command"])
        assert env.sim_env.sim.level.tolist() == [3, 0, 3]  # levels[seed % 2]
        assert env.observation_space.contains(obs)
        for box in env.single_observation_space.values():  # finite ranges (spaces.py)
            assert np.isfinite(box.low).all() and np.isfinite(box.high).all()
        # the datasets' action: the simulator's, not the Gymnasium view's normalized one
        assert env.single_action_space.high.tolist() == [100.0] * 12
        again, _ = env.reset(seed=[7, 8, 9])
        np.testing.assert_array_equal(again["agent_pos"], obs["agent_pos"])

        lerobot_obs = preprocess_observation(obs)
        assert {k: tuple(v.shape) for k, v in lerobot_obs.items()} == {
            derived.STATE_COLUMN: (3, 49), derived.ENV_STATE_COLUMN: (3, 3)}
        assert env.call("_max_episode_steps") == (5, 5, 5)
        assert env.call("task") == ("flat",) * 3
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            check_env_attributes_and_types(env)  # task and task_description are there
        for step in range(5):
            _, reward, term, trunc, info = env.step(np.zeros((3, 12), np.float32))
            assert reward.shape == (3,)
            assert info["is_success"].tolist() == [step == 4] * 3  # standing at the time limit
        assert trunc.all() and not term.any()
        A1VectorEnv._warned_video_off = False
        with caplog.at_level(logging.WARNING, logger="lerobot_env_msta.vector_env"):
            assert [f.shape for f in env.call("render")] == [(16, 16, 3)] * 3  # video off
            env.call("render")
        # said once: lerobot-eval will still write (blank) video files, and how to avoid them
        assert [r.getMessage() for r in caplog.records] == [VIDEO_OFF_WARNING]
        assert "--eval.recording=true" in VIDEO_OFF_WARNING
    finally:
        for group in envs.values():
            group[0].close()


def standing_figures(platform_size: float) -> dict[str, tuple[np.ndarray, float]]:
    """Per paper terrain: each robot's initial height-scan spread (m) and the batch's summed
    reward of 30 steps standing still (zero action), seeds 1000-1001 (levels 1 and 2)."""
    cfg = MstaA1EnvConfig(platform_size=platform_size, episode_length_s=1.0, video=False)
    out = {}
    for terrain, group in cfg.create_envs(n_envs=2).items():
        env = group[0]
        try:
            env.reset(seed=[1000, 1001])
            spread = np.ptp(env.sim_env.sim.meas["height_scan"], axis=1)
            total = sum(env.step(np.zeros((2, 12), np.float32))[1].sum() for _ in range(30))
            out[terrain] = (spread, float(total))
        finally:
            env.close()
    return out


def test_each_terrains_robots_start_on_it_and_get_its_own_figures():
    """A robot that stays where it starts: on legged_gym's 3 m spawn platform four of the five
    paper terrains give it the same reward (only the rough slope's noise reaches the
    platform); by default there is no platform, every robot starts on uneven ground and
    each terrain's figure is its own."""
    legacy = standing_figures(3.0)
    assert len({round(total, 5) for _, total in legacy.values()}) == 2, legacy
    now = standing_figures(MstaA1EnvConfig().platform_size)
    assert all((spread > 0.02).all() for spread, _ in now.values()), now
    assert len({round(total, 5) for _, total in now.values()}) == 5, now


@pytest.fixture(scope="module")
def act_checkpoint(tmp_path_factory) -> Path:
    """A small stock ACT policy with an msta dataset's features (untrained, its processors
    saved as lerobot-train saves them)."""
    from lerobot.configs import FeatureType, PolicyFeature
    from lerobot.policies import ACTConfig, make_pre_post_processors
    from lerobot.policies.act.modeling_act import ACTPolicy

    dims = {derived.STATE_COLUMN: 49, derived.ENV_STATE_COLUMN: 3, "action": 12}
    cfg = ACTConfig(
        device="cpu", push_to_hub=False, dim_model=32, dim_feedforward=64, n_heads=2,
        chunk_size=8, n_action_steps=8, latent_dim=8,
        input_features={derived.STATE_COLUMN: PolicyFeature(FeatureType.STATE, (49,)),
                        derived.ENV_STATE_COLUMN: PolicyFeature(FeatureType.ENV, (3,))},
        output_features={"action": PolicyFeature(FeatureType.ACTION, (12,))})
    stats = {k: {"mean": np.zeros(d), "std": np.ones(d)} for k, d in dims.items()}
    out = tmp_path_factory.mktemp("act") / "pretrained_model"
    ACTPolicy(cfg).save_pretrained(out)
    for processor in make_pre_post_processors(cfg, dataset_stats=stats):
        processor.save_pretrained(out)
    return out


def lerobot_eval(checkpoint: Path, out: Path, *options: str) -> dict:
    """Run lerobot-eval (2 episodes per terrain, offline, caches under out) and return its
    eval_info.json."""
    args = [str(LEROBOT_EVAL), "--env.type=msta_a1", f"--policy.path={checkpoint}",
            "--eval.n_episodes=2", "--eval.batch_size=2", "--policy.device=cpu",
            f"--output_dir={out / 'eval'}", *options]
    proc = subprocess.run(args, env=offline_env(out), capture_output=True, text=True,
                          timeout=300, check=False)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert "Overall Aggregated Metrics" in proc.stdout + proc.stderr
    return json.loads((out / "eval" / "eval_info.json").read_text())


def video_frames(path: str) -> np.ndarray:
    """(T, H, W, 3) uint8 frames of an MP4."""
    import av

    with av.open(path) as container:
        return np.stack([f.to_ndarray(format="rgb24") for f in container.decode(video=0)])


def test_lerobot_eval_runs_a_stock_policy_in_the_simulator(act_checkpoint, tmp_path):
    """lerobot-eval finds the plugin by itself, films the robots (video on: real pictures)
    and writes its usual summary."""
    info = lerobot_eval(act_checkpoint, tmp_path, "--env.terrains=[flat]",
                        "--env.episode_length_s=0.1", "--env.video_width=64",
                        "--env.video_height=48")
    assert info["overall"]["n_episodes"] == 2
    assert set(info["per_group"]) == {"flat"}
    assert 0.0 <= info["overall"]["pc_success"] <= 100.0
    paths = info["overall"]["video_paths"]
    assert len(paths) == 2 and all(Path(p).is_file() for p in paths)
    for path in paths:
        frames = video_frames(path)
        assert frames.shape == (5, 48, 64, 3)  # one a step, 5 steps of 0.02 s
        assert frames[0].std() > 5  # a picture of the robot on its terrain, not a blank frame


def test_lerobot_eval_reports_each_terrain_and_writes_no_video_when_asked(act_checkpoint,
                                                                         tmp_path):
    """Two terrains, the same seeds: each terrain's figures are its own (robots start on it;
    0.6 s, since the first 0.1 s after a spawn is a drop onto the ground that no terrain
    changes). --env.video=false renders nothing; with --eval.recording=true (what the
    plugin's warning advises) lerobot-eval films nothing either: no MP4 anywhere."""
    info = lerobot_eval(act_checkpoint, tmp_path, "--env.terrains=[flat,stairs_up]",
                        "--env.episode_length_s=0.6", "--env.video=false",
                        "--eval.recording=true")
    groups = info["per_group"]
    assert set(groups) == {"flat", "stairs_up"} and info["overall"]["n_episodes"] == 4
    assert groups["flat"]["avg_sum_reward"] != groups["stairs_up"]["avg_sum_reward"]
    assert info["overall"].get("video_paths", []) == []
    assert sorted(p.name for p in tmp_path.rglob("*.mp4")) == []
    assert (tmp_path / "eval" / "recordings").is_dir()
