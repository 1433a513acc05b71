"""msta-export's spec.json holds the robot the student was trained on: its name and the
numbers of its action convention come from its description (``PolicyConfig.robots``);
``--robot`` picks one of several and gives a robot that is not shipped by its spec file."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from msta_test_helpers import tiny_msta, write_robot_spec  # registered by tests/conftest.py

from msta.data import robot as a1_constants
from msta.data.robot import RobotDescription, load_robot
from msta.policies.export_cli import main
from msta.policies.onnx_runtime import OnnxStudent

pytestmark = pytest.mark.usefixtures("one_thread")


def checkpoint(folder: Path, robots: tuple[str, ...]) -> Path:
    """A tiny MSTA student trained (as its config says) on ``robots``, saved in ``folder``."""
    return tiny_msta(3, robots=robots).save_pretrained(folder)


def export(ckpt: Path, out: Path, *extra: str) -> dict:
    main([f"--policy={ckpt}", f"--output_dir={out}", "--formats=onnx", "--parity_windows=0",
          "--random_windows=4", *extra])
    return json.loads((out / "spec.json").read_text())


def convention_of(described: RobotDescription) -> dict:
    return {"default_pose": [float(v) for v in described.default_pose],
            "joint_names": list(described.joints), "action_scale": described.action_scale,
            "clip_actions": described.clip_actions, "kp": described.kp, "kd": described.kd,
            "control_dt_s": described.control_dt}


def test_an_a1_student_exports_the_a1_numbers_as_before(tmp_path):
    spec = export(checkpoint(tmp_path / "ckpt", ("a1",)), tmp_path / "out")
    assert spec["robot"] == "a1"
    before = {"default_pose": [float(v) for v in a1_constants.DEFAULT_POSE],
              "joint_names": list(a1_constants.JOINT_NAMES),
              "action_scale": a1_constants.ACTION_SCALE,
              "clip_actions": a1_constants.CLIP_ACTIONS, "kp": a1_constants.KP,
              "kd": a1_constants.KD, "control_dt_s": a1_constants.CONTROL_DT}
    got = {k: spec["action_convention"][k] for k in before}
    assert json.dumps(got) == json.dumps(before)  # the same numbers, written the same way


def test_a_go1_student_exports_the_go1_numbers_and_the_runtime_reads_them(tmp_path):
    out = tmp_path / "out"
    spec = export(checkpoint(tmp_path / "ckpt", ("go1",)), out)
    go1 = load_robot("go1")
    assert spec["robot"] == "go1"
    assert {k: spec["action_convention"][k] for k in convention_of(go1)} == convention_of(go1)
    assert spec["action_convention"]["control_dt_s"] == pytest.approx(0.02)
    assert spec["action_convention"]["kp"] == 35.0  # not the A1's 30
    student = OnnxStudent(out)
    assert student.spec["robot"] == "go1"
    student.reset()
    action = student.step({n: np.zeros(student.dims[n], np.float32)
                           for n in student.sensors if n != "last_action"})
    assert action.shape == (12,) and np.isfinite(action).all()


def test_a_student_of_several_robots_needs_robot_to_pick_one(tmp_path, capsys):
    ckpt = checkpoint(tmp_path / "ckpt", ("a1", "go1"))
    with pytest.raises(SystemExit):
        export(ckpt, tmp_path / "none")
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "a1, go1" in err and "--robot" in err, err
    assert not (tmp_path / "none").exists()  # refused before anything is written
    spec = export(ckpt, tmp_path / "go1", "--robot=go1")
    assert spec["robot"] == "go1" and spec["action_convention"]["kp"] == load_robot("go1").kp
    capsys.readouterr()
    with pytest.raises(SystemExit):
        export(ckpt, tmp_path / "other", f"--robot={write_robot_spec(tmp_path, 'mybot')}")
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "'mybot'" in err and "--robot" in err, err


def test_a_robot_not_shipped_is_given_by_its_spec_file(tmp_path, capsys):
    spec_file = write_robot_spec(tmp_path, "mybot", base=load_robot("go1"))
    ckpt = checkpoint(tmp_path / "ckpt", ("mybot",))
    with pytest.raises(SystemExit):
        export(ckpt, tmp_path / "none")
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "'mybot'" in err and "spec file" in err, err
    spec = export(ckpt, tmp_path / "out", f"--robot={spec_file}")
    assert spec["robot"] == "mybot"
    assert spec["action_convention"]["default_pose"] == list(load_robot("go1").default_pose)
    capsys.readouterr()
    with pytest.raises(SystemExit):
        export(ckpt, tmp_path / "a1", "--robot=a1")
    assert "not 'a1'" in capsys.readouterr().err
