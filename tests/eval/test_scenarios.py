"""Scenario and suite registries."""

from __future__ import annotations

import itertools

import pytest

from msta.data.sensors import STUDENT_SENSORS
from msta.eval.scenarios import (
    SCENARIOS,
    SUITES,
    build_conditions,
    dead_joint_set,
    get_scenario,
    get_suite,
)


def test_dead_joint_sets_are_seeded_and_nested():
    sets = [dead_joint_set(k, seed=0) for k in range(7)]
    assert [len(s) for s in sets] == list(range(7))
    for small, big in itertools.pairwise(sets):
        assert set(small) < set(big)
    assert sets == [dead_joint_set(k, seed=0) for k in range(7)]
    assert dead_joint_set(6, seed=1) != sets[6]
    with pytest.raises(ValueError, match="k=13"):
        dead_joint_set(13, 0)


def test_paper_suite_conditions():
    conds = build_conditions(list(SCENARIOS), SUITES["paper"], STUDENT_SENSORS, seed=3)
    by = {}
    for c in conds:
        by.setdefault(c.scenario, []).append(c)
    assert [c.spec.mask_ratio for c in by["token_removal"]] == [0.0, 0.25, 0.5]
    # mask_matrix reuses the token-removal conditions instead of duplicating them
    assert "mask_matrix" not in by and len(conds) == len({c.key for c in conds})
    assert [c.spec.drop_sensors for c in by["sensor_removal"]] == \
        [()] + [(s,) for s in STUDENT_SENSORS]
    assert [len(c.spec.dead_joints) for c in by["dead_joints"]] == list(range(7))
    assert [c.spec.history for c in by["history"]] == [3, 5, 7, 10, 15, 20]
    assert all(c.spec.seed == 3 for c in conds)


def test_sensor_removal_follows_the_student_sensors():
    conds = build_conditions(["sensor_removal"], get_suite("quick"), ("joint_pos", "gravity"), 0)
    assert [c.value for c in conds] == ["none", "joint_pos", "gravity"]


def test_unknown_names():
    with pytest.raises(KeyError, match="unknown scenario 'bogus'.*token_removal"):
        get_scenario("bogus")
    with pytest.raises(KeyError, match="unknown suite 'huge'"):
        get_suite("huge")
