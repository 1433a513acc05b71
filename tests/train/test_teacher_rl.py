"""The RMA teacher's training path: msta's simulator as an rsl_rl VecEnv, the RMA actor,
the DAgger warm start from the gait controller and msta-train-teacher (resumable)."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from msta_test_helpers import write_robot_spec  # registered by tests/conftest.py
from rsl_rl.env import VecEnv
from rsl_rl.runners import OnPolicyRunner

from msta.collect.sim.env_config import EnvConfig
from msta.collect.sim.terrain import TerrainConfig
from msta.policies.teacher.config import SHIPPED_RMA, TeacherConfig, build_teacher
from msta.policies.teacher.imported import InputScaler
from msta.policies.teacher.rma import RMAConfig, RMATeacher
from msta.train.ppo import latest_checkpoint
from msta.train.ppo_config import PPOConfig
from msta.train.rsl_env import PRIVILEGED, PROPRIO, RslVecEnv
from msta.train.teacher.config import TrainTeacherConfig, WarmStartConfig
from msta.train.teacher.model import RMAActor, load_from_teacher, teacher_runner_cfg, to_teacher
from msta.train.teacher.run import train_teacher
from msta.train.teacher.warmstart import warm_start


def small_env(n: int = 8, seconds: float = 1.0, **kw) -> EnvConfig:
    return EnvConfig(num_envs=n, episode_length_s=seconds, nthread=1,
                     terrain=TerrainConfig(types=("flat", "smooth_slope"), num_levels=3,
                                           max_init_level=1), **kw)


def test_the_simulator_is_an_rsl_rl_vec_env_with_the_teachers_scaling():
    env = RslVecEnv(small_env(seconds=0.2))
    assert isinstance(env, VecEnv) and env.num_actions == 12 and env.max_episode_length == 10
    obs = env.get_observations()
    rma = RMAConfig()
    priv, prop = InputScaler(rma.privileged)(env.raw_obs), InputScaler(rma.proprio)(env.raw_obs)
    assert obs[PRIVILEGED].shape == (8, 205) and obs[PROPRIO].shape == (8, 49)
    np.testing.assert_array_equal(obs[PRIVILEGED].numpy(), priv)
    np.testing.assert_array_equal(obs[PROPRIO].numpy(), prop)
    timeouts = []
    for _ in range(10):
        obs, rew, dones, extras = env.step(torch.zeros(8, 12))
        assert rew.shape == (8,) and rew.dtype == torch.float32 and dones.dtype == torch.bool
        assert "Env/terrain_level" in extras["log"]  # TensorBoard tags without a leading /
        assert not any(k.startswith("/") for k in extras["log"])
        timeouts.append(extras["time_outs"])
    # standing still on easy ground: every episode ends by the time limit at step 10
    assert bool(timeouts[-1].all()) and not any(bool(t.any()) for t in timeouts[:-1])
    assert (env.episode_length_buf == 0).all()           # auto-reset
    env.episode_length_buf = torch.full((8,), 8)         # rsl_rl's init_at_random_ep_len
    assert bool(env.step(torch.zeros(8, 12))[3]["time_outs"].any()) is False
    assert bool(env.step(torch.zeros(8, 12))[3]["time_outs"].all())
    assert env.take_stats()["episodes"] == 16


def test_rsl_rls_runner_trains_the_rma_actor_and_it_exports_to_an_rma_teacher(tmp_path):
    env = RslVecEnv(small_env())
    rma = RMAConfig()
    cfg = teacher_runner_cfg(PPOConfig(num_steps_per_env=4), rma)
    runner = OnPolicyRunner(env, cfg, log_dir=None, device="cpu")
    actor = runner.alg.get_policy()
    assert isinstance(actor, RMAActor)
    before = {k: v.clone() for k, v in actor.state_dict().items()}
    runner.learn(2)
    assert any(not torch.equal(before[k], v) for k, v in actor.state_dict().items())
    teacher = to_teacher(actor, rma)
    obs = env.get_observations()
    with torch.no_grad():
        np.testing.assert_array_equal(actor(obs).numpy(),
                                      teacher(obs[PRIVILEGED], obs[PROPRIO]).numpy())
    teacher.save_pretrained(tmp_path / "t")
    loaded = build_teacher(TeacherConfig(type="rma", path=str(tmp_path / "t")))
    np.testing.assert_allclose(loaded.act(env.raw_obs), teacher.act(env.raw_obs), atol=0)
    fresh = RMATeacher(rma)
    load_from_teacher(actor, fresh)
    with torch.no_grad():
        np.testing.assert_array_equal(actor(obs).numpy(),
                                      fresh(obs[PRIVILEGED], obs[PROPRIO]).numpy())


def label_mse(net: RMATeacher, seed: int) -> float:
    """MSE between the network and the gait controller on the controller's own rollout."""
    env = RslVecEnv(small_env(16, 2.0, seed=seed))
    gait = build_teacher(TeacherConfig(type="gait"))
    gait.reset(np.arange(16))
    obs, errs = env.raw_obs, []
    for _ in range(50):
        label = gait.act(obs)
        errs.append(float(((net.act(obs) - label) ** 2).mean()))
        res = env.sim.step(label)
        obs = res.obs
        if res.done.any():
            gait.reset(np.flatnonzero(res.done))
    return float(np.mean(errs))


