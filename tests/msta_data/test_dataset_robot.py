"""A dataset records its robot (``meta/msta.json``'s ``robot``, ``info.json``'s
``robot_type``); a dataset written before that counts as the A1; appending episodes of
another robot is refused in one line (docs/robots.md)."""

from __future__ import annotations

import json
import shutil

import pytest
from msta_test_helpers import as_before_robots  # registered by tests/conftest.py

from msta.data.errors import DatasetFormatError
from msta.data.features import load_info
from msta.data.lerobot_edits import derive_msta_meta
from msta.data.msta_json import dataset_robot
from msta.data.sensors import STUDENT_SENSORS
from msta.data.windows import WindowDataset
from msta.data.writer import DatasetWriter
from msta.train.stage2 import append_episodes


def test_a_new_dataset_records_its_robot(tmp_path, synth):
    with DatasetWriter.create(tmp_path / "ds", "local/go", robot="go") as w:
        w.add_episode(synth.episode(5, 0), synth.provenance(0))
    meta = json.loads((tmp_path / "ds/meta/msta.json").read_text())
    info = json.loads((tmp_path / "ds/meta/info.json").read_text())
    assert (meta["robot"], info["robot_type"]) == ("go", "go")
    assert dataset_robot(tmp_path / "ds") == "go"
    with DatasetWriter.open(tmp_path / "ds") as w:  # an append keeps it
        w.add_episode(synth.episode(4, 1), synth.provenance(1))
    assert dataset_robot(tmp_path / "ds") == "go"
    assert json.loads((tmp_path / "ds/meta/msta.json").read_text())["robot"] == "go"


def test_a_dataset_without_the_field_reads_as_the_a1_and_appends(tmp_path, write_dataset,
                                                                 synth):
    root = tmp_path / "old"
    write_dataset(root, (5, 6))
    as_before_robots(root, robot_type="unitree_a1")  # robot_type held whatever it held
    assert "robot" not in json.loads((root / "meta/msta.json").read_text())
    assert dataset_robot(root) == "a1"
    assert len(WindowDataset(root, STUDENT_SENSORS, T=2)) == 11  # checksums intact
    episode = (synth.episode(4, 7), synth.provenance(7, source="student", round_=1))
    assert append_episodes(root, [episode], robot="a1") == 3


def test_appending_episodes_of_another_robot_is_refused(tmp_path, write_dataset, synth):
    root = tmp_path / "a1"
    write_dataset(root, (5,))
    before = sorted(p.name for p in root.rglob("*"))
    episode = (synth.episode(4, 7), synth.provenance(7, source="student", round_=1))
    with pytest.raises(ValueError) as err:
        append_episodes(root, [episode], robot="go")
    msg = str(err.value)
    assert "\n" not in msg and "'a1'" in msg and "'go'" in msg and "--env.robot" in msg
    assert sorted(p.name for p in root.rglob("*")) == before  # nothing appended


def test_a_bad_robot_field_is_refused_naming_the_file(tmp_path, write_dataset):
    root = tmp_path / "bad"
    write_dataset(root, (5,))
    meta = json.loads((root / "meta/msta.json").read_text())
    (root / "meta/msta.json").write_text(json.dumps({**meta, "robot": ["a1"]}))
    with pytest.raises(DatasetFormatError, match=r"msta\.json: 'robot' must be a robot's name"):
        dataset_robot(root)


def test_a_dataset_lerobot_rewrote_keeps_its_robot_type(tmp_path, synth):
    root = tmp_path / "go"
    with DatasetWriter.create(root, "local/go", robot="go") as w:
        w.add_episode(synth.episode(5, 0), synth.provenance(0))
    copy = shutil.copytree(root, tmp_path / "rewritten")
    for name in ("msta.json", "msta_checksums.json"):  # what LeRobot's tools leave out
        (copy / "meta" / name).unlink()
    assert derive_msta_meta(copy, load_info(copy))["robot"] == "go"
    assert dataset_robot(copy) == "go"
