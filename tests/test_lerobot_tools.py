"""LeRobot's own dataset tools on msta datasets: lerobot-edit-dataset delete_episodes (in
place), split and merge, then msta-collect --resume appends and msta-train trains; the
dataset summary (``--operation.type info``) and lerobot-dataset-viz (with the ``viz`` extra)
read them."""

from __future__ import annotations

import csv
import json
import math
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from msta.collect.record import main as msta_collect
from msta.data import layout as L
from msta.data.integrity import verify_dataset
from msta.data.lerobot_edits import UNKNOWN
from msta.data.windows import load_episode_table
from msta.train.offline import main as msta_train

BIN = Path(sys.executable).parent
RECORD = ["--teacher.type=zero", "--num_envs=2", "--episode_length_s=0.4", "--progress=false",
          "--env.nthread=1", "--env.terrain.types=[flat]", "--env.terrain.num_levels=1",
          "--env.terrain.border=2.0", "--env.randomization.pool_size=2"]
TRAIN = ["--policy.preset=tiny", "--policy.input_sensors=[command,joint_pos,gravity]",
         "--policy.history=5", "--batch_size=8", "--warmup_steps=1", "--steps=2",
         "--eval_every=0", "--save_every=0", "--val_samples=8", "--progress=false",
         "--device=cpu"]
KNOWN = {"provenance/terrain": "flat", "provenance/source": "teacher", "provenance/round": 0,
         "provenance/policy": "zero", "provenance/terrain_level": 0}


def _env(tmp: Path) -> dict[str, str]:
    return {**os.environ, "HF_HUB_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1",
            "HF_HOME": str(tmp / "hf"), "HF_LEROBOT_HOME": str(tmp / "lerobot")}


def _lerobot(tool: str, tmp: Path, *args: str) -> str:
    """Run one of LeRobot's console scripts; its stdout."""
    proc = subprocess.run([str(BIN / tool), *args], env=_env(tmp), capture_output=True,
                          text=True, timeout=300, check=False)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
    return proc.stdout


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> Path:
    """6 episodes of the zero teacher, recorded by msta-collect (read-only: copy it)."""
    root = tmp_path_factory.mktemp("recorded") / "ds"
    msta_collect([*RECORD, f"--root={root}", "--episodes=6"])
    return root


def _copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst, ignore=shutil.ignore_patterns(L.LOCK_NAME))
    return dst