def test_the_warm_start_imitates_the_gait_controller(tmp_path):
    torch.manual_seed(0)
    untrained = label_mse(RMATeacher(RMAConfig()), seed=5)
    cfg = WarmStartConfig(iterations=2, steps=60, fit_steps=200, batch_size=512,
                          beta_decay=0.5)
    net = warm_start(small_env(16, 2.0), RMAConfig(), cfg, tmp_path / "ws", log=lambda s: None)
    trained = label_mse(net, seed=5)   # held-out episodes (another seed)
    assert trained < 0.5 * untrained, (trained, untrained)
    history = json.loads((tmp_path / "ws" / "warmstart.json").read_text())["history"]
    assert [h["beta"] for h in history] == [1.0, 0.5]
    assert history[-1]["fit_mse"] < history[0]["label_mse_on_rollout"]
    # a finished warm start is loaded, not trained again
    again = warm_start(small_env(16, 2.0), RMAConfig(), cfg, tmp_path / "ws", log=lambda s: None)
    o = RslVecEnv(small_env(4)).raw_obs
    np.testing.assert_array_equal(again.act(o), net.act(o))


def test_msta_train_teacher_runs_both_stages_and_resumes(tmp_path):
    def cfg(iterations: int) -> TrainTeacherConfig:
        return TrainTeacherConfig(
            output_dir=str(tmp_path), num_threads=1, device="cpu",
            warmstart=WarmStartConfig(iterations=1, steps=20, fit_steps=5),
            ppo=PPOConfig(iterations=iterations, num_steps_per_env=4, save_interval=2,
                          critic_warmup=2, snapshot_interval=3),
            env=small_env())

    logs: list[str] = []
    path = train_teacher(cfg(4), log=logs.append)
    assert any("(critic only)" in line for line in logs)
    curve = json.loads((tmp_path / "curve.json").read_text())
    assert [r["iteration"] for r in curve] == [2, 4] and curve[0]["critic_only"]
    assert curve[1]["env_steps"] == 4 * 4 * 8
    assert latest_checkpoint(tmp_path / "ppo")[1] == 3
    assert len(list((tmp_path / "ppo").glob("model_*.pt"))) == 2        # pruned
    assert list((tmp_path / "ppo").glob("events.out.tfevents.*"))          # TensorBoard
    first = build_teacher(TeacherConfig(type="rma", path=str(path)))
    # the same command with a larger total continues from iteration 4
    logs.clear()
    train_teacher(cfg(6), log=logs.append)
    assert any("resuming from model_3.pt (4/6" in line for line in logs)
    curve = json.loads((tmp_path / "curve.json").read_text())
    assert [r["iteration"] for r in curve] == [2, 4, 6]
    assert curve[2]["env_steps"] == 6 * 4 * 8
    obs = RslVecEnv(small_env(4)).raw_obs
    # a snapshot at the end of each chunk that reached a multiple of 3 (chunks end at 2, 4, 6)
    snaps = sorted(p.name for p in (tmp_path / "snapshots").iterdir())
    assert snaps == ["iter_4", "iter_6"]
    last = build_teacher(TeacherConfig(type="rma", path=str(tmp_path / "snapshots" / "iter_6")))
    np.testing.assert_array_equal(last.act(obs), build_teacher(
        TeacherConfig(type="rma", path=str(path))).act(obs))
    assert not np.array_equal(build_teacher(TeacherConfig(type="rma", path=str(path))).act(obs),
                              first.act(obs))


