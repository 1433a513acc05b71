"""One student for two robots (``msta-train --more_datasets``): the windows of an A1 dataset
(with foot contacts) and a Go1 dataset (without) train one MSTA student; the Go1's samples
read no foot contact (removed per sample, not zeros), the checkpoint records both robots, and
the student acts on a robot that does not offer one of its inputs by removing it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from msta_test_helpers import random_episode  # registered by conftest.py

from msta.data import sensors
from msta.data.stats import aggregate, load_stats
from msta.data.window_union import WindowUnion
from msta.data.windows import WindowDataset
from msta.data.writer import DatasetWriter
from msta.policies.actor import StudentActor
from msta.policies.baselines.configs import GRUConfig
from msta.policies.factory import load_config, load_policy, make_policy
from msta.policies.input_spec import InputSpec
from msta.policies.msta import MSTAConfig
from msta.train.cli import parse_cli
from msta.train.stage1 import train, union_stats
from msta.train.step import batch_absent
from msta.train.train_config import TrainConfig

GO1 = tuple(n for n in sensors.DEFAULT_RECORDED if n != "foot_contact")
INPUTS = sensors.STUDENT_SENSORS  # the paper's seven, foot_contact among them


def dataset_of(root: Path, robot: str, recorded: tuple[str, ...] | None = None) -> Path:
    """Three random episodes of 20 steps recorded as ``robot``'s."""
    rng = np.random.default_rng(len(robot))
    with DatasetWriter.create(root, f"local/{robot}", robot=robot, sensors=recorded) as w:
        for i in range(3):
            w.add_episode(random_episode(20, rng, recorded), {
                "terrain": "flat", "terrain_level": 0, "source": "teacher", "round": 0,
                "policy": "synthetic", "policy_revision": "", "seed": i})
    return root


def train_args(root: Path, out: Path, *extra: str) -> list[str]:
    return [f"--dataset={root}", f"--output_dir={out}", "--policy.preset=tiny",
            "--policy.history=3", "--steps=2", "--batch_size=8", "--warmup_steps=1",
            "--progress=false", "--device=cpu", "--val_fraction=0.34", *extra]


@pytest.fixture(scope="module")
def two(tmp_path_factory):
    base = tmp_path_factory.mktemp("two")
    return dataset_of(base / "a1", "a1"), dataset_of(base / "go1", "go1", recorded=GO1)


def test_the_union_removes_what_a_dataset_does_not_record(two):
    a1, go1 = two
    parts = [WindowDataset(a1, INPUTS, 3), WindowDataset(go1, [s for s in INPUTS if s in GO1], 3)]
    union = WindowUnion(parts, INPUTS)
    assert len(union) == len(parts[0]) + len(parts[1])
    rows = np.array([0, len(parts[0]) + 5, 7, len(union) - 1])
    batch, absent = union.get_batch(rows), union.absent_of(rows)
    own_a1, own_go1 = parts[0].get_batch(np.array([0, 7])), parts[1].get_batch(
        np.array([5, len(parts[1]) - 1]))
    for s in INPUTS:
        np.testing.assert_array_equal(batch[s][[0, 2]], own_a1[s])
        if s != "foot_contact":
            np.testing.assert_array_equal(batch[s][[1, 3]], own_go1[s])
    np.testing.assert_array_equal(batch["action"][[1, 3]], own_go1["action"])
    np.testing.assert_array_equal(batch["pad"][[0, 2]], own_a1["pad"])
    assert list(absent) == ["foot_contact"]  # only the Go1's samples, only foot contacts
    assert absent["foot_contact"].tolist() == [[False] * 4, [True] * 4, [False] * 4, [True] * 4]
    assert union.absent_of(np.array([0, 7])) is None  # A1 samples only: nothing removed


def test_a_go1_sample_reads_no_foot_contact(two):
    """The loss of the union's batch does not depend on the values standing in for the Go1's
    missing foot contacts: they are removed, not read as zeros."""
    a1, go1 = two
    parts = [WindowDataset(a1, INPUTS, 3), WindowDataset(go1, [s for s in INPUTS if s in GO1], 3)]
    union = WindowUnion(parts, INPUTS)
    policy = make_policy(MSTAConfig.from_preset("tiny", history=3),
                         union_stats([a1, go1]))
    rows = np.arange(len(parts[0]) - 4, len(parts[0]) + 4)  # four of each
    batch, gone = union.get_batch(rows), batch_absent(union, rows)
    loss = policy.loss(batch, mask_ratio=0.0, absent=gone)[0]
    batch["foot_contact"][4:] = 1.0  # values the Go1 never measured
    assert torch.equal(policy.loss(batch, mask_ratio=0.0, absent=gone)[0], loss)
    batch["foot_contact"][:4] = 1.0 - batch["foot_contact"][:4]  # the A1's: they are read
    assert not torch.equal(policy.loss(batch, mask_ratio=0.0, absent=gone)[0], loss)


def test_one_student_trains_on_both_robots(two, tmp_path, capsys):
    a1, go1 = two
    cfg = parse_cli(TrainConfig, train_args(a1, tmp_path / "run", f"--more_datasets=[{go1}]"),
                    prog="msta-train")
    final = train(cfg)
    saved = json.loads((final / "config.json").read_text())
    assert saved["robots"] == ["a1", "go1"]
    assert saved["input_sensors"] == list(INPUTS)  # the A1 records foot contacts
    assert "train episodes" in capsys.readouterr().out
    stats = load_policy(final).processor.stats
    col = "observation.joint_pos"
    want = aggregate([{col: load_stats(a1)[col]}, {col: load_stats(go1)[col]}])
    np.testing.assert_allclose(np.asarray(stats[col]["mean"]), want[col]["mean"], rtol=1e-6)
    np.testing.assert_allclose(np.asarray(stats[col]["std"]), want[col]["std"], rtol=1e-6)
    assert load_config(final).robots == ("a1", "go1")
    # a baseline trains on both too: its learned placeholders stand in for the Go1's contacts
    gru = train(parse_cli(TrainConfig, train_args(a1, tmp_path / "gru", f"--more_datasets=[{go1}]",
                                                  "--policy.type=gru"), prog="msta-train"))
    assert load_config(gru).robots == ("a1", "go1")

def test_the_student_acts_without_an_input_its_robot_does_not_offer(two):
    a1 = two[0]
    policy = make_policy(MSTAConfig.from_preset("tiny", history=3), load_stats(a1))
    rng = np.random.default_rng(1)
    obs = {s: rng.normal(size=(2, sensors.get(s).dim)).astype(np.float32) for s in INPUTS}
    go1_obs = {s: v for s, v in obs.items() if s != "foot_contact"}
    got = StudentActor(policy, 2).act(go1_obs)
    dropped = StudentActor(policy, 2, InputSpec(drop_sensors=("foot_contact",))).act(obs)
    np.testing.assert_array_equal(got, dropped)
    assert not np.array_equal(got, StudentActor(policy, 2).act(obs))
    gru = make_policy(GRUConfig(history=3), load_stats(a1))
    got = StudentActor(gru, 2).act(go1_obs)
    dropped = StudentActor(gru, 2, InputSpec(drop_sensors=("foot_contact",))).act(obs)
    np.testing.assert_array_equal(got, dropped)
