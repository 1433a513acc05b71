"""lerobot 0.6.1's own loader reads what DatasetWriter writes, values intact."""

from __future__ import annotations

import json

import numpy as np
import pytest
from lerobot.datasets.lerobot_dataset import LeRobotDataset

from msta.data import features as F
from msta.data.sensors import SENSORS, STUDENT_SENSORS
from msta.data.windows import WindowDataset

LENGTHS = (7, 12, 5, 9)


@pytest.fixture(scope="module")
def written(tmp_path_factory, write_dataset):
    root = tmp_path_factory.mktemp("compat") / "ds"
    # small flush / file caps so the dataset spans several data and episode files
    eps = write_dataset(root, LENGTHS, flush_every_frames=10, max_frames_per_file=15)
    return root, eps


def _source(eps, col):
    return np.concatenate([ep[col] for ep in eps])


def test_info_json_is_lerobot_v30(written):
    root, _ = written
    info = json.loads((root / "meta/info.json").read_text())
    assert info["codebase_version"] == "v3.0" and info["fps"] == 50
    assert info["total_episodes"] == len(LENGTHS) and info["total_frames"] == sum(LENGTHS)
    for spec in SENSORS.values():
        if spec.extension:  # recorded only when asked (msta-collect --extra_sensors)
            assert spec.column not in info["features"]
            continue
        ft = info["features"][spec.column]
        assert ft == {"dtype": "float32", "shape": [spec.dim], "names": list(spec.names)}
    assert len(list((root / "data").glob("chunk-000/file-*.parquet"))) >= 3


def test_lerobot_loads_every_frame_unchanged(written):
    root, eps = written
    ds = LeRobotDataset("local/test", root=root)
    assert len(ds) == sum(LENGTHS) and ds.num_episodes == len(LENGTHS)
    feats = F.build_features()
    i = 0
    for e, ep in enumerate(eps):
        for t in range(LENGTHS[e]):
            item = ds[i]
            assert item["episode_index"].item() == e and item["frame_index"].item() == t
            assert item["index"].item() == i
            assert item["timestamp"].item() == pytest.approx(t / 50)
            for col in F.input_columns(feats):
                np.testing.assert_array_equal(item[col].numpy(), ep[col][t], err_msg=col)
            assert item["task"] == F.task_string(F.Provenance(**_prov(ds, e)))
            i += 1


def _prov(ds, e):
    row = ds.meta.episodes[e]
    return {k.split("/", 1)[1]: row[k] for k in F.PROVENANCE_COLUMNS}


def test_delta_timestamps_match_window_dataset(written):
    root, _ = written
    T = 4
    keys = ["observation.joint_pos", "observation.foot_contact"]
    deltas = {k: [(t - T + 1) / 50 for t in range(T)] for k in keys}
    ds = LeRobotDataset("local/test", root=root, delta_timestamps=deltas)
    wd = WindowDataset(root, ["joint_pos", "foot_contact"], T=T)
    batch = wd.get_batch(np.arange(len(wd)))
    for i in range(len(ds)):
        item = ds[i]
        for k in keys:
            np.testing.assert_array_equal(item[k].numpy(), batch[k.split(".")[1]][i])
            np.testing.assert_array_equal(item[f"{k}_is_pad"].numpy(), batch["pad"][i])
    assert batch["pad"].any() and not batch["pad"].all()


def test_stats_loaded_by_lerobot_match_data(written):
    root, eps = written
    ds = LeRobotDataset("local/test", root=root)
    stats = ds.meta.stats
    assert set(stats) == set(F.build_features(derived=True))
    for col in ("observation.joint_pos", "privileged.height_scan", "next.reward", "action"):
        x = _source(eps, col).astype(np.float64).reshape(sum(LENGTHS), -1)
        st = stats[col]
        assert st["count"].tolist() == [sum(LENGTHS)]
        np.testing.assert_allclose(st["mean"], x.mean(0), rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose(st["std"], x.std(0), rtol=1e-6, atol=1e-9)
        np.testing.assert_array_equal(st["min"], x.min(0))
        np.testing.assert_array_equal(st["max"], x.max(0))
        for q in ("q01", "q10", "q50", "q90", "q99"):
            assert np.all(st[q] >= x.min(0)) and np.all(st[q] <= x.max(0))
        assert np.all(st["q01"] <= st["q50"]) and np.all(st["q50"] <= st["q99"])


def test_provenance_round_trip_and_episode_filter(written, synth):
    root, _ = written
    ds = LeRobotDataset("local/test", root=root)
    for e in range(len(LENGTHS)):
        assert _prov(ds, e) == synth.provenance(e)
    stairs = LeRobotDataset("local/test", root=root,
                            episode_filter=lambda ep: ep["provenance/terrain"] == "stairs_up")
    assert stairs.episodes == [2]
    assert len(stairs) == LENGTHS[2]


def test_observation_inputs_are_student_columns_and_their_concatenation(written):
    """No privileged signal reaches lerobot's policy inputs (every ``observation.*``)."""
    root, _ = written
    ds = LeRobotDataset("local/test", root=root)
    obs = sorted(k for k in ds.features if k.startswith("observation."))
    assert obs == sorted([SENSORS[s].column for s in STUDENT_SENSORS]
                         + ["observation.state", "observation.environment_state"])


def test_schema_and_stats_aggregation_agree_with_lerobot(synth):
    from lerobot.datasets.compute_stats import aggregate_stats
    from lerobot.datasets.feature_utils import get_hf_features_from_features

    from msta.data import stats as S

    feats = F.build_features()
    assert F.data_schema(feats).equals(get_hf_features_from_features(feats).arrow_schema,
                                       check_metadata=True)
    per_episode = [S.episode_stats({"a": synth.episode(n, n)["observation.joint_pos"],
                                    "r": synth.episode(n, n)["next.reward"]})
                   for n in (1, 4, 9)]
    ours, theirs = S.aggregate(per_episode), aggregate_stats(per_episode)
    for col in ("a", "r"):
        assert set(ours[col]) == set(theirs[col])
        for k in ours[col]:
            np.testing.assert_allclose(ours[col][k], theirs[col][k], rtol=1e-12, err_msg=k)
