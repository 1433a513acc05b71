"""A student's config records the robots it was trained on (``robots``); a config.json
written before the field counts as the A1's (docs/robots.md)."""

from __future__ import annotations

import json

import pytest
from msta_test_helpers import tiny_msta  # registered by tests/conftest.py

from msta.policies.config import PolicyConfig, check_trained_on
from msta.policies.factory import load_config, load_policy


def test_a_checkpoint_records_its_robots_and_an_old_one_counts_as_the_a1(tmp_path):
    policy = tiny_msta(history=3)
    policy.config.robots = ("a1", "go")  # a student of two robots' datasets
    ckpt = policy.save_pretrained(tmp_path / "two")
    assert json.loads((ckpt / "config.json").read_text())["robots"] == ["a1", "go"]
    assert load_policy(ckpt).config.robots == ("a1", "go")
    data = json.loads((ckpt / "config.json").read_text())
    data.pop("robots")  # as written before checkpoints recorded their robots
    (ckpt / "config.json").write_text(json.dumps(data))
    assert load_config(ckpt).robots == ("a1",)


@pytest.mark.parametrize("robots", [[], ["a1", "a1"], [""]])
def test_robots_must_name_robots(robots):
    data = {**tiny_msta(history=3).config.to_dict(), "robots": robots}
    with pytest.raises(ValueError, match="robot"):
        PolicyConfig.from_dict(data)


def test_another_robot_is_refused_in_one_line():
    check_trained_on(("a1", "go"), "go", "ckpt", "--robot")  # one of them: accepted
    with pytest.raises(ValueError) as err:
        check_trained_on(("a1",), "go", "--policy.path=ckpt", "--env.robot")
    msg = str(err.value)
    assert "\n" not in msg and "'a1'" in msg and "'go'" in msg and "--env.robot" in msg
