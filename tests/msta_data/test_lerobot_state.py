"""observation.state / observation.environment_state: stock LeRobot policies (ACT, diffusion)
train on msta datasets unchanged, and the derived columns stay in step with the sensors."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from msta.data import derived as D
from msta.data import features as F
from msta.data import stats as S
from msta.data.errors import EpisodeValidationError
from msta.data.sensors import DEFAULT_RECORDED, SENSORS, STUDENT_SENSORS
from msta.data.windows import WindowDataset
from msta.data.writer import DatasetWriter

STATE, ENV = D.STATE_COLUMN, D.ENV_STATE_COLUMN
STATE_SOURCES = [SENSORS[s].column for s in STUDENT_SENSORS]


def _frames(root: Path) -> dict[str, np.ndarray]:
    """Every column of every data file, rows concatenated in file order."""
    tables = [pq.read_table(p) for p in sorted((root / "data").glob("chunk-*/file-*.parquet"))]

    def column(table: pa.Table, c: str) -> np.ndarray:
        arr = table.column(c).combine_chunks()
        if pa.types.is_fixed_size_list(arr.type):
            return arr.flatten().to_numpy().reshape(len(arr), arr.type.list_size)
        return arr.to_numpy(zero_copy_only=False)

    return {c: np.concatenate([column(t, c) for t in tables]) for c in tables[0].column_names}


def _check_in_step(root: Path) -> dict[str, np.ndarray]:
    """Derived columns equal the sensor columns concatenated, frame by frame, and their
    statistics equal those computed over the concatenated values."""
    cols = _frames(root)
    state = np.concatenate([cols[c] for c in STATE_SOURCES], axis=1)
    np.testing.assert_array_equal(cols[STATE], state)
    np.testing.assert_array_equal(cols[ENV], cols["observation.command"])
    stats = S.load_stats(root)
    ep = cols["episode_index"]
    want = S.aggregate(S.episode_stats({STATE: state[ep == e], ENV: cols[ENV][ep == e]})
                       for e in np.unique(ep))
    for col in (STATE, ENV):
        assert set(stats[col]) == set(S.STAT_KEYS)
        for key in S.STAT_KEYS:
            np.testing.assert_allclose(stats[col][key], want[col][key], rtol=1e-12, atol=0,
                                       err_msg=f"{col}/{key}")
    return cols


def test_state_columns_names_values_and_stats(tmp_path, write_dataset):
    root = tmp_path / "ds"
    write_dataset(root, (6, 9, 4), max_frames_per_file=10)  # two data files
    info = json.loads((root / "meta/info.json").read_text())
    names = [f"{s}.{ch}" for s in STUDENT_SENSORS for ch in SENSORS[s].names]
    assert len(names) == 49
    assert info["features"][STATE] == {"dtype": "float32", "shape": [49], "names": names}
    assert info["features"][ENV] == {"dtype": "float32", "shape": [3],
                                     "names": ["command.vx", "command.vy", "command.wz"]}
    assert json.loads((root / "meta/msta.json").read_text())["msta_schema_version"] == 2
    _check_in_step(root)


def test_append_and_recovered_stats_keep_them_in_step(tmp_path, write_dataset):
    root = tmp_path / "ds"
    write_dataset(root, (5, 7))
    write_dataset(root, (8, 3), seed0=10, append=True)
    cols = _check_in_step(root)
    assert len(np.unique(cols["episode_index"])) == 4
    before = S.load_stats(root)
    (root / "meta/stats.json").unlink()  # reopening rebuilds it from the episode rows
    DatasetWriter.open(root).close()
    after = S.load_stats(root)
    for key in S.STAT_KEYS:
        np.testing.assert_allclose(after[STATE][key], before[STATE][key], rtol=1e-12)


def test_subset_of_sensors_gets_a_matching_state(tmp_path, write_dataset):
    root = tmp_path / "ds"
    write_dataset(root, (4,), sensors=["joint_vel", "joint_pos", "height_scan"])
    feats = json.loads((root / "meta/info.json").read_text())["features"]
    assert feats[STATE]["shape"] == [24] and feats[STATE]["names"][0] == "joint_pos.FL_hip"
    assert ENV not in feats  # no command recorded: no environment state
    cols = _frames(root)
    np.testing.assert_array_equal(
        cols[STATE], np.concatenate([cols["observation.joint_pos"],
                                     cols["observation.joint_vel"]], axis=1))


def test_derived_columns_are_filled_by_the_writer_only(tmp_path, synth):
    ep = synth.episode(4, 0)
    ep[STATE] = np.zeros((4, 49), np.float32)
    with (DatasetWriter.create(tmp_path / "ds", "local/x") as w,
          pytest.raises(EpisodeValidationError, match="filled by the writer")):
        w.add_episode(ep, synth.provenance(0))


def test_msta_readers_see_sensors_not_the_state(tmp_path, write_dataset):
    root = tmp_path / "ds"
    write_dataset(root, (5, 6))
    info = F.load_info(root)
    assert set(F.sensor_column_to_name(info["features"]).values()) == set(DEFAULT_RECORDED)
    batch = WindowDataset(root, STUDENT_SENSORS, T=3).get_batch(np.arange(11))
    assert set(batch) == {*STUDENT_SENSORS, "action", "pad"}


def test_schema_1_dataset_loads_and_appends_in_its_own_layout(tmp_path, write_dataset,
                                                              monkeypatch):
    """A dataset written before the derived columns keeps every file without them."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    root = tmp_path / "old"
    with monkeypatch.context() as m:  # msta before schema 2
        m.setattr(F, "MSTA_SCHEMA_VERSION", 1)
        m.setattr(D, "features", lambda columns: {})
        write_dataset(root, (5, 6))
    assert json.loads((root / "meta/msta.json").read_text())["msta_schema_version"] == 1
    write_dataset(root, (4,), seed0=7, append=True)
    for path in (root / "data").glob("chunk-*/file-*.parquet"):
        assert STATE not in pq.read_schema(path).names
    info = json.loads((root / "meta/info.json").read_text())
    assert STATE not in info["features"] and STATE not in S.load_stats(root)
    assert len(LeRobotDataset("local/old", root=root)) == 15
    assert len(WindowDataset(root, STUDENT_SENSORS, T=2)) == 15


