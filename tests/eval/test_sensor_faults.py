"""msta-eval's sensor_faults scenario: conditions, a closed-loop run, the oracle's removal."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from msta.collect.faults import FaultInjector, FaultSpec, FaultyActor, std_from_stats
from msta.collect.rollout import rollout
from msta.collect.sim.env import QuadrupedEnv
from msta.collect.sim.env_config import EnvConfig
from msta.data.sensors import STUDENT_SENSORS
from msta.eval.eval_config import EvalConfig
from msta.eval.evaluate import main
from msta.eval.evaluation import evaluate, load_entries
from msta.eval.scenarios import DEFAULT_FAULTS, FAULT_JOINT, build_conditions, get_suite
from msta.policies.actor import StudentActor
from msta.policies.factory import load_policy
from msta.policies.teacher.config import TeacherConfig

FAST = {"suite": "quick", "terrains": "flat", "levels": "0", "progress": False}
STUCK = "stuck:0:encoder:2/onset=0.1-0.3"


def test_default_sweep_is_every_type_on_three_targets():
    conds = build_conditions(["sensor_faults"], get_suite("quick"), STUDENT_SENSORS, 0)
    assert [c.label for c in conds[:2]] == ["none | unguarded", "none | guard"]
    faults = {c.value for c in conds[2:]}
    assert faults == set(DEFAULT_FAULTS) and len(faults) == 21
    assert {c.fault.type for c in conds[2:]} == {"stuck", "bias", "noise", "spikes", "dropout",
                                                 "drift", "scale"}
    assert {c.fault.target for c in conds[2:]} == {f"encoder:{FAULT_JOINT}",
                                                   f"joint_pos:{FAULT_JOINT}", "ang_vel"}
    for f in faults:
        assert [c.removal for c in conds if c.value == f] == ["unguarded", "oracle", "guard"]
    # a student that does not read ang_vel gets no ang_vel fault
    conds = build_conditions(["sensor_faults"], get_suite("quick"), ("joint_pos", "command"), 0)
    assert all("ang_vel" not in c.label and "encoder" in c.label or "joint_pos" in c.label
               for c in conds[2:])


def test_stuck_encoder_closed_loop_rows_and_records(tiny_ckpt, tmp_path):
    cfg = EvalConfig(policies=f"teacher,{tiny_ckpt}", scenarios="sensor_faults", faults=STUCK,
                     trials=2, episode_length_s=0.6, output_dir=str(tmp_path),
                     teacher=TeacherConfig(type="gait"), **FAST)
    metrics = evaluate(cfg)
    runs = {(r["policy"], r["condition"]): r for r in metrics["runs"]}
    name = tiny_ckpt.name
    # the teacher runs fault-free only; the student: fault-free, unguarded and oracle (no
    # guard saved with the tiny checkpoint: no guard rows)
    assert sorted(runs) == sorted([("teacher", "none | unguarded"),
                                   (name, "none | unguarded"),
                                   (name, f"{STUCK} | unguarded"), (name, f"{STUCK} | oracle")])
    assert all(r["status"] == "ok" for r in runs.values())
    assert metrics["config"]["faults"] == [STUCK]
    rec = runs[(name, f"{STUCK} | oracle")]
    assert rec["fault"]["spec"] == STUCK and rec["fault"]["type"] == "stuck"
    assert rec["fault"]["onset_s"] == [0.1, 0.3] and rec["fault_seed"]["seed"] == cfg.seed
    assert rec["removal"] == "oracle"
    det = rec["detection"]  # the oracle removes at onset, on every trial whose fault began
    assert det["faults_began"] >= 1 and det["detected"] == 1.0 and det["mean_delay_s"] == 0.0
    assert det["false_alarms_per_channel_step"] == 0.0
    unguarded = runs[(name, f"{STUCK} | unguarded")]
    assert "detection" not in unguarded and unguarded["removal"] == "unguarded"
    assert len({r["inputs"] for r in runs.values() if r["policy"] == name}) == 3
    saved = json.loads((tmp_path / "metrics.json").read_text())
    assert saved["runs"] == metrics["runs"]
    report = (tmp_path / "report.md").read_text()
    assert "## Sensor faults" in report and f"### `{STUCK}`" in report
    table = report.split(f"### `{STUCK}`")[1]
    assert f"| {name} | unguarded |" in table and f"| {name} | oracle | " in table
    # seeded: the same command gives the same figures
    again = evaluate(replace(cfg, output_dir=str(tmp_path / "again")))
    assert again["runs"] == metrics["runs"]


def _drive(policy, fault: str, oracle: bool, steps: int = 40):
    """A short closed loop (2 robots): actions per step and the actor's removal record."""
    env = QuadrupedEnv(EnvConfig(num_envs=2, nthread=1, seed=3))
    env.reset()
    spec = FaultSpec.parse(fault)
    std = std_from_stats(policy.processor.stats, policy.required_sensors)
    actor = FaultyActor(StudentActor(policy, 2), FaultInjector(spec, 2, std, seed=1),
                        oracle=oracle, record=True)
    actions: list[np.ndarray] = []

    def hook(step):
        actions.append(step.action.copy())

    rollout(env, actor, hook, max_steps=steps, reset_done=False)  # onsets stay put
    return np.stack(actions), actor


