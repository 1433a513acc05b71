"""msta.eval.label_check: the teacher-takeover check of stage 2's labels."""

from __future__ import annotations

import pytest
from msta_test_helpers import tiny_msta  # registered by tests/conftest.py

from msta.data.sensors import STUDENT_SENSORS
from msta.eval.label_check import LabelCheckConfig, label_check, main, render
from msta.policies.checkpoint import PolicyPath
from msta.policies.teacher.config import TeacherConfig


def test_rows_share_robots_and_the_teacher_is_the_reference(tiny_ckpt, capsys):
    cfg = LabelCheckConfig(policy=PolicyPath(str(tiny_ckpt)), num_envs=3, student_seconds=0.2,
                           episode_length_s=0.4, max_level=0,
                           teacher=TeacherConfig(type="gait"))  # has follow_robot
    rows = label_check(cfg)
    assert list(rows) == ["teacher", "student", "takeover shadow", "takeover follow",
                          "takeover reset"]
    assert rows["teacher"]["lin_tracking"] == pytest.approx(1.0)
    assert all(r["robots"] == 3 and 0.0 <= r["survival"] <= 1.0 for r in rows.values())
    lo, hi = rows["student"]["survival_ci"]
    assert lo <= rows["student"]["survival"] <= hi
    # the takeovers differ from the student alone: the teacher drove their last 0.2 s
    assert rows["takeover shadow"]["lin_tracking"] != rows["student"]["lin_tracking"]
    table = render(rows)
    assert table.count("\n") == 6 and "| takeover follow | 3 |" in table


def test_the_command_line_prints_the_table(tiny_ckpt, capsys):
    main([f"--policy.path={tiny_ckpt}", "--teacher.type=zero", "--num_envs=2",
          "--student_seconds=0.04", "--episode_length_s=0.1", "--max_level=0"])
    out = capsys.readouterr().out
    assert "| takeover reset | 2 |" in out
    assert "takeover follow" not in out  # the zero teacher has no follow_robot: row skipped


@pytest.mark.parametrize("args, message", [
    (["--policy.path=/no/such/ckpt"], "--policy.path '/no/such/ckpt': no such checkpoint"),
    ([], "--policy.path is required"),
    (["--policy=x"], "--policy is a group of options; give --policy.path=..."),
    (["--student_seconds=5", "--episode_length_s=3"],
     "need 0 < student_seconds < episode_length_s"),
    (["--num_envs=0"], "num_envs=0 must be >= 1"),
    (["--teacher.type=nope"], "unknown teacher type 'nope'"),
])
def test_clear_errors(args, message, tiny_ckpt, capsys):
    argv = args if not args or args[0].startswith("--policy") else [
        f"--policy.path={tiny_ckpt}", *args]
    with pytest.raises(SystemExit) as exc:
        main(argv)
    err = capsys.readouterr().err
    assert exc.value.code == 2 and message in err and len(err.strip().splitlines()) == 1, err


def test_robot_runs_the_env_and_the_teacher_on_that_robot(tmp_path, capsys):
    """--robot=go1 simulates the Go1 and builds the teacher for it (the gait controller reads
    the simulator's contacts there); a student trained on another robot is refused."""
    no_contacts = tuple(s for s in STUDENT_SENSORS if s != "foot_contact")
    go1_ckpt = tiny_msta(3, robots=("go1",), input_sensors=no_contacts).save_pretrained(
        tmp_path / "go1")
    cfg = LabelCheckConfig(policy=PolicyPath(str(go1_ckpt)), robot="go1", num_envs=2,
                           student_seconds=0.04, episode_length_s=0.1, max_level=0,
                           teacher=TeacherConfig(type="gait"))
    rows = label_check(cfg)
    assert rows["teacher"]["lin_tracking"] == pytest.approx(1.0)
    assert all(r["robots"] == 2 for r in rows.values()) and "takeover follow" in rows
    with pytest.raises(SystemExit):  # an A1 student on the Go1
        main([f"--policy.path={tiny_msta(3).save_pretrained(tmp_path / 'a1')}", "--robot=go1"])
    err = capsys.readouterr().err
    assert "trained on robot 'a1', not 'go1' (--robot)" in err and len(err.strip().splitlines()) == 1
    with pytest.raises(SystemExit):
        main([f"--policy.path={go1_ckpt}", "--robot=b2"])
    assert "robot=b2: unknown robot 'b2'" in capsys.readouterr().err
