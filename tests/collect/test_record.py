"""msta-collect: teacher rollouts -> a LeRobot v3.0 dataset, resumable after SIGKILL."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from msta.collect.record import CollectConfig, collect
from msta.collect.sim.env_config import EnvConfig
from msta.collect.sim.randomization import RandomizationConfig
from msta.collect.sim.terrain import TerrainConfig
from msta.data.windows import WindowDataset, load_episode_table
from msta.policies.teacher.config import TeacherConfig

SMALL_TERRAIN = TerrainConfig(types=("flat", "stairs_up"), num_levels=2, max_init_level=1,
                              border=2.0)


def small_cfg(root: Path, episodes: int, **kw) -> CollectConfig:
    return CollectConfig(teacher=TeacherConfig(type="zero"), episodes=episodes, num_envs=4,
                         root=str(root), episode_length_s=0.5, progress=False,
                         env=EnvConfig(nthread=1, terrain=SMALL_TERRAIN,
                                       randomization=RandomizationConfig(pool_size=2)), **kw)


def test_collect_writes_episodes_with_provenance_and_labels(tmp_path):
    root = collect(small_cfg(tmp_path / "ds", episodes=6))
    eps = load_episode_table(root)
    assert len(eps) == 6
    assert set(eps["provenance/terrain"]) <= {"flat", "stairs_up"}
    assert (eps["provenance/source"] == "teacher").all()
    assert (eps["provenance/policy"] == "zero").all()
    assert eps["provenance/policy_revision"].str.startswith("zero-").all()
    assert (eps["length"] == 25).all()   # 0.5 s at 50 Hz, nobody falls holding the pose
    ds = WindowDataset(root, ["joint_pos", "command", "last_action"], T=3,
                       extra_columns=("action", "executed_action", "next.done"))
    b = ds.get_batch(np.arange(len(ds)))
    np.testing.assert_array_equal(b["action"], b["executed_action"])
    assert b["next.done"].sum() == 6
    # a standing robot: calf angles near the default pose
    assert np.abs(b["joint_pos"][:, -1, 2] + 1.5).max() < 0.5


def test_action_noise_perturbs_what_runs_and_keeps_the_label_clean(tmp_path):
    """DART: the zero teacher's label stays 0, the executed action carries the noise, and
    the robot's joints leave the pose the clean teacher holds."""
    root = collect(small_cfg(tmp_path / "ds", episodes=4, action_noise=0.5))
    ds = WindowDataset(root, ["joint_pos"], T=1, extra_columns=("action", "executed_action"))
    b = ds.get_batch(np.arange(len(ds)))
    np.testing.assert_array_equal(b["action"], 0.0)
    assert abs(float(b["executed_action"].std()) - 0.5) < 0.05
    assert abs(float(b["executed_action"].mean())) < 0.05
    clean = WindowDataset(collect(small_cfg(tmp_path / "clean", episodes=4)), ["joint_pos"],
                          T=1).get_batch(np.arange(len(ds)))
    assert np.abs(b["joint_pos"] - clean["joint_pos"]).max() > 0.05
    with pytest.raises(ValueError, match="action_noise"):
        small_cfg(tmp_path / "bad", episodes=1, action_noise=-0.1)


def test_existing_dataset_requires_resume(tmp_path):
    collect(small_cfg(tmp_path / "ds", episodes=2))
    with pytest.raises(FileExistsError, match="--resume"):
        collect(small_cfg(tmp_path / "ds", episodes=4))
    collect(small_cfg(tmp_path / "ds", episodes=4, resume=True))
    assert len(load_episode_table(tmp_path / "ds")) == 4


def test_a_collect_with_nothing_to_do_releases_the_dataset(tmp_path):
    """The 'nothing to do' return closes its writer: the same process can extend the dataset
    (as make demo and bench-learn do with easy_terrain_dataset) instead of finding it locked."""
    collect(small_cfg(tmp_path / "ds", episodes=2))
    collect(small_cfg(tmp_path / "ds", episodes=2, resume=True))  # nothing to do
    collect(small_cfg(tmp_path / "ds", episodes=3, resume=True))
    assert len(load_episode_table(tmp_path / "ds")) == 3


def test_sigkill_mid_run_then_resume_reaches_the_count(tmp_path):
    root = tmp_path / "ds"
    args = [sys.executable, "-m", "msta.collect.record", "--teacher.type=zero", "--episodes=400",
            "--num_envs=4", f"--root={root}", "--episode_length_s=0.2", "--progress=false",
            "--flush_every_frames=20", "--env.nthread=1", "--env.terrain.types=[flat]",
            "--env.terrain.num_levels=1", "--env.terrain.max_init_level=0",
            "--env.terrain.border=2.0"]
    proc = subprocess.Popen(args, cwd=Path(__file__).resolve().parents[2],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    info = root / "meta" / "info.json"
    deadline = time.time() + 120
    while time.time() < deadline:
        if info.exists() and json.loads(info.read_text())["total_episodes"] >= 8:
            break
        assert proc.poll() is None, proc.stdout.read().decode()
        time.sleep(0.05)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    had = len(load_episode_table(root))
    assert 8 <= had < 400
    # the dataset loads as it is (lerobot's own loader is exercised in tests/msta_data)
    assert len(WindowDataset(root, ["joint_pos"], T=2)) == 10 * had
    cfg = small_cfg(root, episodes=had + 5, resume=True)
    cfg.env.terrain = TerrainConfig(types=("flat",), num_levels=1, max_init_level=0, border=2.0)
    cfg.episode_length_s = 0.2
    collect(cfg)
    eps = load_episode_table(root)
    assert len(eps) == had + 5
    assert list(eps["episode_index"]) == list(range(had + 5))
