"""Students that learn, on real teacher data (the default teacher in the real simulator).

1. Stage 1: the MSTA cpu preset, at its defaults (mask ratio 0.75, lr 1e-3), reaches val
   loss_unmasked <= 0.3 on a 48-episode teacher dataset within 1000 steps (the mean action
   scores ~1.0; the first design was still at ~0.5 after 1000 steps and ~0.3 after 4000).
2. Stage 2: one msta-correct round lowers the student's loss on its own states: on fresh,
   held-out student-driven episodes labelled by the teacher, the round-1 checkpoint fits the
   teacher's labels better than the stage-1 checkpoint it started from.

Sizes are the smallest that separate learning from not learning on 2 CPU cores (no timing is
asserted; speed lives in ``make bench-learn``).
"""

from __future__ import annotations

import shutil
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from msta.collect.sim.env_config import EnvConfig
from msta.collect.sim.terrain import TerrainConfig
from msta.eval.apps.demo import easy_terrain_dataset
from msta.policies.factory import load_policy
from msta.policies.msta import MSTAConfig
from msta.policies.teacher.config import TeacherConfig
from msta.train.correct_config import CorrectConfig, RoundEvalConfig
from msta.train.stage1 import train
from msta.train.stage2 import append_episodes, correct, drive_and_label
from msta.train.train_config import TrainConfig

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module", autouse=True)
def two_threads() -> Iterator[None]:
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="module")
def teacher_data(tmp_path_factory) -> Path:
    """48 episodes of 10 s of the default teacher on terrain levels 0-2 (the demo's recipe)."""
    root = tmp_path_factory.mktemp("learn") / "teacher"
    return easy_terrain_dataset(root, 48, 10.0, "test/teacher")


@pytest.fixture(scope="module")
def stage1(teacher_data: Path, tmp_path_factory) -> tuple[Path, dict[str, float]]:
    out = tmp_path_factory.mktemp("learn") / "stage1"
    final = train(TrainConfig(dataset=str(teacher_data), policy=MSTAConfig.from_preset("cpu"),
                              output_dir=str(out), steps=1000, eval_every=0, save_every=0,
                              progress=False))
    rows = (out / "metrics.csv").read_text().splitlines()
    header, last = rows[0].split(","), rows[-1].split(",")
    return final, {k: float(v) for k, v in zip(header, last, strict=True) if v}


def test_msta_cpu_preset_imitates_the_teacher(stage1) -> None:
    _, metrics = stage1
    assert metrics["val_loss_unmasked"] <= 0.3  # the mean action scores ~1.0


def student_state_loss(policy, root: Path, episodes: list[int]) -> float:
    """Mean unmasked loss of ``policy`` over every window of ``episodes`` at ``root``."""
    from msta.data.windows import WindowDataset

    ds = WindowDataset(root, policy.required_sensors, policy.config.history,
                       extra_columns=("action",), episodes=episodes)
    policy.eval()
    total = 0.0
    with torch.no_grad():
        for lo in range(0, len(ds), 512):
            idx = np.arange(lo, min(lo + 512, len(ds)))
            loss, _ = policy.loss(ds.get_batch(idx), mask_ratio=0.0)
            total += float(loss) * len(idx)
    return total / len(ds)


def test_a_stage2_round_fits_the_teacher_on_the_students_own_states(
        stage1, teacher_data: Path, tmp_path: Path) -> None:
    ckpt, _ = stage1
    data = tmp_path / "dataset"
    shutil.copytree(teacher_data, data)
    cfg = CorrectConfig(policy=str(ckpt), dataset=str(data), output_dir=str(tmp_path / "s2"),
                        rounds=1, episodes_per_round=24, num_envs=24, episode_length_s=6.0,
                        steps=400, warmup_steps=20, eval_every=0, save_every=0,
                        eval=RoundEvalConfig(enabled=False), progress=False,
                        env=EnvConfig(terrain=TerrainConfig(max_init_level=2)),
                        teacher=TeacherConfig())  # the teacher of teacher_data
    correct(cfg)
    before = load_policy(ckpt)
    after = load_policy(tmp_path / "s2" / "round_1")
    # held-out student states: the stage-1 student drives on other seeds, the teacher labels
    held = tmp_path / "held_out"
    shutil.copytree(teacher_data, held)
    from msta.data.windows import load_episode_table

    n_teacher = len(load_episode_table(held))
    episodes, _ = drive_and_label(replace(cfg, episodes_per_round=12, num_envs=12), before,
                                  r=7, revision="held-out")
    total = append_episodes(held, episodes)
    own = list(range(n_teacher, total))  # only the held-out student episodes
    loss_before = student_state_loss(before, held, own)
    loss_after = student_state_loss(after, held, own)
    # measured 0.398 -> 0.326 (2026-12-01); DAgger's point is exactly this drop
    assert loss_after < 0.9 * loss_before, (loss_before, loss_after)
