"""msta-correct's rollouts on Ray workers (a real local Ray of 2 CPUs): a stage-2 round with 2
workers appends byte-identical episodes to those with 1, with the student driving at two mask
ratios and the teacher executing half of the steps (DAgger), and every frame of the round's
env steps kept (keep_unfinished)."""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import pytest

from msta.collect.record import CollectConfig, collect
from msta.collect.sim.env_config import EnvConfig
from msta.collect.sim.randomization import RandomizationConfig
from msta.collect.sim.terrain import TerrainConfig
from msta.data.stats import load_stats
from msta.data.windows import load_episode_table
from msta.policies.checkpoint import PolicyPath
from msta.policies.factory import make_policy
from msta.policies.msta import MSTAConfig
from msta.policies.teacher.config import TeacherConfig
from msta.train.correct_config import CorrectConfig, RoundEvalConfig
from msta.train.stage2 import correct

TERRAIN = TerrainConfig(types=("flat", "stairs_up"), num_levels=2, max_init_level=1, border=2.0)
ENV = EnvConfig(nthread=1, terrain=TERRAIN, randomization=RandomizationConfig(pool_size=2))


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> tuple[Path, Path]:
    """(teacher dataset of 4 gait episodes, untrained tiny student)."""
    d = tmp_path_factory.mktemp("stage2")
    root = collect(CollectConfig(teacher=TeacherConfig(type="gait"), episodes=4, num_envs=4,
                                 root=str(d / "ds"), episode_length_s=0.3, progress=False,
                                 env=ENV))
    policy = make_policy(MSTAConfig.from_preset("tiny", history=5), load_stats(root))
    return root, policy.save_pretrained(d / "student")


def one_round(base, out: Path, workers: int) -> Path:
    """One round: 4 episodes of 0.3 s in blocks of 2, retrained 2 steps; returns the dataset."""
    root = out / "ds"
    shutil.copytree(base[0], root)
    correct(CorrectConfig(
        policy=PolicyPath(str(base[1])), dataset=str(root), output_dir=str(out / "run"),
        rounds=1, episodes_per_round=4, num_envs=2, episode_length_s=0.3, env=ENV,
        teacher=TeacherConfig(type="gait"), steps=2, batch_size=8, warmup_steps=1,
        progress=False, device="cpu", eval=RoundEvalConfig(enabled=False), beta=0.5,
        rollout_mask_ratios=(0.0, 0.5), workers=workers))
    return root


def data_hashes(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*.parquet"))}


def test_a_round_on_two_workers_appends_the_episodes_of_one(local_ray, base, tmp_path):
    one = one_round(base, tmp_path / "one", workers=1)
    two = one_round(base, tmp_path / "two", workers=2)
    assert data_hashes(two) == data_hashes(one)
    assert len(data_hashes(two)) > len(data_hashes(base[0]))  # the round added files
    eps = load_episode_table(two)
    new = eps.iloc[4:]
    assert (new["provenance/source"] == "student").all() and (new["provenance/round"] == 1).all()
    # keep_unfinished: 2 blocks x 2 slots, each slot's 15 control steps all kept
    assert int(new["length"].sum()) == 4 * 15 and len(new) >= 4
