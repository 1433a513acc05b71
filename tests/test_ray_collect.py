"""msta-collect on Ray workers (a real local Ray of 2 CPUs): the dataset does not depend on the
worker count, a worker killed mid-rollout is replaced without losing or doubling an episode,
and a committer killed mid-run leaves a dataset that opens and resumes to the same episodes."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import ray

from msta.collect import ray_pool
from msta.collect.ray_record import slot_tiles
from msta.collect.record import CollectConfig, collect
from msta.collect.sim.env_config import EnvConfig
from msta.collect.sim.randomization import RandomizationConfig
from msta.collect.sim.terrain import TerrainConfig
from msta.data.windows import load_episode_table
from msta.data.writer import DatasetWriter

REPO = Path(__file__).resolve().parents[1]
TERRAIN = TerrainConfig(types=("flat", "stairs_up"), num_levels=2, max_init_level=1, border=2.0)


def tiny(root: Path, workers: int, episodes: int = 6, num_envs: int = 4, **kw) -> CollectConfig:
    """6 episodes of 0.5 s by the shipped PPO teacher, blocks of 3 (num_envs 4 -> 2 blocks)."""
    return CollectConfig(episodes=episodes, num_envs=num_envs, root=str(root),
                         episode_length_s=0.5,
                         progress=False, workers=workers, seed=3,
                         env=EnvConfig(nthread=1, terrain=TERRAIN,
                                       randomization=RandomizationConfig(pool_size=2)), **kw)


def dataset_bytes(root: Path) -> dict[str, bytes]:
    """Every data and per-episode metadata file of a dataset, by relative path."""
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*.parquet"))}


def frames(root: Path) -> list[dict[str, np.ndarray]]:
    """Every episode's frames, in episode order (column -> array)."""
    import pandas as pd

    data = pd.concat([pd.read_parquet(p) for p in sorted((root / "data").rglob("*.parquet"))])
    return [{c: np.stack(g[c].to_numpy()) for c in g.columns if c != "index"}
            for _, g in data.groupby("episode_index", sort=True)]


@pytest.fixture(scope="module")
def one_worker(local_ray, tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("one") / "ds"
    collect(tiny(root, workers=1))
    return root


def test_one_and_two_workers_record_byte_identical_episodes(one_worker, tmp_path):
    two = collect(tiny(tmp_path / "two", workers=2))
    assert ray_pool.shared_pool(2).workers == 2
    eps = load_episode_table(two)
    assert len(eps) == 6 and (eps["provenance/seed"] == 3).all()
    assert dataset_bytes(two) == dataset_bytes(one_worker) and len(dataset_bytes(two)) >= 2
    # every slot has its own tile and streams: the episodes are not copies of each other
    f = frames(two)
    assert len({ep["observation.joint_pos"].tobytes() for ep in f}) == 6
    types, levels = slot_tiles(EnvConfig(seed=3, terrain=TERRAIN), np.arange(6))
    assert eps["provenance/terrain"].tolist() == [TERRAIN.types[t] for t in types]
    assert eps["provenance/terrain_level"].tolist() == levels.tolist()


def test_a_worker_killed_mid_rollout_is_replaced_and_its_block_redone(one_worker, tmp_path,
                                                                        monkeypatch):
    flag = tmp_path / "exited"
    monkeypatch.setenv(ray_pool.EXIT_HOOK, f"1:{flag}")
    ray_pool.close_shared()  # new workers carry the hook
    try:
        root = collect(tiny(tmp_path / "ds", workers=2))
        pool = ray_pool.shared_pool(2)
        assert flag.exists() and pool.replaced == 1  # block 1's worker died once, mid-rollout
    finally:
        ray_pool.close_shared()
    assert dataset_bytes(root) == dataset_bytes(one_worker)


def test_a_block_that_keeps_killing_workers_ends_the_run_in_one_line(local_ray, tmp_path):
    class Dies:
        def setup(self):
            return None

        def run(self, state, block):
            import os
            os._exit(3)

    with ray_pool.RayPool(1) as pool, pytest.raises(RuntimeError, match="block 0 lost 3"):
        pool.map(Dies(), [0], lambda i, r: None)


def test_bad_worker_options_are_one_line_errors(tmp_path):
    with pytest.raises(ValueError, match="workers"):
        tiny(tmp_path, workers=-1)
    with pytest.raises(ValueError, match="needs --workers"):
        tiny(tmp_path, workers=0, ray_address="auto")
    with pytest.raises(ValueError, match="no Ray cluster answers there"):
        ray_pool.check_reachable("127.0.0.1:1")


#: The killed run: 24 episodes in 12 blocks of 2 on 2 workers of the test's Ray, every
#: episode committed on its own (flush every 25 frames).
KILLED = {"episodes": 24, "num_envs": 2, "flush_every_frames": 25}
COMMITTER = r"""
import sys
sys.path.insert(0, sys.argv[3])
from test_ray_collect import KILLED, tiny
from msta.collect.record import collect
collect(tiny(__import__("pathlib").Path(sys.argv[1]), workers=2, ray_address=sys.argv[2],
             **KILLED))
"""


def test_the_committer_killed_mid_run_leaves_a_dataset_that_resumes_to_the_same_episodes(
        local_ray, tmp_path):
    ray_pool.close_shared()  # the subprocess's workers need the 2 CPUs
    root, address = tmp_path / "ds", ray.get_runtime_context().gcs_address
    proc = subprocess.Popen([sys.executable, "-c", COMMITTER, str(root), address,
                             str(REPO / "tests")], cwd=REPO)
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None:
            info = root / "meta" / "info.json"
            if info.is_file() and json.loads(info.read_text())["total_episodes"] >= 4:
                break
            time.sleep(0.01)
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == -signal.SIGKILL
    with DatasetWriter.open(root) as w:  # verifies every committed file
        have = w.num_episodes
    assert 4 <= have < 24
    collect(tiny(root, workers=2, resume=True, **KILLED))
    whole = collect(tiny(tmp_path / "whole", workers=2, **KILLED))
    got, want = frames(root), frames(whole)
    assert len(got) == len(want) == 24
    for a, b in zip(got, want, strict=True):
        for c in a:
            np.testing.assert_array_equal(a[c], b[c], err_msg=c)


def test_a_ray_run_prints_its_start_up_and_the_one_process_progress(tmp_path):
    """The command as a user runs it: the workers' start-up measured in one line, the same
    episodes bar as one process, and no line about Ray's token authentication."""
    proc = subprocess.run(
        [sys.executable, "-m", "msta.collect.record", "--teacher.type=zero", "--num_envs=2",
         "--episodes=4", "--episode_length_s=0.4", "--env.nthread=1",
         "--env.terrain.types=[flat]", "--env.terrain.num_levels=1", "--workers=2",
         f"--root={tmp_path / 'ds'}"], cwd=REPO, capture_output=True, text=True, timeout=300,
        check=False)
    assert proc.returncode == 0, proc.stderr[-3000:]
    err = proc.stderr.replace("\r", "\n")
    assert any(line.startswith("Ray: 2 workers ready in ") and
               line.endswith(" s on a local Ray started for this run")
               for line in err.splitlines()), err[-2000:]
    assert "episodes: 100%" in err and "4/4" in err
    assert "Token authentication" not in err
