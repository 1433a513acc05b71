"""msta-export with a sensor guard: the removal inputs (absent_<sensor>) of every student hold
the parity check under random removal masks, a checkpoint's guard is copied and named in the
spec, an export without a guard is as before, and the torch-free ONNX loop runs the guard and
the student step for step as the Python guard and the eager student do on a recorded stream
with a stuck joint encoder injected."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from msta_test_helpers import record_gait, tiny_student  # registered by tests/conftest.py

import msta.policies.teacher.gait  # noqa: F401  (registers "gait")
from msta.collect.faults import FaultInjector, FaultSpec, std_from_stats
from msta.data.stats import load_stats
from msta.policies.export import export_student, random_windows, resolve_sensors
from msta.policies.export_cli import main
from msta.policies.export_removal import absent_masks
from msta.policies.guard import INPUT_SENSORS, GuardConfig
from msta.policies.guard_file import load_guard, save_guard
from msta.train.guard_data import load_episodes
from msta.train.guard_fit import fit_guard

REPO = Path(__file__).resolve().parents[2]
CASES = [("msta", {}), ("msta", {"state_tokens": 3}), ("msta", {"learnable_mask": True}),
         ("gru", {}), ("tert_mask", {}), ("rma_tcn", {}), ("mlp", {})]
IDS = [n + "".join(f"-{k}" for k in o) for n, o in CASES]
ONSET_S = 1.4  # after the guard's 1-s warm-up, so the repair starts from trusted readings
T = 5

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> Path:
    """Two 3-second gait-teacher episodes recorded in the real simulator."""
    return record_gait(tmp_path_factory.mktemp("export_guard_data") / "dataset", 2, 3.0)


@pytest.fixture(scope="module")
def checkpoint(recorded, tmp_path_factory) -> Path:
    """A tiny MSTA student saved with a guard fitted on the recorded episodes."""
    ckpt = student("msta", {}, recorded).save_pretrained(
        tmp_path_factory.mktemp("ckpt") / "ckpt")
    save_guard(fit_guard(recorded, cfg=GuardConfig(ridge=30.0)), ckpt)  # 300 steps: a firm fit
    return Path(ckpt)


student = tiny_student


@pytest.mark.parametrize(("name", "overrides"), CASES, ids=IDS)
def test_removal_inputs_hold_parity_under_random_masks(name, overrides, recorded, tmp_path):
    policy = student(name, overrides, recorded)
    Tn = policy.config.history
    names = resolve_sensors(policy, "all")
    absent = ("joint_pos", "joint_vel", "gravity")
    spec = export_student(policy, tmp_path, "all", Tn, absent=absent,
                          windows={"random": random_windows(policy, names, Tn, 16)})
    assert spec["parity_ok"] and spec["parity_max_abs_diff"] <= 1e-5
    assert all(p["absent"] == "random" for p in spec["parity"])
    assert [a["name"] for a in spec["absent_inputs"]] == [f"absent_{s}" for s in absent]
    # fresh windows and masks: both files answer as policy.act(absent=...) does, and the
    # masks change the action (the removal path is in the graph, not traced away)
    fresh = random_windows(policy, names, Tn, 6, seed=7)
    masks = absent_masks(absent, 6, seed=5)
    expect = policy.act({n: torch.from_numpy(fresh[n]) for n in names}, absent=masks).numpy()
    plain = policy.act({n: torch.from_numpy(fresh[n]) for n in names}).numpy()
    import onnxruntime as ort

    sess = ort.InferenceSession(str(tmp_path / "student.onnx"),
                                providers=["CPUExecutionProvider"])
    feed = {n: fresh[n] for n in names} | {f"absent_{s}": masks[s] for s in absent}
    got_onnx = sess.run(["action"], feed)[0]
    loaded = torch.jit.load(str(tmp_path / "student.pt"))
    got_ts = loaded(*(torch.from_numpy(fresh[n]) for n in names),
                    *(torch.from_numpy(masks[s]) for s in absent)).detach().numpy()
    assert np.abs(got_onnx - expect).max() <= 1e-5 and np.abs(got_ts - expect).max() <= 1e-5
    assert np.abs(expect[0] - plain[0]).max() == 0  # the first sample removes nothing
    assert np.abs(expect[1:] - plain[1:]).max() > 1e-3


def test_export_without_a_guard_is_unchanged_and_all_false_masks_are_the_plain_student(
        recorded, tmp_path):
    policy = student("msta", {}, recorded)
    names = resolve_sensors(policy, "all")
    windows = {"random": random_windows(policy, names, T, 8)}
    plain = export_student(policy, tmp_path / "plain", "all", T, windows=windows)
    assert "absent_inputs" not in plain and "guard" not in plain
    assert all("absent" not in p for p in plain["parity"])
    assert sorted(p.name for p in (tmp_path / "plain").iterdir()) == [
        "spec.json", "student.onnx", "student.pt"]
    export_student(policy, tmp_path / "removal", "all", T, windows=windows,
                   absent=("joint_pos",))
    import onnxruntime as ort

    fresh = random_windows(policy, names, T, 4, seed=9)
    a = ort.InferenceSession(str(tmp_path / "plain" / "student.onnx")).run(["action"], fresh)[0]
    none = {"absent_joint_pos": np.zeros((4, 12), bool)}
    b = ort.InferenceSession(str(tmp_path / "removal" / "student.onnx")).run(
        ["action"], fresh | none)[0]
    assert [i.name for i in ort.InferenceSession(
        str(tmp_path / "plain" / "student.onnx")).get_inputs()] == list(names)
    assert np.abs(a - b).max() <= 1e-5


def test_cli_copies_the_guard_and_rejects_bad_removal_inputs(checkpoint, recorded, tmp_path,
                                                             capsys):
    out = tmp_path / "export"
    main([f"--policy={checkpoint}", f"--output_dir={out}", f"--dataset={recorded}",
          f"--history={T}", "--parity_windows=16", "--random_windows=8"])
    printed = capsys.readouterr().out
    assert "with its guard" in printed and "random removal masks" in printed
    spec = json.loads((out / "spec.json").read_text())
    guard = load_guard(checkpoint)
    assert spec["guard"]["files"] == ["guard.json", "guard.safetensors"]
    assert spec["guard"]["reads"] == list(INPUT_SENSORS)
    assert [a["sensor"] for a in spec["absent_inputs"]] == [
        n for n in resolve_sensors(student("msta", {}, recorded), "all") if n in guard.sensors]
    assert (out / "guard.json").read_bytes() == (checkpoint / "guard.json").read_bytes()
    assert np.array_equal(load_guard(out).stats["threshold"], guard.stats["threshold"])
    main([f"--policy={checkpoint}", f"--output_dir={tmp_path / 'bare'}", f"--history={T}",
          "--absent_inputs=none", "--random_windows=4"])
    assert "guard is left out" in capsys.readouterr().err
    assert not (tmp_path / "bare" / "guard.json").exists()
    with pytest.raises(SystemExit):
        main([f"--policy={checkpoint}", f"--output_dir={tmp_path / 'x'}",
              "--absent_inputs=height_map"])
    assert "--absent_inputs" in capsys.readouterr().err


def eager_loop(policy, guard, stream: dict[str, np.ndarray], names) -> tuple[np.ndarray, ...]:
    """The Python guard and the eager student on ``stream`` ({sensor: (steps, dim)}): the
    same windows the ONNX loop builds, the guard's flags as ``absent`` (less the gravity
    vector it repairs, whose estimate the window holds instead)."""
    guard.reset()
    steps = len(stream["joint_pos"])
    actions, flags = [], []
    seen = {n: stream[n].copy() for n in names}
    for t in range(steps):
        obs = {s: stream[s][t][None] for s in INPUT_SENSORS}
        f = guard.update(obs)
        flags.append(np.concatenate([f[s][0] for s in guard.sensors]))
        fixed, f = guard.repair(obs)
        seen["gravity"][t] = fixed["gravity"][0]
        window = {n: np.concatenate([np.repeat(seen[n][:1], T, 0), seen[n][:t + 1]])[-T:]
                  for n in names}
        absent = {s: f[s] for s in guard.sensors if s in names}
        actions.append(policy.act({n: torch.from_numpy(w[None]) for n, w in window.items()},
                                  absent=absent)[0].numpy())
    return np.stack(actions), np.stack(flags)


@pytest.mark.parametrize("fault", ["stuck:0:encoder:3", "bias:3:gravity"])
def test_the_onnx_loop_runs_the_guard_as_python_does(fault, checkpoint, recorded, tmp_path):
    out = tmp_path / "export"
    main([f"--policy={checkpoint}", f"--output_dir={out}", f"--history={T}",
          "--random_windows=8", f"--dataset={recorded}", "--parity_windows=8"])
    episode = load_episodes(recorded, [1])
    steps = int(episode["length"][0])
    clean = {s: episode[s][:, :steps].astype(np.float32) for s in INPUT_SENSORS}  # (1, t, d)
    std = std_from_stats(load_stats(recorded), INPUT_SENSORS)
    inj = FaultInjector(FaultSpec.parse(f"{fault}/onset={ONSET_S}"), 1, std)
    faulty = [inj.apply({s: clean[s][:, t] for s in INPUT_SENSORS}) for t in range(steps)]
    stream = {s: np.concatenate([f[s] for f in faulty]).astype(np.float32)
              for s in INPUT_SENSORS}  # (steps, dim)
    policy = student("msta", {}, recorded)
    guard = load_guard(checkpoint)
    names = resolve_sensors(policy, "all")
    expect, expect_flags = eager_loop(policy, guard, stream, names)
    np.savez(tmp_path / "stream.npz", **stream)
    script = f"""
