"""A robot of the user's own, named by no shipped file, through the whole pipeline: msta-collect
(the gait teacher) -> msta-train (stage 1) -> msta-correct (one round) -> msta-eval, each by
its command's entry point (docs/robots.md). The robot is the Go1's description under another
name, with its MJCF by absolute path: no foot-contact switches (the teachers read the
simulator's contacts), joint torques and an accelerometer instead."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
from msta_test_helpers import write_robot_spec  # registered by tests/conftest.py

from msta.collect.record import main as collect_main
from msta.data.msta_json import dataset_robot
from msta.data.robot import load_robot
from msta.eval.evaluate import main as eval_main
from msta.policies.factory import load_config
from msta.train.offline import main as train_main
from msta.train.online import main as correct_main

#: The student reads what the robot offers: no foot_contact, its torques and accelerometer
#: (extension sensors, named because no default student reads them; the defaults alone would
#: train too, without foot_contact: tests/train/test_robots.py).
INPUTS = "[joint_pos,joint_vel,ang_vel,gravity,command,last_action,joint_torque,base_accel]"
FLAT = ["--env.terrain.types=[flat]", "--env.terrain.num_levels=1",
        "--env.terrain.max_init_level=0", "--env.nthread=1"]


def test_a_robot_of_ones_own_runs_collect_train_correct_and_eval(tmp_path: Path, monkeypatch):
    monkeypatch.setenv("CUBLAS_WORKSPACE_CONFIG", ":4096:8")  # msta-eval's setting, undone after
    spec = write_robot_spec(tmp_path, "mybot", base=load_robot("go1"))
    robot = load_robot(spec)
    assert "foot_contact" not in robot.sensors and Path(robot.mjcf).is_absolute()
    ds, run, corr, ev = (tmp_path / d for d in ("ds", "run", "corr", "eval"))

    collect_main(["--teacher.type=gait", "--episodes=4", "--num_envs=4", "--episode_length_s=0.5",
                  f"--env.robot={spec}", *FLAT, "--progress=false", f"--root={ds}",
                  "--repo_id=local/mybot", "--extra_sensors=joint_torque,base_accel"])
    features = json.loads((ds / "meta/info.json").read_text())["features"]
    assert dataset_robot(ds) == "mybot"
    assert "observation.foot_contact" not in features
    assert {"observation.joint_torque", "observation.base_accel", "privileged.height_scan"} <= set(
        features)
    frames = pd.read_parquet(next((ds / "data").rglob("*.parquet")))
    assert len(frames) == 4 * 25 and np.isfinite(np.stack(frames["action"])).all()
    assert np.stack(frames["observation.joint_torque"]).std() > 0  # the motors really worked

    train_main([f"--dataset={ds}", f"--output_dir={run}", "--policy.preset=tiny",
                "--policy.history=3", f"--policy.input_sensors={INPUTS}", "--steps=2",
                "--batch_size=8", "--warmup_steps=1", "--progress=false", "--device=cpu",
                "--val_fraction=0"])
    assert load_config(run / "final").robots == ("mybot",)
    assert "foot_contact" not in load_config(run / "final").input_sensors

    correct_main([f"--policy.path={run / 'final'}", f"--dataset={ds}", f"--output_dir={corr}",
                  f"--env.robot={spec}", *FLAT, "--teacher.type=gait", "--steps=1",
                  "--progress=false", "--device=cpu", "--eval.enabled=false", "--rounds=1",
                  "--episodes_per_round=2", "--num_envs=2", "--episode_length_s=0.2",
                  "--keep_unfinished=false"])
    assert load_config(corr / "round_1").robots == ("mybot",)
    assert json.loads((ds / "meta/info.json").read_text())["total_episodes"] == 6

    eval_main([f"--policies={corr / 'round_1'}", f"--robot={spec}", "--teacher.type=gait",
               "--trials=2", "--terrains=flat", "--levels=0", "--episode_length_s=0.5",
               "--num_envs=2", "--nthread=1", f"--output_dir={ev}", "--progress=false",
               "--scenarios=token_removal"])
    metrics = json.loads((ev / "metrics.json").read_text())
    assert metrics["config"]["robot"] == "mybot"  # named by the spec's name
    reference = metrics["reference"]["per_terrain"]["flat"]
    assert reference["trials"] == 2 and reference["survival"] == 1.0  # the gait teacher stands
    ok = [r for r in metrics["runs"] if r["status"] == "ok"]
    assert ok and all(math.isfinite(r["raw"]["per_terrain"]["flat"][k])
                      for r in ok for k in ("lin_tracking", "total", "survival", "vel_err"))