def test_ppo_can_start_from_an_existing_rma_teacher(tmp_path):
    def cfg(iterations: int, init_from: str = str(SHIPPED_RMA)) -> TrainTeacherConfig:
        return TrainTeacherConfig(
            output_dir=str(tmp_path), num_threads=1, device="cpu", init_from=init_from,
            ppo=PPOConfig(iterations=iterations, num_steps_per_env=4, save_interval=2,
                          critic_warmup=2),
            env=small_env())

    logs: list[str] = []
    path = train_teacher(cfg(2), log=logs.append)
    assert not (tmp_path / "warmstart").exists()          # no warm start was run
    assert any("starts from the rma teacher" in line for line in logs)
    record = json.loads((tmp_path / "train_teacher.json").read_text())
    assert record["init_from"] == str(SHIPPED_RMA.resolve())
    # the critic-only iterations leave the actor as loaded: the export is the shipped teacher,
    # and the run keeps a copy of its start in init/
    obs = RslVecEnv(small_env(4)).raw_obs
    shipped = RMATeacher.from_pretrained(SHIPPED_RMA).act(obs)
    for d in (path, tmp_path / "init"):
        np.testing.assert_allclose(
            build_teacher(TeacherConfig(type="rma", path=str(d))).act(obs), shipped, atol=1e-6)
    # resuming with another start is refused; without --init_from too (it would warm-start)
    for other in (str(tmp_path / "init"), ""):
        with pytest.raises(ValueError, match="resume it with --init_from="):
            train_teacher(cfg(4, other), log=logs.append)
    assert json.loads((tmp_path / "train_teacher.json").read_text()) == record
    logs.clear()
    train_teacher(cfg(4), log=logs.append)                 # the same start resumes
    assert any("resuming from model_1.pt (2/4" in line for line in logs)
    assert not any("starts from the rma teacher" in line for line in logs)
    bad = TrainTeacherConfig(output_dir=str(tmp_path / "b"), num_threads=1,
                             init_from=str(tmp_path / "none"))
    with pytest.raises(ValueError, match="--init_from="):
        train_teacher(bad, log=logs.append)


def test_a_run_resumed_mid_chunk_realigns_its_chunks_and_replaces_its_curve(tmp_path):
    def cfg(iterations: int) -> TrainTeacherConfig:
        return TrainTeacherConfig(
            output_dir=str(tmp_path), num_threads=1, device="cpu",
            warmstart=WarmStartConfig(iterations=0),
            ppo=PPOConfig(iterations=iterations, num_steps_per_env=4, save_interval=3,
                          critic_warmup=0, snapshot_interval=3),
            env=small_env())

    train_teacher(cfg(4), log=lambda s: None)     # chunks end at 3 and 4 (the total)
    # a reader holding the old curve.json keeps it whole: each row is a new file renamed
    # over the old one (msta.train.state.atomic_json), never the old file rewritten in place
    os.link(tmp_path / "curve.json", tmp_path / "held_curve.json")
    train_teacher(cfg(9), log=lambda s: None)     # resumes at 4: the next chunk ends at 6
    curve = json.loads((tmp_path / "curve.json").read_text())
    assert [r["iteration"] for r in curve] == [3, 4, 6, 9]
    held = json.loads((tmp_path / "held_curve.json").read_text())
    assert [r["iteration"] for r in held] == [3, 4]
    assert not list(tmp_path.glob("*.tmp"))
    assert sorted(p.name for p in (tmp_path / "snapshots").iterdir()) == [
        "iter_3", "iter_6", "iter_9"]
    # a run killed after its checkpoint, before the snapshot: the resume writes the snapshot
    shutil.rmtree(tmp_path / "snapshots" / "iter_9")
    logs: list[str] = []
    train_teacher(cfg(9), log=logs.append)
    assert any("snapshot iter_9 written from model_8.pt" in line for line in logs)
    obs = RslVecEnv(small_env(4)).raw_obs
    np.testing.assert_array_equal(
        build_teacher(TeacherConfig(type="rma", path=str(tmp_path / "snapshots" / "iter_9")))
        .act(obs), build_teacher(TeacherConfig(type="rma", path=str(tmp_path / "teacher")))
        .act(obs))


def test_bad_settings_are_one_line_errors():
    with pytest.raises(ValueError, match="init_std"):
        PPOConfig(init_std=0)
    with pytest.raises(ValueError, match="beta_decay"):
        WarmStartConfig(beta_decay=2)


def test_an_interrupted_warm_start_continues_after_its_last_iteration(tmp_path):
    cfg = WarmStartConfig(iterations=2, steps=10, fit_steps=3, batch_size=64)

    def killed_in_iteration_2(line: str) -> None:
        if line.startswith("warm start 2/2"):   # after iteration 2's fit, before its save
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        warm_start(small_env(), RMAConfig(), cfg, tmp_path, log=killed_in_iteration_2)
    assert (tmp_path / "partial.safetensors").is_file()  # tensors and JSON, nothing pickled
    assert not (tmp_path / "config.json").exists()
    logs: list[str] = []
    warm_start(small_env(), RMAConfig(), cfg, tmp_path, log=logs.append)
    assert logs[0] == "warm start: resuming after iteration 1/2"
    assert [line[:14] for line in logs[1:]] == ["warm start 2/2"]
    history = json.loads((tmp_path / "warmstart.json").read_text())["history"]
    assert [h["iteration"] for h in history] == [0, 1]
    assert not (tmp_path / "partial.safetensors").exists()   # a finished warm start cleans up