def _resume_and_train(root: Path, out: Path) -> pd.DataFrame:
    """msta-collect --resume appends 2 episodes, the dataset verifies against its new
    manifest and LeRobot loads every frame, msta-train trains 2 steps; the episode table."""
    from lerobot.datasets import LeRobotDataset

    before = json.loads((root / L.INFO_PATH).read_text())["total_episodes"]
    msta_collect([*RECORD, f"--root={root}", f"--episodes={before + 2}", "--resume=true"])
    verify_dataset(root)  # the manifest the append recorded matches every file
    info = json.loads((root / L.INFO_PATH).read_text())
    assert info["total_episodes"] == before + 2
    lerobot = LeRobotDataset("local/edited", root=root)
    assert (lerobot.num_episodes, len(lerobot)) == (before + 2, info["total_frames"])
    assert int(lerobot[len(lerobot) - 1]["episode_index"]) == before + 1
    meta = json.loads((root / L.MSTA_META_PATH).read_text())
    assert meta["msta_schema_version"] == 2 and "joint_pos" in meta["sensors"]
    assert (root / L.CARD_NAME).is_file()
    msta_train([f"--dataset={root}", f"--output_dir={out}", *TRAIN])
    with open(out / "metrics.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert rows[-1]["step"] == "2" and math.isfinite(float(rows[-1]["loss"]))
    table = load_episode_table(root)
    appended = table.tail(2)
    for col, want in KNOWN.items():  # the new episodes carry their full provenance
        assert (appended[col] == want).all(), col
    return table


def _unknown(rows: pd.DataFrame) -> None:
    """Provenance LeRobot dropped: terrain from the task text, the rest unknown."""
    assert (rows["provenance/terrain"] == "flat").all()
    for col in ("provenance/source", "provenance/policy", "provenance/policy_revision"):
        assert (rows[col] == UNKNOWN).all(), col
    for col in ("provenance/terrain_level", "provenance/round", "provenance/seed"):
        assert (rows[col] == -1).all(), col


def test_in_place_delete_then_resume_and_train(recorded, tmp_path):
    root = _copy(recorded, tmp_path / "ds")
    frames = json.loads((root / L.INFO_PATH).read_text())["total_frames"]
    lengths = load_episode_table(root)["length"].tolist()
    _lerobot("lerobot-edit-dataset", tmp_path, "--repo_id=local/ds", f"--root={root}",
             f"--new_root={root}", "--operation.type=delete_episodes",
             "--operation.episode_indices=[1, 3]")
    assert (tmp_path / "ds_old" / L.MSTA_META_PATH).is_file()  # LeRobot's backup
    for gone in (L.MSTA_META_PATH, L.MANIFEST_PATH, L.CARD_NAME):  # what LeRobot drops
        assert not (root / gone).exists(), gone
    table = _resume_and_train(root, tmp_path / "train")
    kept = table.head(4)
    assert kept["length"].tolist() == [lengths[i] for i in (0, 2, 4, 5)]
    assert table["length"].head(4).sum() == frames - lengths[1] - lengths[3]
    _unknown(kept)


def test_split_and_merge_then_resume_and_train(recorded, tmp_path):
    from lerobot.scripts.lerobot_edit_dataset import (
        EditDatasetConfig,
        MergeConfig,
        SplitConfig,
        handle_merge,
        handle_split,
    )

    src = _copy(recorded, tmp_path / "src")
    handle_split(EditDatasetConfig(SplitConfig(splits={"train": [0, 1, 2, 3], "val": [4, 5]}),
                                   repo_id="local/src", root=str(src),
                                   new_root=str(tmp_path / "split")))
    train = tmp_path / "split" / "train"
    _unknown(_resume_and_train(train, tmp_path / "train_split").head(4))
    # a merge keeps the provenance columns, empty for a source without them (the val split)
    merged = tmp_path / "merged"
    handle_merge(EditDatasetConfig(
        MergeConfig(repo_ids=["local/src", "local/val"],
                    roots=[str(src), str(tmp_path / "split" / "val")]),
        new_repo_id="local/merged", new_root=str(merged)))
    table = _resume_and_train(merged, tmp_path / "train_merged")
    original = load_episode_table(src)
    cols = [c for c in original.columns if c.startswith("provenance/")]
    pd.testing.assert_frame_equal(table.head(6)[cols].reset_index(drop=True), original[cols])
    _unknown(table.iloc[6:8])


def test_a_lerobot_rewritten_dataset_that_is_not_msta_is_refused(recorded, tmp_path):
    """Features that no msta schema has: one line, nothing written."""
    from msta.data.errors import DatasetFormatError
    from msta.data.writer import DatasetWriter

    root = _copy(recorded, tmp_path / "ds")
    for rel in (L.MSTA_META_PATH, L.MANIFEST_PATH):
        (root / rel).unlink()
    info = json.loads((root / L.INFO_PATH).read_text())
    del info["features"]["observation.state"]  # a derived column without its partner
    (root / L.INFO_PATH).write_text(json.dumps(info))
    before = sorted(p.relative_to(root) for p in root.rglob("*") if p.name != L.LOCK_NAME)
    with pytest.raises(DatasetFormatError, match=r"not an msta dataset, nothing was changed"):
        DatasetWriter.open(root)
    after = sorted(p.relative_to(root) for p in root.rglob("*") if p.name != L.LOCK_NAME)
    assert after == before


def test_lerobot_dataset_info_reads_an_msta_dataset(recorded, capsys):
    """lerobot-edit-dataset --operation.type=info (the CLI itself runs in the delete test)."""
    from lerobot.scripts.lerobot_edit_dataset import EditDatasetConfig, InfoConfig, handle_info

    handle_info(EditDatasetConfig(InfoConfig(show_features=True), repo_id="local/ds",
                                  root=str(recorded)))
    out = capsys.readouterr().out
    info = json.loads((recorded / L.INFO_PATH).read_text())
    assert f"Total episode: {info['total_episodes']}" in out
    assert f"({info['total_frames']})" in out and '"observation.state"' in out


def test_lerobot_dataset_viz_saves_an_episode(recorded, tmp_path):
    """LeRobot's viz extra (rerun-sdk) is part of msta's dev extra, so this always runs."""
    from rerun.experimental import RrdReader

    _lerobot("lerobot-dataset-viz", tmp_path, "--repo-id=local/ds", f"--root={recorded}",
             "--episode-index=1", "--save=1", f"--output-dir={tmp_path / 'rrd'}",
             "--num-workers=0")
    rrd = tmp_path / "rrd" / "local_ds_episode_1.rrd"
    length = int(load_episode_table(recorded)["length"][1])
    summary = RrdReader(str(rrd)).store().summary()  # one row per frame of the episode
    rows: dict[str, int] = {}  # an entity's rows may come in several chunks (rerun batches by time)
    for line in summary.splitlines():
        entity, _, rest = line.partition(" rows=")
        if rest:
            rows[entity] = rows.get(entity, 0) + int(rest.split()[0])
    for entity in ("action", "state", "next.reward", "next.done"):
        assert rows.get(f"/{entity}") == length, summary


def _rewritten(recorded: Path, dst: Path, edit) -> tuple[Path, Path]:
    """A copy of ``recorded`` as LeRobot's tools leave it (no meta/msta.json, no manifest)
    whose first episode file's table went through ``edit(table) -> table``: (root, file)."""
    import pyarrow.parquet as pq

    root = _copy(recorded, dst)
    for rel in (L.MSTA_META_PATH, L.MANIFEST_PATH):
        (root / rel).unlink()
    path = next((root / L.EPISODES_DIR).rglob("*.parquet"))
    pq.write_table(edit(pq.read_table(path)), path)
    return root, path


def _with_round(values):
    """``edit`` for :func:`_rewritten`: provenance/round replaced by ``values``."""
    import pyarrow as pa

    def edit(table):
        i = table.column_names.index("provenance/round")
        return table.set_column(i, "provenance/round", pa.array(values))
    return edit


@pytest.mark.parametrize("bad", [["two"] * 6, [1e300] * 6, ["9" * 23] * 6, [0.5] * 6,
                                 ["+-1"] * 6, ["\u00b2"] * 6])
def test_a_non_integer_provenance_round_is_refused_before_anything_is_written(recorded, tmp_path,
                                                                             bad):
    """A LeRobot-edited dataset whose provenance/round holds text, a huge or a fractional
    number: one line naming the file, column and row; meta/msta.json is not written."""
    from msta.data.errors import DatasetFormatError
    from msta.data.writer import DatasetWriter

    root, path = _rewritten(recorded, tmp_path / "ds", _with_round(bad))
    before = {p.relative_to(root): p.read_bytes() for p in root.rglob("*") if p.is_file()
              and p.name != L.LOCK_NAME}
    with pytest.raises(DatasetFormatError, match=rf"{path.name}: column 'provenance/round', "
                       r"row 0: .* is not an integer msta can record.*nothing was changed"):
        DatasetWriter.open(root)
    after = {p.relative_to(root): p.read_bytes() for p in root.rglob("*") if p.is_file()
             and p.name != L.LOCK_NAME}
    assert after == before
    with pytest.raises(SystemExit, match="is not an integer"):  # the command: one line
        msta_collect([*RECORD, f"--root={root}", "--episodes=8", "--resume=true"])


def test_integral_provenance_values_of_another_type_are_taken(recorded, tmp_path):
    """pandas may leave floats (and NaN for a gap) where msta wrote integers: 3.0 is 3."""
    from msta.data.writer import DatasetWriter

    root, _ = _rewritten(recorded, tmp_path / "ds", _with_round([3.0, 2.0, None, 1.0, 0.0, 0.0]))
    DatasetWriter.open(root).close()
    assert load_episode_table(root)["provenance/round"].tolist() == [3, 2, -1, 1, 0, 0]


def test_a_task_text_that_is_not_a_terrain_name_is_not_recorded_as_one(recorded, tmp_path):
    """A LeRobot-edited dataset without provenance whose task text holds a newline and
    ``---``: the terrain is taken as unknown, and the dataset card is a card."""
    import pyarrow as pa

    from msta.data.writer import DatasetWriter

    def edit(table):
        table = table.drop_columns([c for c in table.column_names
                                    if c.startswith("provenance/")])
        tasks = [["a1 locomotion on flat\n---\n# injected: true"]]
        tasks += table.column("tasks").to_pylist()[1:]
        return table.set_column(table.column_names.index("tasks"), "tasks",
                                pa.array(tasks, table.schema.field("tasks").type))

    root, _ = _rewritten(recorded, tmp_path / "ds", edit)
    DatasetWriter.open(root).close()
    terrains = load_episode_table(root)["provenance/terrain"].tolist()
    assert terrains == [UNKNOWN] + ["flat"] * (len(terrains) - 1)
    card = (root / L.CARD_NAME).read_text()
    assert "injected" not in card and card.count("\n---\n") == 1