import sys
import numpy as np
sys.path.insert(0, {str(REPO)!r})
from msta.policies.onnx_runtime import OnnxStudent
stream = np.load({str(tmp_path / 'stream.npz')!r})
s = OnnxStudent({str(out)!r})
s.reset()
actions, flags = [], []
for t in range(len(stream["joint_pos"])):
    actions.append(s.step({{n: stream[n][t] for n in stream.files}}))
    flags.append(np.concatenate([s.flags[n] for n in s.guard.sensors]))
np.savez({str(tmp_path / 'got.npz')!r}, actions=np.stack(actions), flags=np.stack(flags))
print("torch" in sys.modules)
"""
    printed = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                             timeout=300, check=True).stdout.split()
    assert printed[-1] == "False"  # the robot loop runs without torch
    got = np.load(tmp_path / "got.npz")
    assert np.array_equal(got["flags"], expect_flags)
    assert np.abs(got["actions"] - expect).max() <= 1e-5
    onset = round(ONSET_S / 0.02)
    assert guard.sensors[:2] == ("joint_pos", "joint_vel")  # flags: q (12), q-dot (12), ...
    assert not expect_flags[:onset].any()  # quiet on the stream it was calibrated on
    if fault.endswith("encoder:3"):
        assert expect_flags[-1, 3] and expect_flags[-1, 12 + 3]  # q and q-dot of joint 3
    else:  # the gravity vector (flags: q, q-dot, gyro, gravity, ...), repaired
        assert expect_flags[-1, 27:30].all() and not expect_flags[-1, 24:27].any()
    # the guard's removal or repair changes the student's actions once it flags
    assert np.abs(expect[-1] - plain_last_action(policy, stream, names)).max() > 1e-4


def plain_last_action(policy, stream, names) -> np.ndarray:
    """The eager student's last action on ``stream`` without any removal."""
    t = len(stream["joint_pos"]) - 1
    window = {n: np.concatenate([np.repeat(stream[n][:1], T, 0), stream[n][:t + 1]])[-T:]
              for n in names}
    return policy.act({n: torch.from_numpy(w[None]) for n, w in window.items()})[0].numpy()
