"""A writer killed with SIGKILL leaves a dataset that loads; open() recovers and appends."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from lerobot.datasets.lerobot_dataset import LeRobotDataset

from msta.data import stats as S
from msta.data.integrity import Manifest
from msta.data.layout import MANIFEST_PATH
from msta.data.windows import WindowDataset, load_episode_table
from msta.data.writer import DatasetWriter

REPO = Path(__file__).resolve().parents[2]

# Writes 20-frame episodes forever, flushing every 60 frames; prints the committed episode
# count after each flush.
WRITER_SCRIPT = r"""
import sys
import numpy as np
from msta.data import features as F
from msta.data.writer import DatasetWriter

feats = F.build_features()
rng = np.random.default_rng(0)
w = DatasetWriter.create(sys.argv[1], "local/crash", flush_every_frames=60)
i = 0
while True:
    ep = {c: (np.arange(20) == 19) if feats[c]["dtype"] == "bool" else
          rng.standard_normal((20, feats[c]["shape"][0])).astype(np.float32)
          for c in F.input_columns(feats)}
    committed = w.info["total_episodes"]
    w.add_episode(ep, dict(terrain="discrete", terrain_level=i % 10, source="teacher",
                           round=0, policy="gait", policy_revision="", seed=i))
    if w.info["total_episodes"] != committed:
        print("committed", w.info["total_episodes"], flush=True)
    i += 1
"""


def test_sigkill_mid_run_keeps_flushed_episodes(tmp_path, synth):
    root = tmp_path / "ds"
    proc = subprocess.Popen([sys.executable, "-c", WRITER_SCRIPT, str(root)], cwd=REPO,
                            stdout=subprocess.PIPE, text=True)
    try:
        committed = 0
        for line in proc.stdout:
            committed = int(line.split()[1])
            if committed >= 12:
                break
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == -signal.SIGKILL and committed >= 12
    info = json.loads((root / "meta/info.json").read_text())
    assert info["total_episodes"] >= committed  # it may have committed more before the kill
    ds = LeRobotDataset("local/crash", root=root)
    assert ds.num_episodes == info["total_episodes"] and len(ds) == 20 * ds.num_episodes
    assert ds[len(ds) - 1]["frame_index"].item() == 19
    # Recover, append, and check that the result is consistent again.
    with DatasetWriter.open(root) as w:
        assert w.num_episodes == info["total_episodes"]
        w.add_episode(synth.episode(20, 0), synth.provenance(0))
    assert list((root).glob("**/*.tmp")) == []
    n = info["total_episodes"] + 1
    assert load_episode_table(root)["episode_index"].tolist() == list(range(n))
    assert len(WindowDataset(root, ["joint_pos"], T=3)) == 20 * n
    assert LeRobotDataset("local/crash", root=root).num_episodes == n


def test_uncommitted_files_are_ignored_then_moved_aside(tmp_path, write_dataset, synth):
    """Simulate a kill between writing a flush's files and committing info.json."""
    root = tmp_path / "ds"
    write_dataset(root, [5, 6], flush_every_frames=5)  # two flushes -> files 000 and 001
    committed = {n: (root / "meta" / n).read_bytes() for n in ("info.json", "stats.json")}
    before = Manifest.load(root).committed
    write_dataset(root, [7], seed0=5, append=True)  # file 002 ...
    for name, content in committed.items():  # ... but killed before the commit
        (root / "meta" / name).write_bytes(content)
    # the manifest a kill at that point leaves: the new generation pending, not committed
    (root / MANIFEST_PATH).write_bytes(Manifest(before, Manifest.load(root).committed).dumps())
    for sub in ("data", "meta/episodes"):
        (root / sub / "chunk-000" / "file-003.parquet.tmp").write_bytes(b"partial")
    (root / "meta/info.json.tmp").write_text("{")
    # Readers only trust info.json: the leftovers are invisible to them.
    assert LeRobotDataset("local/test", root=root).num_episodes == 2
    assert len(WindowDataset(root, ["command"], T=2)) == 11
    with DatasetWriter.open(root) as w:
        w.add_episode(synth.episode(4, 9), synth.provenance(9))
    names = sorted(p.name for p in (root / "data/chunk-000").iterdir())
    assert names == ["file-000.parquet", "file-001.parquet", "file-002.parquet"]
    assert not list(root.glob("**/*.tmp"))
    wd = WindowDataset(root, ["command"], T=2)
    assert len(wd) == 15
    assert S.load_stats(root)["action"]["count"].tolist() == [15]  # recomputed, not 22
    np.testing.assert_array_equal(wd.get_batch(np.array([11]))["command"][0, 1],
                                  synth.episode(4, 9)["observation.command"][0])


class _Killed(BaseException):
    """A kill at one write of the commit (BaseException: nothing catches it on the way)."""


@pytest.mark.parametrize("kill_at", ["manifest", "meta/msta.json", "meta/tasks.parquet",
                                     "meta/info.json"])
def test_a_kill_inside_a_commit_that_replaces_msta_json_and_tasks_reopens(tmp_path, synth,
                                                                        monkeypatch, kill_at):
    """A flush that changes meta/msta.json (a new recording block) and meta/tasks.parquet (a
    new task) killed at each of the commit's writes: the dataset reopens (those files match
    the committed generation or the pending one) and holds the committed episodes or all."""
    from msta.data import writer as W
    from msta.data.msta_json import add_recording

    root = tmp_path / "ds"
    with DatasetWriter.create(root, "local/test") as w:
        w.add_episode(synth.episode(5, 0), synth.provenance(0))
    real = W._atomic_write

    def write(path, fill):
        if path.as_posix().endswith(MANIFEST_PATH if kill_at == "manifest" else kill_at):
            raise _Killed
        return real(path, fill)

    w = DatasetWriter.open(root)
    assert add_recording(w.msta_meta, 1, {"teacher": "gait"})
    w.meta_changed()
    w.add_episode(synth.episode(6, 1), {**synth.provenance(1), "terrain": "stairs_up"})
    monkeypatch.setattr(W, "_atomic_write", write)
    with pytest.raises(_Killed):
        w.flush()
    monkeypatch.setattr(W, "_atomic_write", real)
    import os

    os.close(w._lock_fd)  # the killed process's lock goes with it
    w._lock_fd = None
    with DatasetWriter.open(root) as again:
        assert again.num_episodes == 1  # the commit point was not reached
        again.add_episode(synth.episode(4, 2), synth.provenance(2))
    assert len(load_episode_table(root)) == 2
