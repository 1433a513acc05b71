"""The demo pipeline end to end at a tiny size (the real `make demo` only changes sizes)."""

from __future__ import annotations

import json
import re

import numpy as np
import pandas as pd
import pytest
from msta_test_helpers import write_robot_spec  # registered by conftest.py

from msta.data import sensors
from msta.eval.apps.demo import DemoConfig, main
from msta.policies.teacher.config import SHIPPED_ROBOT_RMA, TeacherConfig


@pytest.mark.parametrize("teacher,select", [("gait", 5), ("rma", 0)])
def test_demo_runs_every_stage_at_tiny_size(tmp_path, capsys, teacher, select):
    """gait with the round selection; rma (the default) as make demo runs it: DART noise,
    no selection (the last round is evaluated)."""
    out = tmp_path / "demo"
    main([f"--output_dir={out}", "--episodes=4", "--episode_length_s=0.5", "--train_steps=3",
          "--rounds=1", "--correct_steps=2", "--correct_episodes=2", "--teacher_seconds=0.4",
          "--envs_per_type=1", "--eval_trials=5", "--eval_episode_length_s=0.3",
          "--num_threads=1", f"--select_trials={select}", "--select_episode_length_s=0.3",
          f"--teacher.type={teacher}", "--history=3",
          f"--action_noise={0.5 if teacher == 'rma' else 0.0}"])
    text = capsys.readouterr().out
    assert f"== 1. the {teacher} teacher" in text
    # the one teacher records, labels the stage-2 round and is the evaluation's reference
    episodes = pd.concat(pd.read_parquet(f) for f in sorted(
        (out / "stage2" / "dataset" / "meta" / "episodes").rglob("*.parquet")))
    recorded = episodes[episodes["provenance/source"] == "teacher"]["provenance/policy"]
    assert set(recorded) == {teacher}
    reference = json.loads((out / "eval" / "metrics.json").read_text())["reference"]["revision"]
    assert reference.startswith(f"{teacher}-")
    for step in range(1, 7):
        assert f"== {step}." in text
    # the last line is the verdict; three training steps do not make a walking student
    last = text.strip().splitlines()[-1]
    assert last.startswith("VERDICT: the student does NOT walk yet") and "test mask 0" in last
    assert (out / "verdict.txt").read_text().strip() == last
    info = json.loads((out / "datasets" / "a1_teacher" / "meta" / "info.json").read_text())
    assert info["total_episodes"] == 4              # the teacher dataset pushed to the hub
    # stage 2 started from the hub dataset and appended its round to its own copy
    info = json.loads((out / "stage2" / "dataset" / "meta" / "info.json").read_text())
    assert info["total_episodes"] >= 4 + 2  # every simulated frame: falls add episodes
    assert (out / "stage1" / "final" / "model.safetensors").is_file()
    assert json.loads((out / "stage1" / "final" / "config.json").read_text())["history"] == 3
    if select:  # the round picked on the selection trials (seed 1) is pulled and evaluated
        sel = re.search(r"selection \(.*seed 1;.*: round 0 (\S+), round 1 (\S+); evaluating "
                        r"round (\d)", text)
        assert sel, text[-3000:]
        best = int(sel.group(3))
        assert best == (1 if float(sel.group(2)) >= float(sel.group(1)) else 0)
    else:  # no round evaluation at all; the last round is evaluated
        assert "evaluating the last round, 1" in text
        assert not json.loads((out / "stage2" / "progress.json").read_text())["rounds"][
            "1"].get("eval")
        best = 1
    # DART: the recording teacher's executed actions carry the noise, its labels do not
    teacher_eps = pd.concat(pd.read_parquet(f) for f in sorted(
        (out / "datasets" / "a1_teacher" / "data").rglob("*.parquet")))
    moved = np.abs(np.stack(teacher_eps["executed_action"]) - np.stack(teacher_eps["action"]))
    assert (moved.max() > 0.1) == (teacher == "rma")
    tag = "stage2-r1" if best else "stage1"
    assert (out / "pulled" / tag / "model.safetensors").is_file()
    assert last.endswith(f"(checkpoint {tag})")
    # stage 1 trained at 0.75, stage 2 retrained at the demo's --correct_mask_ratio (the
    # paper's 0.5), and each checkpoint says which: config.json keeps the stage-1 ratio, the
    # round's training.json the one it retrained at
    assert json.loads((out / "stage1" / "final" / "config.json").read_text())["mask_ratio"] == 0.75
    assert json.loads((out / "stage2" / "round_1" / "config.json").read_text())[
        "mask_ratio"] == 0.75
    assert json.loads((out / "stage2" / "round_1" / "training.json").read_text())[
        "mask_ratio"] == 0.5
    assert "DAgger beta 0" in text
    # by default half of the stage-2 robots drive with half of the tokens removed
    progress = json.loads((out / "stage2" / "progress.json").read_text())
    assert progress["config"]["rollout_mask_ratios"] == [0.0, 0.5]
    assert "test-time mask 0 / 0.5 over its robots" in text
    metrics = json.loads((out / "eval" / "metrics.json").read_text())
    assert metrics
    assert f"demo/msta_a1@{tag}" in text
    assert "demo-secret-token" not in text