class _Payload:
    """Unpickling it creates the file ``path``: what a hostile resume file could run."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def __reduce__(self):
        return (open, (str(self.path), "w"))


@pytest.mark.parametrize("name", ["partial.pt", "partial.safetensors"])
def test_a_resume_file_carrying_a_pickle_payload_is_refused_and_never_runs(tmp_path, name):
    """Issue 41 (15): the warm start's resume state is loaded without unpickling code."""
    marker = tmp_path / "payload_ran"
    out = tmp_path / "warmstart"
    out.mkdir()
    torch.save({"net": _Payload(marker), "opt": {}, "history": []}, out / name)
    cfg = WarmStartConfig(iterations=1, steps=5, fit_steps=1, batch_size=16)
    with pytest.raises(ValueError) as err:
        warm_start(small_env(n=2), RMAConfig(), cfg, out, log=lambda line: None)
    assert str(out / name) in str(err.value) and "\n" not in str(err.value)
    assert not marker.exists()


def test_a_ppo_checkpoint_carrying_a_pickle_payload_is_refused_and_never_runs(tmp_path):
    """rsl_rl unpickles its checkpoints with weights_only=False: a resume reads the newest
    one with weights_only=True first and refuses it in one line."""
    marker = tmp_path / "payload_ran"
    (tmp_path / "ppo").mkdir()
    torch.save({"model_state_dict": _Payload(marker), "iter": 0}, tmp_path / "ppo" / "model_1.pt")
    cfg = TrainTeacherConfig(output_dir=str(tmp_path), num_threads=1, device="cpu",
                             ppo=PPOConfig(iterations=4, num_steps_per_env=4, save_interval=2),
                             env=small_env(n=2))
    with pytest.raises(ValueError) as err:
        train_teacher(cfg, log=lambda line: None)
    assert str(tmp_path / "ppo" / "model_1.pt") in str(err.value) and "\n" not in str(err.value)
    assert not marker.exists()


def test_a_new_teacher_reads_joint_angles_relative_to_its_robots_default_pose(tmp_path):
    """The training env of a robot with another default pose scales its joint angles by that
    pose (RMAConfig.for_robot), not the A1's."""
    pose = [0.05, 0.9, -1.6, -0.05, 0.9, -1.6, 0.05, 1.1, -1.6, -0.05, 1.1, -1.6]
    spec = write_robot_spec(tmp_path, "posed")
    spec.write_text(spec.read_text().replace(
        next(ln for ln in spec.read_text().splitlines() if ln.startswith("default_pose")),
        f"default_pose = {json.dumps(pose)}"))
    env = RslVecEnv(small_env(n=2, seconds=0.2, robot=str(spec)))
    assert env.rma.proprio[0].offset == pose
    obs = env.get_observations()[PROPRIO].numpy()
    np.testing.assert_allclose(obs[:, :12], env.raw_obs["joint_pos"] - np.array(pose), atol=1e-6)
    assert RslVecEnv(small_env(n=2, seconds=0.2)).rma.to_dict() == RMAConfig().to_dict()


def test_a_robot_without_foot_contact_trains_on_its_true_contact(tmp_path):
    """The Go1 offers no foot_contact: the training groups, the warm start and PPO read its
    privileged true_contact in its place, as the RMA teacher does when it acts."""
    env = RslVecEnv(small_env(n=2, seconds=0.2, robot="go1"))
    assert "foot_contact" not in env.raw_obs and "true_contact" in env.raw_obs
    obs = env.step(torch.zeros(2, 12))[0]
    assert obs[PRIVILEGED].shape == (2, 205) and obs[PROPRIO].shape == (2, 49)
    assert all(bool(torch.isfinite(obs[g]).all()) for g in (PRIVILEGED, PROPRIO))
    names, dims = env.proprio_in.names, env.proprio_in.dims
    at = sum(dims[:names.index("foot_contact")])
    np.testing.assert_array_equal(obs[PROPRIO][:, at:at + 4].numpy(), env.raw_obs["true_contact"])
    cfg = TrainTeacherConfig(output_dir=str(tmp_path), num_threads=1, device="cpu",
                             warmstart=WarmStartConfig(iterations=1, steps=5, fit_steps=2),
                             ppo=PPOConfig(iterations=2, num_steps_per_env=4, save_interval=2,
                                           critic_warmup=1),
                             env=small_env(n=2, robot="go1"))
    path = train_teacher(cfg, log=lambda s: None)   # the warm start, then PPO
    teacher = build_teacher(TeacherConfig(type="rma", path=str(path)))
    assert np.isfinite(teacher.act(env.raw_obs)).all()
