"""msta-finetune-ppo: a frozen-transformer MSTA student fine-tuned by rsl_rl's PPO."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from rsl_rl.runners import OnPolicyRunner
from safetensors.torch import load_file

from msta.collect.record import CollectConfig, collect
from msta.collect.sim.env_config import EnvConfig
from msta.collect.sim.randomization import RandomizationConfig
from msta.collect.sim.terrain import TerrainConfig
from msta.data.stats import load_stats
from msta.policies.actor import StudentActor
from msta.policies.baselines.configs import GRUConfig
from msta.policies.checkpoint import PolicyPath
from msta.policies.factory import load_policy, make_policy
from msta.policies.input_spec import MINIMIZED_SENSORS
from msta.policies.msta import MSTAConfig
from msta.policies.teacher.config import TeacherConfig
from msta.train.finetune_ppo import main
from msta.train.finetune_ppo_config import FinetunePPOConfig, StudentPPOConfig
from msta.train.finetune_ppo_run import (
    DUMMY,
    RECORD,
    STUDENT,
    MSTAActor,
    StudentVecEnv,
    finetune_ppo,
    prepare_start,
    split_window,
    student_runner_cfg,
)

TERRAIN = TerrainConfig(types=("flat", "stairs_up"), num_levels=2, max_init_level=1,
                        border=2.0)


def small_env(n: int = 4, seconds: float = 0.3) -> EnvConfig:
    return EnvConfig(num_envs=n, episode_length_s=seconds, nthread=1, terrain=TERRAIN,
                     randomization=RandomizationConfig(pool_size=2))


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> tuple[Path, Path, Path]:
    """(teacher dataset, tiny MSTA checkpoint at T = 5, tiny GRU checkpoint)."""
    d = tmp_path_factory.mktemp("finetune_ppo")
    root = collect(CollectConfig(teacher=TeacherConfig(type="gait"), episodes=4, num_envs=4,
                                 root=str(d / "ds"), episode_length_s=0.3, progress=False,
                                 env=small_env(), extra_sensors="height_map"))
    torch.manual_seed(0)
    msta = make_policy(MSTAConfig.from_preset("tiny", history=5), load_stats(root))
    gru = make_policy(GRUConfig.from_preset("tiny"), load_stats(root))
    return root, msta.save_pretrained(d / "msta"), gru.save_pretrained(d / "gru")


def make_cfg(base, out: Path, **kw) -> FinetunePPOConfig:
    ppo = kw.pop("ppo", StudentPPOConfig(iterations=2, num_steps_per_env=4, critic_warmup=1,
                                         save_interval=1, num_mini_batches=2,
                                         learning_rate=1e-2, desired_kl=1.0))
    defaults = {"policy": PolicyPath(str(base[1])), "output_dir": str(out), "device": "cpu",
                "num_threads": 1, "history": 3, "env": small_env(seconds=1.0), "ppo": ppo}
    return FinetunePPOConfig(**{**defaults, **kw})


def tensor_hashes(directory: Path) -> dict[str, str]:
    return {k: hashlib.sha256(v.numpy().tobytes()).hexdigest()
            for k, v in load_file(directory / "model.safetensors").items()}


def test_the_student_group_is_the_students_window_and_the_actor_its_action(base, tmp_path):
    """StudentVecEnv's window equals StudentActor's over steps and episode resets, and
    MSTAActor's action mean is the student's own action on it."""
    start, _ = prepare_start(make_cfg(base, tmp_path), tmp_path)
    policy = load_policy(start)
    assert policy.required_sensors == tuple(s for s in policy.required_sensors
                                            if s in MINIMIZED_SENSORS)
    env = StudentVecEnv(small_env(n=3, seconds=0.1), policy)  # episodes of 5 steps
    ref = StudentActor(policy, 3)
    actor = MSTAActor(env.get_observations(), {"actor": [STUDENT]}, "actor", 12,
                      policy_path=str(start), trainable="embeddings",
                      distribution_cfg={"init_std": 0.1})
    obs, raw = env.get_observations(), env.raw_obs
    rng = np.random.default_rng(0)
    saw_reset = False
    for step in range(8):
        want = ref.act(raw)
        win = obs[STUDENT]
        assert win.shape == (3, 3, 30 + 1)  # T = 3; command, joint_pos, gravity, last_action
        np.testing.assert_array_equal(win[..., -1].numpy() > 0.5, ref.pad)
        with torch.no_grad():
            np.testing.assert_allclose(actor(obs).numpy(), want, atol=1e-5)
        obs, _, dones, _ = env.step(torch.from_numpy(rng.normal(0, 0.1, (3, 12))).float())
        raw = env.raw_obs
        if dones.any():
            ref.reset(np.flatnonzero(dones.numpy()))
            saw_reset = True
            # a new episode's window is its first frame, padded
            assert bool(obs[STUDENT][dones][:, :-1, -1].all())
    assert saw_reset
    torch.manual_seed(0)
    sample = actor(obs, stochastic_output=True)
    assert sample.shape == (3, 12) and not torch.allclose(sample, actor(obs))
    assert actor.output_std.mean().item() == pytest.approx(0.1)


def test_ppo_trains_only_the_embeddings_and_the_noise_then_resumes(base, tmp_path):
    cfg = make_cfg(base, tmp_path / "run")
    student = finetune_ppo(cfg, log=lambda *_: None)
    out = Path(cfg.output_dir)
    start = out / "start"
    before, after = tensor_hashes(start), tensor_hashes(student)
    changed = {k for k in before if before[k] != after[k]}
    assert changed and all(k.startswith(("model.bin_embed", "model.sensor_embed"))
                           for k in changed), changed
    assert any(k.startswith("model.blocks") for k in before)  # frozen, and present
    record = json.loads((student / RECORD).read_text())
    assert record["method"] == "ppo" and record["history"] == 3 and record["iterations"] == 2
    assert record["input_sensors"] == list(load_policy(student).required_sensors)
    assert any(k.startswith("model.bin_embed") for k in record["trained_parameters"])
    assert not any(".blocks." in k for k in record["trained_parameters"])
    curve = json.loads((out / "curve.json").read_text())
    assert [r["iteration"] for r in curve] == [1, 2]
    assert curve[0]["critic_only"] and not curve[1]["critic_only"]
    assert curve[-1]["env_steps"] == 2 * 4 * 4  # iterations x steps x robots
    # the fine-tuned student is a plain checkpoint that acts on its T = 3 window
    pol = load_policy(student)
    assert pol.config.history == 3
    acts = StudentActor(pol, 2).act({s: np.zeros((2, 12 if s in ("joint_pos", "last_action")
                                                  else 3), np.float32)
                                     for s in pol.required_sensors})
    assert acts.shape == (2, 12) and np.isfinite(acts).all()
    # resume: a third iteration continues from rsl_rl's checkpoint, start/ is kept
    cfg3 = make_cfg(base, tmp_path / "run", ppo=StudentPPOConfig(
        iterations=3, num_steps_per_env=4, critic_warmup=1, save_interval=1,
        num_mini_batches=2, learning_rate=1e-2, desired_kl=1.0))
    lines: list[str] = []
    finetune_ppo(cfg3, log=lines.append)
    assert any("resuming" in line and "(2/3 iterations)" in line for line in lines)
    assert tensor_hashes(start) == before
    curve = json.loads((out / "curve.json").read_text())
    assert [r["iteration"] for r in curve] == [1, 2, 3]
    assert json.loads((student / RECORD).read_text())["iterations"] == 3
    with pytest.raises(ValueError, match="history=3, not 4"):
        finetune_ppo(make_cfg(base, tmp_path / "run", history=4), log=lambda *_: None)


def test_a_run_resumed_mid_chunk_realigns_its_chunks_and_replaces_its_curve(base, tmp_path):
    """The chunk loop msta-train-teacher runs too (msta.train.ppo.ChunkLoop): after a resume
    from mid-chunk the chunks end at multiples of save_interval again, curve.json is
    replaced atomically, and snapshots (also one lost to a kill) are kept."""
    def cfg(iterations: int) -> FinetunePPOConfig:
        return make_cfg(base, tmp_path, ppo=StudentPPOConfig(
            iterations=iterations, num_steps_per_env=4, critic_warmup=0, save_interval=2,
            snapshot_interval=2, num_mini_batches=2, learning_rate=1e-2, desired_kl=1.0))

    finetune_ppo(cfg(3), log=lambda *_: None)          # chunks end at 2 and 3 (the total)
    os.link(tmp_path / "curve.json", tmp_path / "held_curve.json")
    finetune_ppo(cfg(8), log=lambda *_: None)          # resumes at 3: the next chunk ends at 4
    curve = json.loads((tmp_path / "curve.json").read_text())
    assert [r["iteration"] for r in curve] == [2, 3, 4, 6, 8]
    assert [r["env_steps"] for r in curve] == [n * 4 * 4 for n in (2, 3, 4, 6, 8)]
    # a reader holding the old curve.json keeps it whole (a new file renamed over it)
    held = json.loads((tmp_path / "held_curve.json").read_text())
    assert [r["iteration"] for r in held] == [2, 3]
    assert not list(tmp_path.glob("*.tmp"))
    snaps = tmp_path / "snapshots"
    assert sorted(p.name for p in snaps.iterdir()) == ["iter_2", "iter_4", "iter_6", "iter_8"]
    assert json.loads((snaps / "iter_4" / RECORD).read_text())["iterations"] == 4
    student = tensor_hashes(tmp_path / "student")
    assert tensor_hashes(snaps / "iter_8") == student != tensor_hashes(snaps / "iter_6")
    # killed after the checkpoint, before the snapshot: the resume writes it
    shutil.rmtree(snaps / "iter_8")
    lines: list[str] = []
    finetune_ppo(cfg(8), log=lines.append)
    assert any("snapshot iter_8 written from model_7.pt" in line for line in lines)
    assert tensor_hashes(snaps / "iter_8") == student


def test_a_critic_warmup_leaves_the_student_unchanged(base, tmp_path):
    cfg = make_cfg(base, tmp_path, ppo=StudentPPOConfig(
        iterations=1, num_steps_per_env=4, critic_warmup=1, save_interval=1,
        num_mini_batches=2, learning_rate=1e-2))
    student = finetune_ppo(cfg, log=lambda *_: None)
    assert tensor_hashes(student) == tensor_hashes(tmp_path / "start")


def test_the_runner_uses_the_student_as_its_actor(base, tmp_path):
    cfg = make_cfg(base, tmp_path)
    start, _ = prepare_start(cfg, tmp_path)
    env = StudentVecEnv(cfg.env, load_policy(start))
    runner = OnPolicyRunner(env, student_runner_cfg(cfg.ppo, start, "embeddings+head"),
                            log_dir=None, device="cpu")
    actor = runner.alg.get_policy()
    assert isinstance(actor, MSTAActor)
    trainable = {n for n, p in actor.policy.named_parameters() if p.requires_grad}
    assert trainable == set(actor.trained) and any(".head." in n for n in trainable)
    assert not any(".blocks." in n for n in trainable)


def test_an_added_sensor_needs_statistics_and_gets_them_from_the_dataset(base, tmp_path):
    sensors = ",".join([*MINIMIZED_SENSORS, "height_map"])
    with pytest.raises(ValueError, match="--dataset"):
        prepare_start(make_cfg(base, tmp_path / "a", sensors=sensors), tmp_path / "a")
    start, record = prepare_start(make_cfg(base, tmp_path / "b", sensors=sensors,
                                           dataset=str(base[0])), tmp_path / "b")
    assert record["added_sensors"] == ["height_map"]
    assert load_policy(start).required_sensors[-1] == "height_map"


def test_bad_inputs_are_one_line_errors(base, tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        main([f"--policy.path={base[2]}", f"--output_dir={tmp_path}"])
    assert "gru" in str(e.value) and "\n" not in str(e.value)
    for argv, words in ((["--sensors=joint_pos,nope"], "unknown sensor"),
                        (["--trainable=blocks"], "unknown trainable group"),
                        ([], "policy.path is required")):
        with pytest.raises(SystemExit):
            main([*argv, f"--output_dir={tmp_path}"] + ([f"--policy.path={base[1]}"]
                                                         if argv else []))
        err = capsys.readouterr().err
        assert words in err, err


def test_help_lists_the_options(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--help"])
    assert e.value.code == 0
    text = capsys.readouterr().out
    for opt in ("--policy.path", "--sensors", "--history", "--trainable", "--ppo.iterations",
                "--ppo.critic_warmup", "--ppo.init_std", "--env.num_envs", "--dataset"):
        assert opt in text, opt


def test_dummy_tokens_ride_with_the_rollout_so_the_update_sees_the_same_tokens(base, tmp_path):
    cfg = make_cfg(base, tmp_path, dummy_tokens=8)
    start, _ = prepare_start(cfg, tmp_path)
    env = StudentVecEnv(cfg.env, load_policy(start), dummy_tokens=8)
    runner = OnPolicyRunner(env, student_runner_cfg(cfg.ppo, start, "embeddings", 8),
                            log_dir=None, device="cpu")
    actor = runner.alg.get_policy()
    obs = env.get_observations()
    assert obs[DUMMY].shape == (4, 32) and float(obs[DUMMY].min()) >= 0.0
    with torch.no_grad():
        a = actor(obs)
        torch.testing.assert_close(a, actor(obs))               # fixed by the stored draws
        plain = actor.policy.processor.unnormalize_action(
            actor.policy(split_window(actor.policy, obs[STUDENT]), mask_ratio=0.0))
        assert not torch.allclose(a, plain)                     # and the dummies are there
    nxt = env.step(torch.zeros(4, 12))[0]
    assert not torch.equal(nxt[DUMMY], obs[DUMMY])              # fresh every step
    student = finetune_ppo(cfg, log=lambda *_: None)
    assert json.loads((student / RECORD).read_text())["dummy_tokens"] == 8
    assert tensor_hashes(student) != tensor_hashes(start)
