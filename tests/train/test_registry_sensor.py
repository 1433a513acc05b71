"""A sensor added to the registry, and nowhere else but the sensors of the robot that has it
(its description's ``sensors``), flows through every stage: the simulator produces it, msta-collect records it, the processor and an MSTA student read it
(one token per scalar or through an MLP encoder), msta-correct's rounds record it in the
student's episodes, and msta-eval runs the student with and without it."""

from __future__ import annotations

import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import torch

from msta.collect.record import CollectConfig, collect
from msta.collect.sim import env_config
from msta.collect.sim.env_config import EnvConfig
from msta.collect.sim.randomization import RandomizationConfig
from msta.collect.sim.terrain import TerrainConfig
from msta.data import sensors
from msta.data.robot import RobotDescription, load_robot
from msta.data.sensors import SensorSpec
from msta.data.stats import load_stats
from msta.data.windows import load_episode_table
from msta.eval.eval_config import EvalConfig as MstaEvalConfig
from msta.eval.evaluation import evaluate
from msta.policies.checkpoint import PolicyPath
from msta.policies.factory import load_policy, make_policy
from msta.policies.msta import MSTAConfig
from msta.policies.teacher.config import TeacherConfig
from msta.train.correct_config import CorrectConfig, RoundEvalConfig
from msta.train.loop import load_windows
from msta.train.optim import make_optimizer
from msta.train.stage2 import correct
from msta.train.step import train_step

TERRAIN = TerrainConfig(types=("flat", "stairs_up"), num_levels=2, max_init_level=1,
                        border=2.0)


def small_env() -> EnvConfig:
    return EnvConfig(nthread=1, terrain=TERRAIN, randomization=RandomizationConfig(pool_size=2))


def columns(root: Path, *cols: str) -> list[np.ndarray]:
    table = pq.read_table(sorted((root / "data").rglob("*.parquet")), columns=list(cols))
    return [np.stack(table[c].to_numpy(zero_copy_only=False)) for c in cols]


@pytest.mark.parametrize("encoder_tokens", [0, 2])
def test_a_registry_added_sensor_flows_through_every_stage(tmp_path, monkeypatch,
                                                            encoder_tokens):
    # the one edit: a registry entry read from a quantity the simulator measures
    probe = SensorSpec("probe", "extero", ("a", "b", "c"), 0.0, 1.0, extension=True,
                       source="base_lin_vel", encoder_tokens=encoder_tokens,
                       description="a test sensor: the true base velocity")
    monkeypatch.setitem(sensors.SENSORS, "probe", probe)

    def with_probe(name_or_path: str) -> RobotDescription:
        """The robot the simulator builds, with the probe among its sensors (as a robot whose
        spec file lists it)."""
        robot = load_robot(name_or_path)
        return replace(robot, sensors=(*robot.sensors, "probe"))

    monkeypatch.setattr(env_config, "load_robot", with_probe)

    # dataset: recorded only when asked, equal to its source (no noise)
    root = collect(CollectConfig(teacher=TeacherConfig(type="gait"), episodes=4, num_envs=4,
                                 root=str(tmp_path / "ds"), episode_length_s=0.3,
                                 extra_sensors="probe", progress=False, env=small_env()))
    got, src = columns(root, "observation.probe", "privileged.base_lin_vel")
    assert got.shape == (len(src), 3) and (got == src).all()
    assert "observation.probe" in load_stats(root)

    # processor and model: a student that reads it, trained a few steps
    inputs = (*sensors.STUDENT_SENSORS, "probe")
    torch.manual_seed(0)
    policy = make_policy(MSTAConfig.from_preset("tiny", history=3, input_sensors=inputs),
                         load_stats(root))
    windows = load_windows(root, policy, range(4))
    opt = make_optimizer(policy, 1e-3, 0.0)
    rng = np.random.default_rng(0)
    for _ in range(3):
        metrics = train_step(policy, opt, None, windows.get_batch(rng.integers(0, len(windows), 8)),
                             1.0, 0.5)
    assert np.isfinite(metrics["loss"])
    own = ([p for n, p in policy.named_parameters() if "probe" in n] if encoder_tokens
           else [policy.model.bin_embed.weight])
    assert own and all(p.grad is not None and p.grad.abs().sum() > 0 for p in own)
    ckpt = policy.save_pretrained(tmp_path / "student")
    assert load_policy(ckpt).required_sensors == inputs

    # stage 2: the student drives on it and its episodes record it
    shutil.copytree(root, tmp_path / "ds2")
    cfg = CorrectConfig(policy=PolicyPath(str(ckpt)), dataset=str(tmp_path / "ds2"),
                        output_dir=str(tmp_path / "correct"), rounds=1, episodes_per_round=4,
                        num_envs=4, episode_length_s=0.3, env=small_env(),
                        teacher=TeacherConfig(type="gait"), steps=2, batch_size=8,
                        warmup_steps=1, progress=False, device="cpu",
                        eval=RoundEvalConfig(enabled=False))
    correct(cfg)
    eps = load_episode_table(tmp_path / "ds2")
    assert (eps["provenance/source"] == "student").sum() == 4
    got, src = columns(tmp_path / "ds2", "observation.probe", "privileged.base_lin_vel")
    assert (got == src).all()

    # msta-eval: with the sensor and without it (sensor_removal covers the student's inputs)
    metrics = evaluate(MstaEvalConfig(
        policies=str(tmp_path / "correct" / "round_1"), scenarios="sensor_removal",
        trials=2, episode_length_s=0.5, terrains="flat", levels="0",
        output_dir=str(tmp_path / "eval"), progress=False))
    runs = {r["condition"]: r for r in metrics["runs"]}
    assert runs["none"]["status"] == runs["-probe"]["status"] == "ok"
