"""Tiny checkpoints for the eval tests: a gait-teacher dataset and random-weight MSTA students."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import torch

import msta.policies.teacher.gait  # noqa: F401  (registers "gait")
from msta.collect.record import CollectConfig, collect
from msta.collect.sim.env_config import EnvConfig
from msta.collect.sim.terrain import TerrainConfig
from msta.data.stats import load_stats
from msta.policies.factory import make_policy
from msta.policies.msta import MSTAConfig
from msta.policies.teacher.config import TeacherConfig


@pytest.fixture(scope="session")
def tiny_ckpt(tmp_path_factory) -> Path:
    """A tiny MSTA checkpoint (random weights; its actions vary with its inputs because the
    action statistics come from a walking teacher)."""
    base = tmp_path_factory.mktemp("eval_ckpt")
    root = base / "dataset"
    collect(CollectConfig(teacher=TeacherConfig(type="gait"), episodes=2, num_envs=2,
                          root=str(root), episode_length_s=0.5, progress=False,
                          env=EnvConfig(terrain=TerrainConfig(curriculum=False))))
    torch.manual_seed(0)  # the initial weights too: a session draws the same student
    policy = make_policy(MSTAConfig.from_preset("tiny"), load_stats(root))
    # Large random weights on top (seeded): the student's actions are large and still vary
    # with its inputs (test_report_warns_when_a_student_ignores_its_inputs needs both).
    gen = torch.Generator().manual_seed(0)
    with torch.no_grad():
        for p in policy.parameters():
            p.add_(0.5 * torch.randn(p.shape, generator=gen))
    return policy.save_pretrained(base / "msta_tiny")


@pytest.fixture(scope="session")
def two_ckpts(tiny_ckpt, tmp_path_factory) -> tuple[Path, Path]:
    """Two checkpoint directories (same weights) standing for two train mask settings."""
    base = tmp_path_factory.mktemp("eval_matrix")
    return tuple(shutil.copytree(tiny_ckpt, base / name) for name in ("a75_50", "a50_50"))
