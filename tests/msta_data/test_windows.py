"""WindowDataset: windows, padding, selection, and clear errors on bad datasets."""

from __future__ import annotations

import json

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import torch

from msta.data.errors import DatasetFormatError
from msta.data.sensors import SENSORS, STUDENT_SENSORS
from msta.data.windows import WindowDataset, episode_split

LENGTHS = (3, 20, 1, 8)


@pytest.fixture(scope="module")
def ds(tmp_path_factory, write_dataset):
    root = tmp_path_factory.mktemp("win") / "ds"
    eps = write_dataset(root, LENGTHS, flush_every_frames=12)
    return root, eps


def _expected_window(eps, e, t, col, T):
    rows = [max(0, t - T + 1 + k) for k in range(T)]
    return eps[e][col][rows].reshape(T, -1), np.array([t - T + 1 + k < 0 for k in range(T)])


@pytest.mark.parametrize("T", [1, 5, 15])
def test_windows_equal_source_rows_with_padding(ds, T):
    root, eps = ds
    sensors = [*STUDENT_SENSORS, "base_height"]
    wd = WindowDataset(root, sensors, T=T, extra_columns=("action", "next.done", "next.reward"))
    assert len(wd) == sum(LENGTHS)
    batch = wd.get_batch(np.arange(len(wd)))
    i = 0
    for e, n in enumerate(LENGTHS):
        for t in range(n):
            for s in sensors:
                want, pad = _expected_window(eps, e, t, SENSORS[s].column, T)
                assert batch[s].shape[1:] == (T, SENSORS[s].dim) and batch[s].dtype == np.float32
                np.testing.assert_array_equal(batch[s][i], want, err_msg=f"{s} ep{e} t{t}")
                np.testing.assert_array_equal(batch["pad"][i], pad)
            np.testing.assert_array_equal(batch["action"][i], eps[e]["action"][t])
            assert batch["next.done"][i] == (t == n - 1)
            assert batch["next.reward"][i] == eps[e]["next.reward"][t]
            i += 1
    if T == 1:
        assert not batch["pad"].any()


def test_episode_subset_in_given_order(ds):
    root, eps = ds
    wd = WindowDataset(root, ["joint_pos"], T=4, episodes=[3, 0])
    assert wd.episodes == [3, 0] and len(wd) == LENGTHS[3] + LENGTHS[0]
    b = wd.get_batch(np.array([0, LENGTHS[3], len(wd) - 1]))
    np.testing.assert_array_equal(b["joint_pos"][1, -1], eps[0]["observation.joint_pos"][0])
    assert b["pad"][1].tolist() == [True, True, True, False]
    np.testing.assert_array_equal(b["joint_pos"][2, :, :], eps[0]["observation.joint_pos"][
        [0, 0, 1, 2]])
    assert wd.episode_of(np.array([0, LENGTHS[3]])).tolist() == [3, 0]
    with pytest.raises(ValueError, match="distinct indices"):
        WindowDataset(root, ["joint_pos"], episodes=[4])


def test_getitem_works_with_torch_dataloader(ds):
    root, _ = ds
    wd = WindowDataset(root, ["gravity", "command"], T=6)
    loader = torch.utils.data.DataLoader(wd, batch_size=7, shuffle=False)
    first = next(iter(loader))
    ref = wd.get_batch(np.arange(7))
    for k, v in ref.items():
        np.testing.assert_array_equal(first[k].numpy(), v)
    assert first["pad"].dtype == torch.bool
    with pytest.raises(IndexError):
        wd[len(wd)]
    with pytest.raises(IndexError):
        wd.get_batch(np.array([len(wd)]))


def test_episode_split(ds):
    root, _ = ds
    train, val = episode_split(root, 0.5, seed=3)
    assert sorted(train + val) == list(range(len(LENGTHS))) and len(val) == 2
    assert episode_split(root, 0.5, seed=3) == (train, val)
    assert episode_split(root, 0.0) == (list(range(len(LENGTHS))), [])
    with pytest.raises(ValueError, match="val_fraction"):
        episode_split(root, 1.0)


# ----- bad datasets ------------------------------------------------------------------------