def _metrics(lin0: float, lin50: float, surv: float) -> dict:
    def run(mask: float, lin: float) -> dict:
        return {"policy": "student", "scenario": "token_removal", "status": "ok",
                "spec": {"mask_ratio": mask},
                "normalized": {"per_terrain": {"average": {
                    "lin_tracking": lin, "ci": {"lin_tracking": [lin - 0.05, lin + 0.05]}}}},
                "raw": {"per_terrain": {"average": {"survival": surv, "trials": 100}}}}
    teacher = {"policy": "teacher", "scenario": "token_removal", "status": "ok"}
    return {"runs": [teacher, run(0.0, lin0), run(0.25, 0.0), run(0.5, lin50)]}


def test_verdict_applies_the_walking_bar():
    from msta.eval.apps.demo import verdict

    walks, line = verdict(_metrics(0.85, 0.78, 0.95))
    assert walks and line.startswith("VERDICT: the student WALKS")
    assert "0.85 [0.80, 0.90]" in line and "0.78" in line and "100 trials" in line
    for bad in (_metrics(0.79, 0.78, 0.95), _metrics(0.85, 0.74, 0.95),
                _metrics(0.85, 0.78, 0.89)):
        walks, line = verdict(bad)
        assert not walks and "does NOT walk yet" in line
    walks, line = verdict({"runs": []})
    assert not walks and "evaluation failed" in line


def test_demo_runs_on_another_robot(tmp_path, capsys):
    """--robot=go1: every step simulates the Go1 (its gait controller records, labels and
    is the reference), and the datasets, models and evaluation name and record it."""
    out = tmp_path / "demo"
    main([f"--output_dir={out}", "--robot=go1", "--teacher.type=gait", "--episodes=3",
          "--episode_length_s=0.5", "--train_steps=2", "--rounds=1", "--correct_steps=2",
          "--correct_episodes=2", "--teacher_seconds=0.4", "--envs_per_type=1",
          "--eval_trials=5", "--eval_episode_length_s=0.3", "--num_threads=1",
          "--history=2", "--action_noise=0", "--extra_inputs=joint_torque,base_accel",
          "--correct_type_weights=[0,0,0,1,0,0]"])
    text = capsys.readouterr().out
    assert "robot=go1  teacher=gait" in text and "robot=a1" not in text  # step 1 walks the Go1
    meta = json.loads((out / "datasets" / "go1_teacher" / "meta" / "msta.json").read_text())
    assert meta["robot"] == "go1"
    for ckpt in (out / "stage1" / "final", out / "stage2" / "round_1"):
        config = json.loads((ckpt / "config.json").read_text())
        assert config["robots"] == ["go1"]
        # the Go1 has no contact switches; it reads its torques and accelerometer too
        assert config["input_sensors"] == [s for s in sensors.STUDENT_SENSORS
                                           if s != "foot_contact"] + ["joint_torque", "base_accel"]
    info = json.loads((out / "stage2" / "dataset" / "meta" / "info.json").read_text())
    assert {"observation.joint_torque", "observation.base_accel"} <= set(info["features"])
    assert "demo/msta_go1@stage2-r1" in text and "dataset  demo/go1_teacher  commit" in text
    assert json.loads((out / "eval" / "metrics.json").read_text())["config"]["robot"] == "go1"
    # --correct_type_weights reaches the stage-2 rollouts: every round episode on stairs up
    progress = json.loads((out / "stage2" / "progress.json").read_text())
    assert progress["config"]["env"]["type_weights"] == [0, 0, 0, 1, 0, 0]
    episodes = pd.concat(pd.read_parquet(f) for f in sorted(
        (out / "stage2" / "dataset" / "meta" / "episodes").rglob("*.parquet")))
    student = episodes[episodes["provenance/source"] != "teacher"]
    assert len(student) and set(student["provenance/terrain"]) == {"stairs_up"}


def test_demo_takes_the_robots_own_teacher(tmp_path, capsys):
    """The Go1 takes its shipped teacher in place of the A1's; a robot msta ships no teacher
    for is refused in one line with the A1's, before anything is written."""
    go1 = DemoConfig(robot="go1")
    assert go1.teacher == TeacherConfig(type="rma", path=str(SHIPPED_ROBOT_RMA["go1"]))
    assert "robot go1 takes its shipped teacher rma (go1_ppo)" in capsys.readouterr().out
    assert DemoConfig(robot="go1", teacher=TeacherConfig(type="gait")).teacher.type == "gait"
    assert DemoConfig().teacher == TeacherConfig()  # the A1: rma_ppo
    for extra in ("height_map", "joint_torque,true_contact"):  # not offered; privileged
        with pytest.raises(ValueError, match=f"extra_inputs={extra}: the robot go1 offers "
                           "base_accel, joint_torque beyond the paper's"):
            DemoConfig(robot="go1", extra_inputs=extra)
    (tmp_path / "mine").mkdir()
    spec = write_robot_spec(tmp_path / "mine", name="mine")
    with pytest.raises(SystemExit):
        main([f"--output_dir={tmp_path / 'demo'}", f"--robot={spec}"])
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert f"robot={spec}: the teacher" in err and "rma_ppo was trained on the A1" in err
    assert not (tmp_path / "demo").exists()


def test_bad_correct_type_weights_are_one_line(capsys):
    with pytest.raises(SystemExit):
        main(["--correct_type_weights=[1,2]"])
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "correct_type_weights: type_weights (1.0, 2.0) must have one weight per terrain" in err
