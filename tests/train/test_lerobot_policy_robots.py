"""lerobot-train's MSTA on another robot's dataset: the student reads the default inputs the
dataset has (the Go1 has no foot contacts) and records the dataset's robot, as msta-train's
does (docs/robots.md)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata
from lerobot.policies.factory import make_policy
from msta_test_helpers import random_episode  # registered by conftest.py

from lerobot_policy_msta import MSTAConfig  # installed by the Makefile's venv step
from msta.data import sensors
from msta.data.writer import DatasetWriter

#: What a Go1 dataset records by default: no foot_contact.
GO1_RECORDED = tuple(n for n in sensors.DEFAULT_RECORDED if n != "foot_contact")
TINY = {"dim": 32, "num_layers": 1, "num_heads": 2, "head_hidden_dim": 32, "history": 4}


@pytest.fixture(autouse=True)
def keep_threads():
    """A policy built for a dataset sets torch's threads; the other tests keep theirs."""
    threads = torch.get_num_threads()
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def go1_dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("go1") / "ds"
    rng = np.random.default_rng(0)
    with DatasetWriter.create(root, "local/go1", robot="go1", sensors=GO1_RECORDED) as w:
        for i in range(2):
            w.add_episode(random_episode(12, rng, GO1_RECORDED), {
                "terrain": "flat", "terrain_level": 0, "source": "teacher", "round": 0,
                "policy": "synthetic", "policy_revision": "", "seed": i})
    return root


def test_the_student_reads_what_the_go1_has_and_records_the_go1(go1_dataset, tmp_path, capsys):
    meta = LeRobotDatasetMetadata("local/go1", root=go1_dataset)
    policy = make_policy(MSTAConfig(**TINY, device="cpu"), ds_meta=meta)
    said = [ln for ln in capsys.readouterr().err.splitlines() if "foot_contact" in ln]
    assert len(said) == 1 and "lacks foot_contact" in said[0], said
    want = tuple(n for n in sensors.STUDENT_SENSORS if n != "foot_contact")
    assert policy.config.input_sensors == want
    assert "foot_contact" not in policy.config.state_sensors
    assert policy.config.robots == ("go1",)
    policy.save_pretrained(tmp_path / "ckpt")
    saved = json.loads((tmp_path / "ckpt" / "config.json").read_text())
    assert saved["robots"] == ["go1"] and saved["input_sensors"] == list(want)


def test_named_inputs_the_dataset_lacks_are_still_refused(go1_dataset):
    meta = LeRobotDatasetMetadata("local/go1", root=go1_dataset)
    cfg = MSTAConfig(**TINY, device="cpu", input_sensors=("joint_pos", "foot_contact"))
    with pytest.raises(ValueError, match=r"input sensors \['foot_contact'\] are not in"):
        make_policy(cfg, ds_meta=meta)
