"""Issue 15 (6, 7): a damaged dataset is refused by every msta entry point that trains on,
extends or publishes it: one line naming the file, and not one byte of the dataset changed.

The matrix: seven damages (the six of the audit plus a rewrite with finite but absurd values,
the audit's 5.9e36) x msta-train, msta-collect --resume, msta-correct, msta-hub
push-dataset and WindowDataset. lerobot's own loader notices only a truncated file (it reads
Parquet without page-checksum verification and knows nothing of meta/msta_checksums.json:
flipped bytes, NaN, absurd values and a lowered episode count load silently), so it gets
one test, for truncation.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from msta_test_helpers import running_hub  # registered by tests/conftest.py

from msta.data.errors import DatasetFormatError
from msta.data.integrity import Manifest
from msta.data.layout import LOCK_NAME, MANIFEST_PATH
from msta.data.windows import WindowDataset
from msta.data.writer import DatasetWriter

FILE = "data/chunk-000/file-001.parquet"  # the second of four data files
COL = "observation.joint_pos"
SECRET = "alice-secret-0001"


# ----- damages (each returns the path the error must name) ---------------------------------
def _rewrite(root: Path, fn) -> str:
    path = root / FILE
    pq.write_table(fn(pq.read_table(path)), path)
    return FILE


def _set_value(table: pa.Table, value: float) -> pa.Table:
    col = table.column(COL).combine_chunks()
    x = col.flatten().to_numpy().reshape(len(col), -1).copy()
    x[2, 1] = value
    arr = pa.FixedSizeListArray.from_arrays(pa.array(x.reshape(-1)), x.shape[1])
    return table.set_column(table.column_names.index(COL), table.schema.field(COL), arr)


def truncate(root: Path) -> str:
    data = (root / FILE).read_bytes()
    (root / FILE).write_bytes(data[: len(data) // 2])
    return FILE


def flip_bytes(root: Path) -> str:
    """32 random bytes in the middle of joint_pos's first data page (the audit's case)."""
    meta = pq.ParquetFile(root / FILE).metadata
    chunk = meta.row_group(0).column(meta.schema.to_arrow_schema().names.index(COL))
    start = chunk.data_page_offset + chunk.total_compressed_size // 2 - 16
    data = bytearray((root / FILE).read_bytes())
    data[start:start + 32] = np.random.default_rng(0).integers(0, 256, 32, np.uint8).tobytes()
    (root / FILE).write_bytes(bytes(data))
    return FILE


def absurd_values(root: Path) -> str:
    return _rewrite(root, lambda t: _set_value(t, 5.9e36))


def drop_column(root: Path) -> str:
    return _rewrite(root, lambda t: t.remove_column(t.column_names.index(COL)))


def nan(root: Path) -> str:
    return _rewrite(root, lambda t: _set_value(t, float("nan")))


def stale_info(root: Path) -> str:
    """Episode count lowered to the first two files: files 002-003 look uncommitted."""
    path = root / "meta/info.json"
    info = json.loads(path.read_text())
    info.update(total_episodes=4, total_frames=24, splits={"train": "0:4"})
    path.write_text(json.dumps(info, indent=4))
    return "meta/info.json"


def missing_file(root: Path) -> str:
    (root / FILE).unlink()
    return FILE


DAMAGES = {f.__name__: f for f in (truncate, flip_bytes, absurd_values, drop_column, nan,
                                    stale_info, missing_file)}


def snapshot(root: Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file() and p.name != LOCK_NAME}


# ----- fixtures ------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def template(tmp_path_factory, write_dataset) -> Path:
    root = tmp_path_factory.mktemp("corruption") / "ds"
    write_dataset(root, [6] * 8, flush_every_frames=12)  # 4 data files of 2 episodes
    assert len(list((root / "data/chunk-000").iterdir())) == 4
    return root


@pytest.fixture(params=list(DAMAGES))
def damaged(request, template, tmp_path) -> tuple[Path, str, dict[str, bytes]]:
    root = tmp_path / "ds"
    shutil.copytree(template, root)
    name = DAMAGES[request.param](root)
    return root, name, snapshot(root)


@pytest.fixture(scope="module")
def checkpoint(template, tmp_path_factory) -> Path:
    from msta.data.stats import load_stats
    from msta.policies.factory import make_policy
    from msta.policies.msta import MSTAConfig

    cfg = MSTAConfig.from_preset("tiny", input_sensors=("command", "joint_pos", "gravity"))
    path = tmp_path_factory.mktemp("ckpt") / "final"
    make_policy(cfg, load_stats(template)).save_pretrained(path)
    return path


@pytest.fixture(scope="module")
def hub_server(tmp_path_factory):
    with running_hub(tmp_path_factory.mktemp("hub"), f"alice:{SECRET}") as srv:
        yield srv


# ----- the matrix ----------------------------------------------------------------------------
def test_the_writer_records_every_file_and_lerobot_layout_is_unchanged(template):
    committed = Manifest.load(template).committed
    data = sorted(p.relative_to(template).as_posix() for p in template.glob("data/*/*"))
    assert set(data) <= set(committed.files) and committed.total_episodes == 8
    for rel, rec in committed.files.items():
        content = (template / rel).read_bytes()
        assert (rec.size, rec.sha256) == (len(content), hashlib.sha256(content).hexdigest())
    assert Manifest.load(template).pending is None
    assert pq.ParquetFile(template / FILE).metadata.num_row_groups == 2


def test_window_dataset_refuses(damaged):
    root, name, before = damaged
    with pytest.raises(DatasetFormatError, match=name.replace(".", r"\.")):
        WindowDataset(root, ["joint_pos", "command"], T=3)
    assert snapshot(root) == before


def test_msta_train_refuses(damaged, tmp_path):
    from msta.train.offline import main

    root, name, before = damaged
    out = tmp_path / "run"
    with pytest.raises(SystemExit) as err:
        main([f"--dataset={root}", f"--output_dir={out}", "--policy.preset=tiny",
              "--policy.input_sensors=[command,joint_pos]", "--steps=2", "--progress=false"])
    message = str(err.value)
    assert message.startswith("msta-train: error: ") and "\n" not in message
    assert name in message and snapshot(root) == before
    assert not out.exists()  # the dataset is checked before the run directory is made


def test_msta_collect_resume_refuses_and_deletes_nothing(damaged):
    from msta.collect.record import main

    root, name, before = damaged
    with pytest.raises(SystemExit) as err:
        main([f"--root={root}", "--resume=true", "--episodes=12", "--num_envs=2",
              "--progress=false"])
    message = str(err.value)
    assert message.startswith("msta-collect: error: ") and "\n" not in message
    assert name in message
    assert snapshot(root) == before  # stale_info: committed files 002-003 are still there


def test_msta_correct_refuses(damaged, checkpoint, tmp_path):
    from msta.train.online import main

    root, name, before = damaged
    out = tmp_path / "correct"
    with pytest.raises(SystemExit) as err:
        main([f"--policy.path={checkpoint}", f"--dataset={root}", f"--output_dir={out}",
              "--episodes_per_round=1", "--num_envs=1", "--steps=1", "--progress=false"])
    message = str(err.value)
    assert message.startswith("msta-correct: error: ") and "\n" not in message
    assert name in message
    assert snapshot(root) == before and not out.exists()


def test_msta_hub_push_dataset_refuses(damaged, hub_server, monkeypatch, capsys):
    from msta.data.hub_cli import main
    from msta.data.hub_ids import hub_api

    monkeypatch.setenv("HF_ENDPOINT", hub_server.url)
    monkeypatch.setenv("HF_TOKEN", SECRET)
    root, name, before = damaged
    assert main(["push-dataset", str(root), "alice/damaged"]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("msta-hub push-dataset: error: ") and name in err and "\n" not in err
    assert not hub_api().repo_exists("alice/damaged", repo_type="dataset")
    assert snapshot(root) == before


def test_push_dataset_waits_for_no_writer(template, tmp_path, hub_server, monkeypatch, capsys):
    from msta.data.hub_cli import main

    monkeypatch.setenv("HF_ENDPOINT", hub_server.url)
    monkeypatch.setenv("HF_TOKEN", SECRET)
    root = tmp_path / "ds"
    shutil.copytree(template, root)
    with DatasetWriter.open(root):
        assert main(["push-dataset", str(root), "alice/busy"]) == 1
    assert "a dataset writer (pid" in capsys.readouterr().err
    assert main(["push-dataset", str(root), "alice/busy"]) == 0


def test_lerobot_itself_notices_only_truncation(template, tmp_path):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    root = tmp_path / "ds"
    shutil.copytree(template, root)
    truncate(root)
    with pytest.raises(Exception, match="file-001.parquet|generating the dataset"):
        LeRobotDataset("local/test", root=root)


# ----- without the manifest: page checksums, no deletion on doubt, upgrade --------------------
def _legacy(template: Path, tmp_path: Path) -> Path:
    root = tmp_path / "legacy"
    shutil.copytree(template, root)
    (root / MANIFEST_PATH).unlink()
    return root


def test_page_checksums_catch_flipped_bytes_without_the_manifest(template, tmp_path):
    root = _legacy(template, tmp_path)
    flip_bytes(root)
    with pytest.raises(DatasetFormatError, match=r"file-001\.parquet: cannot read Parquet"):
        WindowDataset(root, ["joint_pos"], T=1)


def test_legacy_dataset_with_a_stale_info_json_is_refused_not_truncated(template, tmp_path):
    root = _legacy(template, tmp_path)
    stale_info(root)
    before = snapshot(root)
    with pytest.raises(DatasetFormatError, match=r"file-002\.parquet: beyond the 4 episodes"):
        DatasetWriter.open(root)
    assert snapshot(root) == before


def test_legacy_dataset_gets_a_manifest_when_opened(template, tmp_path, synth):
    root = _legacy(template, tmp_path)
    before = snapshot(root)
    with DatasetWriter.open(root):
        pass
    manifest = Manifest.load(root)
    assert manifest is not None and manifest.committed.total_episodes == 8
    derived = (MANIFEST_PATH, "meta/stats.json")  # stats are recomputed, as before manifests
    assert ({k: v for k, v in snapshot(root).items() if k not in derived}
            == {k: v for k, v in before.items() if k not in derived})
    absurd_values(root)
    with pytest.raises(DatasetFormatError, match=r"file-001\.parquet: .* recorded at commit"):
        DatasetWriter.open(root)