def test_oracle_student_input_lacks_the_faulty_channels(tiny_ckpt):
    """After onset the oracle removes joint 2's q and q-dot: whatever the fault writes into
    them (stuck, or a 100-std bias) the student's actions are the same, step for step."""
    policy = load_policy(tiny_ckpt)
    onset = "/onset=0.2-0.2"  # step 10
    a_stuck, actor = _drive(policy, f"stuck:0:encoder:2{onset}", oracle=True)
    a_bias, _ = _drive(policy, f"bias:100:encoder:2{onset}", oracle=True)
    np.testing.assert_array_equal(a_stuck, a_bias)
    for t, removed in enumerate(actor.removed):
        if t < 10:
            assert not any(m.any() for m in removed.values())
            continue
        assert set(removed) == {"joint_pos", "joint_vel"}
        for m in removed.values():
            assert m[:, 2].all() and not np.delete(m, 2, axis=1).any()
    # unguarded, the same two faults reach the student and change its actions after onset
    u_stuck, _ = _drive(policy, f"stuck:0:encoder:2{onset}", oracle=False)
    u_bias, _ = _drive(policy, f"bias:100:encoder:2{onset}", oracle=False)
    np.testing.assert_array_equal(u_stuck[:10], u_bias[:10])
    assert not np.allclose(u_stuck[10:], u_bias[10:])
    np.testing.assert_array_equal(u_stuck[:10], a_stuck[:10])  # before onset: no removal


def test_fault_options_are_one_line_errors(tiny_ckpt, tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        main([f"--policies={tiny_ckpt}", "--scenarios=sensor_faults", "--faults=bias:3:command",
              f"--output_dir={tmp_path}"])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert "physical sensor" in err and len(err.splitlines()) == 1
    with pytest.raises(ValueError, match="--faults needs --scenarios"):
        EvalConfig(policies=str(tiny_ckpt), scenarios="token_removal", faults=STUCK)
    cfg = EvalConfig(policies=str(tiny_ckpt), scenarios="sensor_faults",
                     faults="bias:3:joint_pos:3,7,noise:3:ang_vel", **FAST)
    assert cfg.fault_list == ["bias:3:joint_pos:3,7", "noise:3:ang_vel"]
    assert "faults" not in EvalConfig(policies=str(tiny_ckpt), **FAST).resolved()
    assert load_entries(cfg)[0].kind == "student"


def test_false_removals_count_only_each_trials_live_steps():
    """A trial whose episode ended after 2 steps counts its first 2 steps only: what a
    guard flags after the robot restarted elsewhere is not a false alarm of that trial."""
    from msta.eval.sensor_faults import live_false_removals

    by_step = np.array([[0, 1], [1, 1], [3, 1], [5, 1]])  # (steps, envs) false removals
    det = {"onset": np.zeros(2, dtype=int), "false_by_step": by_step,
           "channel_steps": np.array([4 * 34, 4 * 34])}  # 34 watched channels a step
    false, steps = live_false_removals([det], np.array([2, 4]))
    assert false == (0 + 1) + (1 + 1 + 1 + 1)
    assert steps == 34 * (2 + 4)


def test_a_damaged_guard_stops_only_the_guard_rows(tiny_ckpt, tmp_path, capsys):
    """A guard.json whose arrays file is damaged: a suite without guard rows runs as before;
    the sensor-fault suite (guard rows) is one line naming the file."""
    import shutil

    ckpt = tmp_path / "ckpt"
    shutil.copytree(tiny_ckpt, ckpt)
    (ckpt / "guard.json").write_text('{"format": 1}')
    (ckpt / "guard.safetensors").write_bytes(b"\x00" * 16)
    metrics = evaluate(EvalConfig(policies=str(ckpt), trials=1, episode_length_s=0.2,
                                  output_dir=str(tmp_path / "plain"), **FAST))
    assert metrics["runs"] and all(r["policy"] == "ckpt" for r in metrics["runs"])
    with pytest.raises(SystemExit) as e:
        main([f"--policies={ckpt}", "--scenarios=sensor_faults", f"--faults={STUCK}",
              f"--output_dir={tmp_path / 'faults'}", "--suite=quick", "--progress=false"])
    err = capsys.readouterr().err.strip()
    assert e.value.code == 2 and len(err.splitlines()) == 1
    assert f"{ckpt / 'guard.safetensors'}: not a readable safetensors file" in err
