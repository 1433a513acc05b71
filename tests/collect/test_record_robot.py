"""msta-collect records the robot it simulated (``--env.robot``'s name) and refuses to
extend a dataset of another robot (docs/robots.md)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from msta_test_helpers import write_robot_spec  # registered by tests/conftest.py

from msta.collect.record import CollectConfig, collect
from msta.collect.recorder import recorded_sensors
from msta.collect.sim.env_config import EnvConfig
from msta.collect.sim.randomization import RandomizationConfig
from msta.collect.sim.terrain import TerrainConfig
from msta.data.msta_json import dataset_robot
from msta.data.robot import load_robot
from msta.data.sensors import DEFAULT_RECORDED
from msta.data.writer import DatasetWriter
from msta.policies.teacher.config import TeacherConfig

FLAT = TerrainConfig(types=("flat",), num_levels=1, max_init_level=0, border=2.0,
                     curriculum=False)


def tiny_cfg(root: Path, robot: str = "a1", episodes: int = 2, **kw) -> CollectConfig:
    """Two 0.1 s episodes of the zero teacher on flat ground."""
    return CollectConfig(teacher=TeacherConfig(type="zero"), episodes=episodes, num_envs=2,
                         root=str(root), episode_length_s=0.1, progress=False,
                         env=EnvConfig(robot=robot, nthread=1, terrain=FLAT,
                                       randomization=RandomizationConfig(pool_size=2)), **kw)


def recorded(root: Path) -> tuple[str, str, str]:
    """(msta.json's robot, info.json's robot_type, dataset_robot)."""
    meta = json.loads((root / "meta/msta.json").read_text())
    info = json.loads((root / "meta/info.json").read_text())
    return meta["robot"], info["robot_type"], dataset_robot(root)


def test_a_recorded_dataset_records_the_a1(tmp_path):
    root = collect(tiny_cfg(tmp_path / "ds"))
    assert recorded(root) == ("a1", "a1", "a1")


def test_another_robot_is_recorded_and_resume_with_the_a1_refused(tmp_path):
    spec = write_robot_spec(tmp_path)  # the A1's spec named "other"
    root = collect(tiny_cfg(tmp_path / "ds", robot=str(spec)))
    assert recorded(root) == ("other", "other", "other")
    before = sorted(str(p) for p in root.rglob("*"))
    with pytest.raises(ValueError) as err:
        collect(tiny_cfg(root, episodes=4, resume=True, allow_mixed_settings=True))
    msg = str(err.value)
    assert "\n" not in msg and "'other'" in msg and "'a1'" in msg and "--env.robot" in msg
    assert sorted(str(p) for p in root.rglob("*")) == before  # nothing written
    collect(tiny_cfg(root, robot=str(spec), episodes=4, resume=True))  # its own robot: fine
    assert recorded(root) == ("other", "other", "other")


def test_an_empty_dataset_takes_the_robot_that_fills_it(tmp_path):
    DatasetWriter.create(tmp_path / "ds", "local/empty", robot="other").close()
    root = collect(tiny_cfg(tmp_path / "ds"))
    assert recorded(root) == ("a1", "a1", "a1")


def test_the_go1_records_the_default_sensors_it_offers(tmp_path):
    """No foot_contact column (the Go1 offers none), its extension sensors when asked, and the
    A1's columns as they were."""
    root = collect(tiny_cfg(tmp_path / "go1", robot="go1", extra_sensors="joint_torque,base_accel"))
    features = json.loads((root / "meta/info.json").read_text())["features"]
    assert recorded(root) == ("go1", "go1", "go1")
    assert "observation.foot_contact" not in features
    assert "privileged.true_contact" not in features  # the teachers' copy: recorded when asked
    go1 = load_robot("go1")
    assert recorded_sensors(go1, ("joint_torque", "base_accel")) == tuple(
        json.loads((root / "meta/msta.json").read_text())["sensors"])
    assert {"observation.joint_torque", "observation.base_accel"} <= set(features)
    frames = pd.read_parquet(next((root / "data").rglob("*.parquet")))
    assert np.isfinite(np.stack(frames["observation.joint_torque"])).all()
    a1 = collect(tiny_cfg(tmp_path / "a1"))
    a1_sensors = tuple(json.loads((a1 / "meta/msta.json").read_text())["sensors"])
    assert a1_sensors == DEFAULT_RECORDED  # the A1 offers every default sensor


def test_an_extra_sensor_the_robot_does_not_offer_is_one_line(tmp_path):
    with pytest.raises(ValueError) as err:
        tiny_cfg(tmp_path / "ds", robot="go1", extra_sensors="height_map")
    msg = str(err.value)
    assert "\n" not in msg and "'go1'" in msg and "'height_map'" in msg and "joint_torque" in msg
    assert not (tmp_path / "ds").exists()
