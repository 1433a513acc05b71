"""msta-eval simulates ``--robot``, by default the robot its checkpoints were trained on, and
refuses a checkpoint trained on another robot in one line (docs/robots.md)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from msta_test_helpers import write_robot_spec  # registered by tests/conftest.py

from msta.eval.eval_config import EvalConfig
from msta.eval.evaluate import main
from msta.eval.evaluation import eval_robot, evaluate, load_entries
from msta.policies.teacher.config import TeacherConfig

TINY = {"scenarios": "token_removal", "trials": 1, "episode_length_s": 0.2, "terrains": "flat",
        "levels": "0", "num_envs": 1, "nthread": 1, "progress": False, "device": "cpu"}


def trained_on(ckpt: Path, folder: Path, *robots: str) -> Path:
    """A copy of the checkpoint ``ckpt`` whose config.json names ``robots``."""
    copy = shutil.copytree(ckpt, folder)
    config = json.loads((copy / "config.json").read_text())
    (copy / "config.json").write_text(json.dumps({**config, "robots": list(robots)}))
    return copy


def test_the_default_is_the_checkpoints_robot(tiny_ckpt, tmp_path):
    cfg = EvalConfig(policies=f"teacher,{tiny_ckpt}", output_dir=str(tmp_path), **TINY)
    assert eval_robot(cfg, load_entries(cfg)) == "a1"  # the tiny student is the A1's
    teachers = EvalConfig(policies="teacher", output_dir=str(tmp_path), **TINY)
    assert eval_robot(teachers, load_entries(teachers)) == "a1"


def test_a_checkpoint_of_another_robot_is_refused_in_one_line(tiny_ckpt, tmp_path, capsys):
    spec = write_robot_spec(tmp_path)  # the A1's spec named "other"
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as stop:
        main([f"--policies=teacher,{tiny_ckpt}", f"--robot={spec}", "--teacher.type=gait",
              f"--output_dir={out}",
              "--scenarios=token_removal", "--trials=1", "--episode_length_s=0.2",
              "--terrains=flat", "--levels=0", "--progress=false", "--device=cpu"])
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("msta-eval: error:"), err
    assert "'a1'" in err and "'other'" in err and "--robot" in err, err
    assert not out.exists()  # refused before anything is written


def test_a_checkpoint_of_another_robot_runs_on_it(tiny_ckpt, tmp_path):
    spec = write_robot_spec(tmp_path)
    other = trained_on(tiny_ckpt, tmp_path / "other_ckpt", "other")
    cfg = EvalConfig(policies=f"teacher,{other}", output_dir=str(tmp_path / "out"),
                     teacher=TeacherConfig(type="zero"), **TINY)
    with pytest.raises(ValueError, match=r"robot=other: unknown robot 'other'"):
        evaluate(cfg)  # its robot is not shipped: the spec file is needed
    metrics = evaluate(EvalConfig(**{**TINY, "policies": f"teacher,{other}",
                                     "output_dir": str(tmp_path / "out"), "robot": str(spec),
                                     "teacher": TeacherConfig(type="zero")}))
    assert metrics["config"]["robot"] == "other"
    assert {r["status"] for r in metrics["runs"]} == {"ok", "n/a"}


def test_checkpoints_of_different_robots_are_refused_without_robot(tiny_ckpt, tmp_path):
    other = trained_on(tiny_ckpt, tmp_path / "other_ckpt", "other")
    cfg = EvalConfig(policies=f"{tiny_ckpt},{other}", output_dir=str(tmp_path), **TINY)
    with pytest.raises(ValueError) as err:
        eval_robot(cfg, load_entries(cfg))
    msg = str(err.value)
    assert "\n" not in msg and "'a1'" in msg and "'other'" in msg and "--robot" in msg