# ----- stock lerobot policies on a dataset recorded by msta-collect ---------------------
@pytest.fixture(scope="module")
def collected(tmp_path_factory) -> Path:
    """4 short episodes of the zero teacher, recorded by msta's own collector."""
    from msta.collect.record import CollectConfig, collect
    from msta.collect.sim.env_config import EnvConfig
    from msta.collect.sim.randomization import RandomizationConfig
    from msta.collect.sim.terrain import TerrainConfig
    from msta.policies.teacher.config import TeacherConfig

    root = tmp_path_factory.mktemp("collected") / "ds"
    terrain = TerrainConfig(types=("flat",), num_levels=1, max_init_level=0, border=2.0)
    return collect(CollectConfig(
        teacher=TeacherConfig(type="zero"), episodes=4, num_envs=4, root=str(root),
        repo_id="local/a1_state", episode_length_s=0.5, progress=False,
        env=EnvConfig(nthread=1, terrain=terrain,
                      randomization=RandomizationConfig(pool_size=2))))


def test_act_trains_on_collected_dataset(collected, tmp_path):
    """What lerobot-train does per step (make_policy, its processors, forward, backward),
    without lerobot-train's accelerate dependency."""
    import torch
    from lerobot.datasets.factory import resolve_delta_timestamps
    from lerobot.datasets.lerobot_dataset import LeRobotDataset, LeRobotDatasetMetadata
    from lerobot.policies import ACTConfig, make_policy, make_pre_post_processors

    cfg = ACTConfig(device="cpu", push_to_hub=False, dim_model=32, dim_feedforward=64,
                    n_heads=2, chunk_size=8, n_action_steps=8, latent_dim=8)
    meta = LeRobotDatasetMetadata("local/a1_state", root=collected)
    policy = make_policy(cfg, ds_meta=meta)
    assert cfg.robot_state_feature.shape == (49,) and cfg.env_state_feature.shape == (3,)
    assert not cfg.image_features and not hasattr(policy.model, "backbone")  # no download
    ds = LeRobotDataset("local/a1_state", root=collected,
                        delta_timestamps=resolve_delta_timestamps(cfg, meta))
    pre, _ = make_pre_post_processors(cfg, dataset_stats=meta.stats)
    opt = torch.optim.AdamW(policy.parameters(), lr=1e-3)
    loader = torch.utils.data.DataLoader(ds, batch_size=2, shuffle=True)
    for _, batch in zip(range(2), loader, strict=False):
        loss, _ = policy.forward(pre(batch))
        loss.backward()
        opt.step()
        opt.zero_grad()
        assert torch.isfinite(loss)
    policy.save_pretrained(tmp_path / "ckpt")
    assert (tmp_path / "ckpt" / "model.safetensors").is_file()


def test_diffusion_accepts_the_dataset_features(collected):
    """Diffusion asks what ACT asks (its model needs lerobot[diffusion], not installed)."""
    from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata
    from lerobot.policies import DiffusionConfig
    from lerobot.utils.feature_utils import dataset_to_policy_features

    feats = dataset_to_policy_features(
        LeRobotDatasetMetadata("local/a1_state", root=collected).features)
    cfg = DiffusionConfig(device="cpu", push_to_hub=False,
                          input_features={k: v for k, v in feats.items() if k != "action"},
                          output_features={"action": feats["action"]})
    cfg.validate_features()
    assert cfg.robot_state_feature.shape == (49,) and cfg.env_state_feature.shape == (3,)


LEROBOT_TRAIN = Path(sys.executable).with_name("lerobot-train")


def test_lerobot_train_act_on_collected_dataset(collected, tmp_path):
    out = tmp_path / "out"
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1",
           "WANDB_MODE": "disabled", "HF_HOME": str(tmp_path / "hf"),
           "HF_LEROBOT_HOME": str(tmp_path / "lerobot"), "TORCH_HOME": str(tmp_path / "torch")}
    args = [str(LEROBOT_TRAIN), "--policy.type=act", "--dataset.repo_id=local/a1_state",
            f"--dataset.root={collected}", "--policy.device=cpu", "--policy.push_to_hub=false",
            "--wandb.enable=false", "--steps=2", "--batch_size=2", "--num_workers=0",
            "--save_freq=2", "--log_freq=1", f"--output_dir={out}",
            # a small ACT keeps the test fast; the dataset options are what matter here
            "--policy.dim_model=32", "--policy.dim_feedforward=64", "--policy.n_heads=2",
            "--policy.chunk_size=8", "--policy.n_action_steps=8"]
    proc = subprocess.run(args, check=False, env=env, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    ckpt = out / "checkpoints" / "000002" / "pretrained_model"
    assert (ckpt / "model.safetensors").is_file()
    config = json.loads((ckpt / "config.json").read_text())
    assert config["input_features"][STATE]["shape"] == [49]
    assert not (tmp_path / "torch").exists()  # no backbone weights fetched
