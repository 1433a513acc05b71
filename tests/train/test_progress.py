"""progress.json as typed records (train/correct_progress.py) and the one training mask-ratio rule
(train/config.py): files of the earlier dict layout read back and write out unchanged."""

from __future__ import annotations

import json
from dataclasses import replace

import draccus
import pytest

from msta.collect.sim.env_config import ControlConfig
from msta.policies.checkpoint import PolicyPath
from msta.train.config import STAGE2_MASK_RATIO, training_mask_ratio
from msta.train.correct_config import CorrectConfig
from msta.train.correct_progress import (
    PROGRESS_FORMAT,
    CorrectProgress,
    RoundRecord,
    load_progress,
)

#: progress.json as msta-correct wrote it before the typed records (a run killed in round 2,
#: with a key this version does not know at both levels).
OLD = {
    "format": PROGRESS_FORMAT,
    "config": {"rounds": 2, "policy": {"path": "ckpt"}},
    "dataset": "/data/ds",
    "rounds": {
        "0": {"evaluated": True, "checkpoint": "ckpt", "episodes_after": 4,
              "policy_revision": "msta-abc", "eval": {"0": {"status": "ok"}},
              "eval_config": {"trials": 4}},
        "1": {"episodes_before": 0, "policy_revision": "msta-abc", "episodes_rolled_out": 8,
              "appended": True, "episodes_after": 12, "rollout": {"frames": 100.0},
              "train": {"windows": 90, "val_loss": 0.5}, "trained": True,
              "checkpoint": "out/round_1", "trained_revision": "msta-def", "evaluated": True,
              "pushed": {"repo": "a/b", "tag": "stage2-r1"}, "from_a_later_version": 1},
        "2": {"episodes_before": 12, "policy_revision": "msta-def"},
    },
    "rollout_max_init_level": 2,
    "teacher_revision": "gait-123",
    "teacher_eval": {"per_terrain": {}},
    "note": "kept",
}


def test_an_old_progress_file_reads_as_records_and_writes_back_the_same(tmp_path):
    prog = CorrectProgress.from_json(json.loads(json.dumps(OLD)), tmp_path / "progress.json")
    assert sorted(prog.rounds) == [0, 1, 2]
    r1, r2 = prog.rounds[1], prog.rounds[2]
    assert r1.appended and r1.trained and r1.train["windows"] == 90
    assert r1.extra == {"from_a_later_version": 1} and prog.extra == {"note": "kept"}
    assert not r2.appended and r2.episodes_before == 12 and r2.episodes_rolled_out is None
    assert prog.rollout_max_init_level == 2 and prog.dataset_source is None
    prog.save()
    assert json.loads((tmp_path / "progress.json").read_text()) == OLD


def test_a_record_leaves_out_what_is_still_at_its_default():
    rec = RoundRecord(episodes_before=0, policy_revision="x")
    assert rec.to_json() == {"episodes_before": 0, "policy_revision": "x"}  # 0 is kept
    rec.appended, rec.recovered_after_commit = True, False
    assert "recovered_after_commit" not in rec.to_json() and rec.to_json()["appended"] is True
    prog = CorrectProgress(config={}, dataset="d")
    assert prog.round(3) is prog.round(3) and prog.to_json()["rounds"] == {"3": {}}
    with pytest.raises(ValueError, match="no path"):
        prog.save()


@pytest.mark.parametrize(("requested", "config", "stage", "expected"), [
    (None, 0.75, 1, 0.75), (0.25, 0.75, 1, 0.25),   # stage 1: the config's, or --mask_ratio
    (None, 0.75, 2, STAGE2_MASK_RATIO),              # stage 2: 0.5 ...
    (None, 0.25, 2, 0.25), (None, 0.0, 2, 0.0),      # ... capped at the stage-1 ratio
    (0.75, 0.0, 2, 0.75),                            # --mask_ratio always wins
])
def test_one_rule_decides_the_training_mask_ratio(requested, config, stage, expected):
    assert training_mask_ratio(requested, config, stage) == expected


def test_a_run_from_before_env_robot_resumes_on_the_numbers_in_force(tmp_path):
    """progress.json written before ``--env.robot``: no robot (the A1) and every control
    number written out; the same numbers resume, other ones do not."""
    cfg = CorrectConfig(policy=PolicyPath("ckpt"), dataset="ds", output_dir=str(tmp_path),
                        resume=True)
    old = draccus.encode(cfg)
    old["env"] = {k: v for k, v in old["env"].items() if k != "robot"} | {
        "control": draccus.encode(cfg.env.resolved())["control"]}

    def resume(config: CorrectConfig) -> None:
        (tmp_path / "progress.json").write_text(json.dumps(
            {"format": PROGRESS_FORMAT, "config": old, "dataset": "ds", "rounds": {}}))
        load_progress(tmp_path, config, tmp_path)

    resume(cfg)
    old["env"]["control"]["kp"] = 25.0
    with pytest.raises(ValueError, match=r"different \['env'\]"):
        resume(cfg)
    resume(replace(cfg, env=replace(cfg.env, control=ControlConfig(kp=25.0))))