@pytest.fixture
def small(tmp_path, write_dataset):
    root = tmp_path / "ds"
    write_dataset(root, [6, 5], sensors=["joint_pos", "command"])
    return root


def _rewrite_column(root, col, fn):
    path = root / "data/chunk-000/file-000.parquet"
    table = pq.read_table(path)
    i = table.column_names.index(col)
    new = fn(table.column(col))
    table = table.remove_column(i) if new is None else table.set_column(i, col, new)
    pq.write_table(table, path)
    return path


def _edit_info(root, **kv):
    path = root / "meta/info.json"
    info = json.loads(path.read_text())
    info.update(kv)
    path.write_text(json.dumps(info))


def _nan_at_row_2(col):
    x = col.combine_chunks().flatten().to_numpy().reshape(len(col), -1).copy()
    x[2, 1] = np.nan
    return pa.FixedSizeListArray.from_arrays(pa.array(x.reshape(-1)), x.shape[1])


def _width_11(col):
    x = col.combine_chunks().flatten().to_numpy().reshape(len(col), -1)[:, :11].copy()
    return pa.FixedSizeListArray.from_arrays(pa.array(x.reshape(-1)), 11)


def _float64(col):
    x = col.combine_chunks().flatten().to_numpy().reshape(len(col), -1).astype(np.float64)
    return pa.FixedSizeListArray.from_arrays(pa.array(x.reshape(-1)), x.shape[1])


@pytest.mark.parametrize("corrupt, match", [
    (lambda r: None, None),  # control: the untouched dataset loads
    (lambda r: _rewrite_column(r, "observation.command", lambda c: None),
     r"file-000.parquet: column 'observation.command' missing"),
    (lambda r: _rewrite_column(r, "observation.joint_pos", _width_11),
     r"file-000.parquet: column 'observation.joint_pos' has Arrow type .*\[11\]"),
    (lambda r: _rewrite_column(r, "observation.joint_pos", _float64),
     r"file-000.parquet: column 'observation.joint_pos' has Arrow type .*double"),
    (lambda r: _rewrite_column(r, "observation.joint_pos", _nan_at_row_2),
     r"file-000.parquet: column 'observation.joint_pos' has NaN/Inf at episode 0, frame 2"),
    (lambda r: _rewrite_column(r, "action", _nan_at_row_2),
     r"file-000.parquet: column 'action' has NaN/Inf"),
    (lambda r: _edit_info(r, codebase_version="v2.1"),
     r"meta/info.json: codebase_version is 'v2.1', expected 'v3.0'"),
    (lambda r: _edit_info(r, fps=25), r"meta/info.json: fps is 25, expected 50"),
    (lambda r: _truncate(r / "data/chunk-000/file-000.parquet"),
     r"file-000.parquet: cannot read Parquet \(truncated or corrupt"),
    (lambda r: _truncate(r / "meta/episodes/chunk-000/file-000.parquet"),
     r"episodes/chunk-000/file-000.parquet: cannot read Parquet"),
    (lambda r: (r / "data/chunk-000/file-000.parquet").unlink(),
     r"file-000.parquet: no such file"),
])
def test_corrupt_dataset_errors_name_file_and_column(small, corrupt, match):
    corrupt(small)
    if match is None:
        assert len(WindowDataset(small, ["joint_pos", "command"])) == 11
        return
    with pytest.raises(DatasetFormatError, match=match):
        WindowDataset(small, ["joint_pos", "command"])


def _truncate(path):
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def test_missing_sensor_column_and_fps_and_timestamps(small):
    with pytest.raises(DatasetFormatError, match=r"info.json: column 'observation.joint_vel' "
                                                 r"missing"):
        WindowDataset(small, ["joint_pos", "joint_vel"])
    with pytest.raises(DatasetFormatError, match=r"info.json: fps is 50, expected 30"):
        WindowDataset(small, ["joint_pos"], fps=30)
    with pytest.raises(KeyError, match="unknown sensor 'nope'"):
        WindowDataset(small, ["nope"])
    _edit_info(small, fps=25)  # data timestamps were written at 50 Hz
    with pytest.raises(DatasetFormatError, match=r"column 'timestamp' .* not frame_index / 25"):
        WindowDataset(small, ["joint_pos"], fps=25)
