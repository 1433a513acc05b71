"""Issue 41 (10, 12): datasets whose manifest agrees with what is on disk (edited together,
or pushed to a hub with plain huggingface_hub) but whose content is hostile or absurd.

* a manifest entry naming a path outside the dataset (``/dev/zero``, ``../``), a symbolic
  link leading out of it, or a device or FIFO where a file should be: refused in one line
  naming the entry, nothing read (``/dev/zero`` used to hang msta-train, msta-collect
  --resume and msta-hub push-dataset at 100 % CPU);
* absurd ``meta/info.json`` values, an empty episode, a lowered episode count: one line
  naming the file (they were tracebacks, an error naming no file, silent training on a
  subset);
* a statistic with std 0: the normalizer takes it as 1 (the loss was 1e12).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from msta.data.errors import DatasetFormatError, DatasetIntegrityError
from msta.data.integrity import Generation, Manifest, digest_bytes, digest_file, verify_dataset
from msta.data.layout import LOCK_NAME, MANIFEST_PATH
from msta.data.windows import WindowDataset
from msta.data.writer import DatasetWriter

REPO = Path(__file__).resolve().parents[2]
TRAIN = ["--policy.preset=tiny", "--policy.input_sensors=[command,joint_pos]",
         "--progress=false", "--eval_every=0", "--steps=2"]


def consistent(root: Path, extra: dict[str, tuple[int, str]] | None = None) -> None:
    """Rewrite the manifest to agree with the files and counts on disk (what anyone can
    push), adding ``extra`` entries (path -> size, sha256) as given."""
    info = json.loads((root / "meta/info.json").read_text())
    files = {rel: digest_file(root / rel, use_cache=False)
             for rel in Manifest.load(root).committed.files if (root / rel).is_file()}
    for rel, (size, sha) in (extra or {}).items():
        files[rel] = type(files["meta/info.json"])(size, sha)
    gen = Generation(info["total_episodes"], info["total_frames"], files)
    (root / MANIFEST_PATH).write_bytes(Manifest(gen).dumps())


def snapshot(root: Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file() and p.name != LOCK_NAME}


def edit_info(root: Path, **values) -> None:
    path = root / "meta/info.json"
    path.write_text(json.dumps({**json.loads(path.read_text()), **values}, indent=4))


def train(root: Path, out: Path, *extra: str) -> str:
    """msta-train in this process; returns its one-line error."""
    from msta.train.offline import main

    with pytest.raises(SystemExit) as err:
        main([f"--dataset={root}", f"--output_dir={out}", *TRAIN, *extra])
    message = str(err.value)
    assert message.startswith("msta-train: error: ") and "\n" not in message, message
    return message


@pytest.fixture(scope="module")
def template(tmp_path_factory, write_dataset) -> Path:
    root = tmp_path_factory.mktemp("hostile") / "ds"
    write_dataset(root, [6] * 8, flush_every_frames=12)  # 4 data files of 2 episodes
    return root


@pytest.fixture
def ds(template, tmp_path) -> Path:
    root = tmp_path / "ds"
    shutil.copytree(template, root)
    return root


# ----- item 10: the manifest names only regular files inside the dataset -------------------
@pytest.mark.timeout(60)  # /dev/zero was read forever
@pytest.mark.parametrize("entry", ["/dev/zero", "../outside.txt",
                                   "data/chunk-000/../../../outside.txt", "data\\..\\x"])
def test_manifest_entries_outside_the_dataset_are_refused(ds, entry):
    outside = ds.parent / "outside.txt"
    outside.write_text("a file next to the dataset")
    rec = digest_file(outside) if "outside" in entry else digest_bytes(b"")  # /dev/zero: 0 bytes
    consistent(ds, {entry: (rec.size, rec.sha256)})  # right size and hash: reading passes
    with pytest.raises(DatasetIntegrityError, match=re.escape(f"entry {entry!r}")):
        verify_dataset(ds)


@pytest.mark.parametrize("cli", ["msta-train", "msta-collect", "msta-hub push-dataset"])
def test_dev_zero_in_the_manifest_is_one_line_from_every_command(ds, cli, tmp_path):
    consistent(ds, {"/dev/zero": (0, "0" * 64)})
    before = snapshot(ds)
    args = {"msta-train": ["msta.train.offline", f"--dataset={ds}",
                           f"--output_dir={tmp_path / 'run'}", *TRAIN],
            "msta-collect": ["msta.collect.record", f"--root={ds}", "--resume=true",
                             "--episodes=12", "--num_envs=2", "--progress=false"],
            "msta-hub push-dataset": ["msta.data.hub_cli", "push-dataset", str(ds), "a/b"]}[cli]
    env = {**os.environ, "HF_ENDPOINT": "http://127.0.0.1:9", "HF_TOKEN": "unused"}
    proc = subprocess.run([sys.executable, "-m", *args], cwd=REPO, env=env, timeout=120,
                          capture_output=True, text=True, check=False)
    last = proc.stderr.strip().splitlines()[-1]
    assert proc.returncode != 0 and last.startswith(f"{cli}: error: "), proc.stderr
    assert "'/dev/zero' is not a relative path inside the dataset" in last
    assert snapshot(ds) == before


@pytest.mark.timeout(60)  # a FIFO blocked the reader
def test_symlinks_out_of_the_dataset_and_fifos_are_refused(ds):
    rel = "data/chunk-000/file-001.parquet"
    outside = ds.parent / "elsewhere.parquet"
    shutil.move(ds / rel, outside)
    (ds / rel).symlink_to(outside)  # the same bytes, so size and hash match
    with pytest.raises(DatasetIntegrityError, match="symbolic link leading outside"):
        verify_dataset(ds)
    (ds / "store").mkdir()  # a link inside the dataset is fine
    (ds / rel).unlink()
    shutil.move(outside, ds / "store/file-001.parquet")
    (ds / rel).symlink_to(ds / "store/file-001.parquet")
    verify_dataset(ds)
    (ds / "meta/tasks.parquet").unlink()
    os.mkfifo(ds / "meta/tasks.parquet")
    consistent(ds, {"meta/tasks.parquet": (0, "0" * 64)})
    with pytest.raises(DatasetIntegrityError, match=r"tasks\.parquet: not a regular file"):
        verify_dataset(ds)


# ----- item 12: consistent but absurd -------------------------------------------------------
@pytest.mark.parametrize("values, says", [
    ({"total_episodes": 1e12}, "total_episodes must be an integer >= 0, got 1000000000000.0"),
    ({"total_episodes": 10**12, "total_frames": 10**12},
     "info.json: total_episodes 1000000000000, but meta/episodes holds 8 of them"),
    ({"chunks_size": 0}, "chunks_size must be an integer >= 1, got 0"),
    ({"total_frames": -1}, "total_frames must be an integer >= 0"),
])
def test_absurd_info_json_values_are_one_line_errors(ds, tmp_path, values, says):
    edit_info(ds, **values)
    consistent(ds)
    message = train(ds, tmp_path / "run")
    assert says in message and f"{ds}/meta/info.json: " in message


def test_chunks_size_0_stops_msta_collect_resume_in_one_line(ds):
    from msta.collect.record import main

    edit_info(ds, chunks_size=0)
    consistent(ds)
    before = snapshot(ds)
    with pytest.raises(SystemExit) as err:
        main([f"--root={ds}", "--resume=true", "--episodes=12", "--num_envs=2",
              "--progress=false"])
    assert str(err.value) == (f"msta-collect: error: {ds}/meta/info.json: chunks_size must be "
                              "an integer >= 1, got 0")
    assert snapshot(ds) == before


def test_an_empty_episode_is_refused_naming_its_file(ds, tmp_path):
    path = ds / "meta/episodes/chunk-000/file-003.parquet"
    table = pq.read_table(path)
    rows = table.to_pydict()
    rows["length"][1], rows["dataset_to_index"][1] = 0, rows["dataset_from_index"][1]
    pq.write_table(pa.Table.from_pydict(rows, schema=table.schema), path)
    edit_info(ds, total_frames=42)
    consistent(ds)
    assert f"{path}: episode 7 has length 0" in train(ds, tmp_path / "run")
    with pytest.raises(DatasetFormatError, match="file-003.parquet: episode 7 has length 0"):
        WindowDataset(ds, ["joint_pos"], T=2)


@pytest.mark.parametrize("manifest", ["rewritten", "info_hash_only", "removed"])
def test_a_lowered_episode_count_is_refused_not_trained_on(ds, tmp_path, manifest):
    """info.json lowered from 8 to 4 episodes (files 002-003 beyond it): msta-train used to
    train on the first 4, and a writer would have written its next file over file-002."""
    edit_info(ds, total_episodes=4, total_frames=24, splits={"train": "0:4"})
    if manifest == "rewritten":
        consistent(ds)
    elif manifest == "info_hash_only":
        m = Manifest.load(ds)
        m.committed.files["meta/info.json"] = digest_file(ds / "meta/info.json")
        (ds / MANIFEST_PATH).write_bytes(m.dumps())
    else:
        (ds / MANIFEST_PATH).unlink()
    before = snapshot(ds)
    says = ("meta/info.json: 4 episodes and 24 frames, the last commit" if manifest ==
            "info_hash_only" else "file-002.parquet: beyond the 4 episodes of meta/info.json")
    assert says in train(ds, tmp_path / "run")
    with pytest.raises(DatasetFormatError, match=re.escape(says)):
        DatasetWriter.open(ds)
    assert snapshot(ds) == before


def test_a_zero_std_statistic_trains_with_a_finite_loss(ds, tmp_path, capsys):
    """std 0 in meta/stats.json (a constant channel, or statistics that say so) while the
    data varies: the action targets were z-scored with std 1e-6 (loss ~1e12)."""
    from msta.data.stats import load_stats
    from msta.policies.factory import make_policy
    from msta.policies.msta import MSTAConfig
    from msta.train.offline import main

    stats = json.loads((ds / "meta/stats.json").read_text())
    for col in ("action", "observation.joint_pos"):
        stats[col]["std"] = [0.0] * len(stats[col]["std"])
    (ds / "meta/stats.json").write_text(json.dumps(stats))
    consistent(ds)
    cfg = MSTAConfig.from_preset("tiny", input_sensors=("command", "joint_pos"))
    processor = make_policy(cfg, load_stats(ds)).processor
    actions = WindowDataset(ds, ["joint_pos"], T=1).get_batch(np.arange(48))["action"]
    import torch

    z = processor.normalize_target(torch.as_tensor(actions))
    assert float(z.abs().max()) < 100  # raw offsets from the mean, not 1e6 times them
    main([f"--dataset={ds}", f"--output_dir={tmp_path / 'run'}", *TRAIN[:-1], "--steps=10"])
    loss = float(re.search(r"train loss ([0-9.e+-]+)", capsys.readouterr().out).group(1))
    assert loss < 1e3


@pytest.mark.parametrize("link", ["data/chunk-001", ".msta-quarantine", "meta/episodes"])
def test_a_writer_touches_nothing_through_a_symbolic_link(ds, tmp_path, link):
    """A chunk folder, the quarantine or the episodes folder linked to an outside folder:
    reopening for append (msta-collect --resume, stage 2) refuses in one line, and neither
    the outside folder nor the dataset changes."""
    from msta.data.writer import DatasetWriter

    outside = tmp_path / "outside"
    if (ds / link).exists():
        shutil.move(ds / link, outside)
    else:
        outside.mkdir()
    (outside / "mine.txt").write_text("a user's file")
    (ds / link).symlink_to(outside, target_is_directory=True)
    before, theirs = snapshot(ds), sorted(p.name for p in outside.iterdir())
    with pytest.raises(DatasetIntegrityError, match=rf"holds symbolic links \({link}\).*"
                       "replace them with the files themselves"):
        DatasetWriter.open(ds)
    assert snapshot(ds) == before
    assert sorted(p.name for p in outside.iterdir()) == theirs
