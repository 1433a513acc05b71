"""DatasetWriter: append, locking, input validation, stats."""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest

from msta.data import stats as S
from msta.data.errors import DatasetLockedError, EpisodeValidationError
from msta.data.windows import WindowDataset, load_episode_table
from msta.data.writer import DatasetWriter


def _digests(root):
    return {p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.glob("**/*.parquet")) if "meta/tasks" not in p.as_posix()}


def test_append_keeps_files_and_updates_totals_and_stats(tmp_path, write_dataset, synth):
    root = tmp_path / "ds"
    first = write_dataset(root, [6, 9, 4], flush_every_frames=8)
    before = _digests(root)
    second = write_dataset(root, [5, 7], seed0=10, append=True)
    after = _digests(root)
    assert all(after[k] == v for k, v in before.items())  # earlier files byte-identical
    assert len(after) > len(before)
    info = json.loads((root / "meta/info.json").read_text())
    assert info["total_episodes"] == 5 and info["total_frames"] == 31
    assert info["splits"] == {"train": "0:5"}
    everything = first + second
    stats = S.load_stats(root)
    for col in ("observation.joint_vel", "next.lin_vel_tracking", "executed_action"):
        x = np.concatenate([ep[col] for ep in everything]).astype(np.float64).reshape(31, -1)
        assert stats[col]["count"].tolist() == [31]
        np.testing.assert_allclose(stats[col]["mean"], x.mean(0), rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose(stats[col]["std"], x.std(0), rtol=1e-6, atol=1e-9)
        np.testing.assert_array_equal(stats[col]["max"], x.max(0))
    assert stats["episode_index"]["max"].tolist() == [4.0]
    table = load_episode_table(root)
    assert table["episode_index"].tolist() == list(range(5))
    assert table["provenance/seed"].tolist() == [1000, 1001, 1002, 1010, 1011]
    wd = WindowDataset(root, ["joint_vel"], T=1, extra_columns=("executed_action",))
    np.testing.assert_array_equal(wd.get_batch(np.arange(31))["executed_action"],
                                  np.concatenate([ep["executed_action"] for ep in everything]))


def test_append_stage2_provenance(tmp_path, write_dataset, synth):
    root = tmp_path / "ds"
    write_dataset(root, [5])
    with DatasetWriter.open(root) as w:
        idx = w.add_episode(synth.episode(4, 3), synth.provenance(3, source="student", round_=2))
    assert idx == 1
    row = load_episode_table(root).iloc[1]
    assert row["provenance/source"] == "student" and row["provenance/round"] == 2
    assert row["provenance/policy"] == "msta" and row["tasks"].tolist() == [
        "a1 locomotion on stairs_down"]


def test_second_writer_is_refused(tmp_path, write_dataset, synth):
    root = tmp_path / "ds"
    write_dataset(root, [3])
    with DatasetWriter.open(root) as w:
        with pytest.raises(DatasetLockedError, match="another writer"):
            DatasetWriter.open(root)
        w.add_episode(synth.episode(3, 1), synth.provenance(1))
    with DatasetWriter.open(root) as w:  # released on close
        assert w.num_episodes == 2


def test_create_refuses_existing_dataset(tmp_path, write_dataset):
    root = tmp_path / "ds"
    write_dataset(root, [3])
    with pytest.raises(FileExistsError, match="DatasetWriter.open"):
        DatasetWriter.create(root, "local/x")


def _bad(ep, col, value):
    ep = dict(ep)
    if value is None:
        del ep[col]
    else:
        ep[col] = value
    return ep


@pytest.mark.parametrize("mutate, match", [
    (lambda ep: _bad(ep, "observation.gravity", None), r"missing \['observation.gravity'\]"),
    (lambda ep: {**ep, "observation.bogus": ep["action"]}, "unknown.*observation.bogus"),
    (lambda ep: {**ep, "timestamp": np.zeros(5, np.float32)}, "filled by the writer"),
    (lambda ep: _bad(ep, "action", ep["action"].astype(np.float64)),
     "'action': dtype float64, expected float32"),
    (lambda ep: _bad(ep, "observation.joint_pos", ep["observation.joint_pos"][:, :11]),
     r"'observation.joint_pos': shape \(5, 11\), expected \(L, 12\)"),
    (lambda ep: _bad(ep, "next.reward", ep["next.reward"][:4]), "'next.reward': 4 frames"),
    (lambda ep: _bad(ep, "next.done", ep["next.done"].astype(np.float32)),
     "'next.done': dtype float32, expected bool"),
    (lambda ep: _bad(ep, "observation.joint_vel", _with(ep["observation.joint_vel"], np.nan)),
     "'observation.joint_vel': non-finite value nan at frame 2, channel 'FR_thigh'"),
    (lambda ep: _bad(ep, "privileged.height_scan", _with(ep["privileged.height_scan"], np.inf)),
     "'privileged.height_scan': non-finite value inf at frame 2"),
    (lambda ep: _bad(ep, "command", ep["action"]), "unknown"),
    (lambda ep: _bad(ep, "action", ep["action"].tolist()), "expected np.ndarray"),
])
def test_bad_episode_is_rejected(tmp_path, synth, mutate, match):
    ep = synth.episode(5, 0)
    with DatasetWriter.create(tmp_path / "ds", "local/x") as w:
        with pytest.raises(EpisodeValidationError, match=match):
            w.add_episode(mutate(ep), synth.provenance(0))
        assert w.num_episodes == 0


def _with(a, value):
    a = a.copy()
    a[2, 4] = value
    return a


@pytest.mark.parametrize("prov, match", [
    ({"terrain": "x"}, "missing"),
    ({"extra": 1}, "unknown"),
    ({"source": "robot"}, "source"),
    ({"seed": "7"}, "'seed' must be an int"),
])
def test_bad_provenance_is_rejected(tmp_path, synth, prov, match):
    base = synth.provenance(0)
    p = prov if list(prov) == ["terrain"] else {**base, **prov}
    with (DatasetWriter.create(tmp_path / "ds", "local/x") as w,
          pytest.raises(EpisodeValidationError, match=match)):
        w.add_episode(synth.episode(4, 0), p)


def test_buffered_episodes_survive_an_exception_in_the_block(tmp_path, synth):
    root = tmp_path / "ds"
    with pytest.raises(EpisodeValidationError), DatasetWriter.create(root, "local/x") as w:
        w.add_episode(synth.episode(4, 0), synth.provenance(0))
        w.add_episode({}, synth.provenance(1))
    assert json.loads((root / "meta/info.json").read_text())["total_episodes"] == 1


def test_sensor_subset_and_caller_buffers_are_copied(tmp_path, synth):
    root = tmp_path / "ds"
    sensors = ["joint_pos", "command"]
    ep = synth.episode(6, 0, sensors)
    with DatasetWriter.create(root, "local/x", sensors=sensors) as w:
        w.add_episode(ep, synth.provenance(0))
        original = ep["observation.joint_pos"].copy()
        ep["observation.joint_pos"][:] = 0  # the collector reuses its buffers
    wd = WindowDataset(root, sensors, T=1)
    np.testing.assert_array_equal(wd.get_batch(np.arange(6))["joint_pos"][:, 0], original)
