"""msta-export: every student to TorchScript and ONNX, parity with the eager model on recorded
and random windows (full and minimized sensor sets), the torch-free runtime, the CLI."""

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
from msta.policies.baselines import BASELINES, REFERENCES
from msta.policies.export import export_student, random_windows, recorded_windows, resolve_sensors
from msta.policies.export_cli import main
from msta.policies.export_files import ExportParityError
from msta.policies.input_spec import MINIMIZED_SENSORS

REPO = Path(__file__).resolve().parents[2]
#: MSTA (the paper's single <S>, more readout tokens, the learnable-mask variant, per-step
#: attention, axial attention, sensor tokens) and every baseline and reference learner
CASES = [("msta", {}), ("msta", {"state_tokens": 3}), ("msta", {"learnable_mask": True}),
         ("msta", {"attention": "step", "num_layers": 2, "state_tokens": 2}),
         ("msta", {"attention": "axial", "num_layers": 3, "state_tokens": 2}),
         ("msta", {"tokens": "sensor"})] + [
    (name, {}) for name in BASELINES + REFERENCES]
IDS = [n + "".join(f"-{v}" if isinstance(v, str) else f"-{k}" for k, v in o.items())
       for n, o in CASES]
FIXED_T = ("rma_tcn", "mlp")  # learners that only run at their training window length

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> Path:
    """Two short gait-teacher episodes recorded in the real simulator."""
    return record_gait(tmp_path_factory.mktemp("export_data") / "dataset", 2, 1.0)



student = tiny_student


@pytest.mark.parametrize("which", ["all", "minimized"])
@pytest.mark.parametrize(("name", "overrides"), CASES, ids=IDS)
def test_export_matches_the_eager_student(name, overrides, which, recorded, tmp_path):
    policy = student(name, overrides, recorded)
    names = resolve_sensors(policy, which)
    T = policy.config.history if (which == "all" or name in FIXED_T) else 7
    windows = {"recorded": recorded_windows(recorded, names, T, 32),
               "random": random_windows(policy, names, T, 16)}
    spec = export_student(policy, tmp_path, which, T, windows=windows)

    assert not policy.training  # the export leaves the student as it found it (eval mode)
    assert spec["parity_ok"] and spec["parity_max_abs_diff"] <= 1e-5
    assert {(p["format"], p["windows"]) for p in spec["parity"]} == {
        (f, w) for f in ("torchscript", "onnx") for w in ("recorded", "random")}
    assert [i["name"] for i in spec["inputs"]] == list(names)
    assert spec["history"] == T and spec["policy_type"] == name
    if which == "minimized":
        assert set(names) == set(MINIMIZED_SENSORS)
    # the TorchScript file answers fresh windows (another batch size) as policy.act does
    fresh = random_windows(policy, names, T, 5, seed=7)
    expect = policy.act({n: torch.from_numpy(fresh[n]) for n in names})
    loaded = torch.jit.load(str(tmp_path / "student.pt"))
    got = loaded(*(torch.from_numpy(fresh[n]) for n in names))
    assert torch.allclose(got, expect, atol=1e-5, rtol=0)
    assert expect.std(0).max() > 1e-3  # a student whose actions depend on its inputs


def test_a_tolerance_the_export_cannot_meet_fails_loudly(recorded, tmp_path):
    policy = student("msta", {}, recorded)
    with pytest.raises(ExportParityError, match="tolerance"):
        export_student(policy, tmp_path, tolerance=1e-12,
                       windows={"random": random_windows(policy, policy.required_sensors, 15, 16)})
    spec = json.loads((tmp_path / "spec.json").read_text())
    assert spec["parity_ok"] is False and spec["parity_max_abs_diff"] > 1e-12


def test_the_onnx_runtime_walks_a_window_without_torch(recorded, tmp_path):
    """OnnxStudent (numpy + onnxruntime only) keeps the window, fills it with the first
    reading, feeds its own action back as last_action, and acts as the eager student does."""
    policy = student("msta", {"state_tokens": 2}, recorded)
    export_student(policy, tmp_path / "export", "all", 5)
    names = resolve_sensors(policy, "all")
    steps = 4
    readings = random_windows(policy, names, steps, 1, seed=3)  # {name: (1, steps, dim)}
    # the eager student on the windows the runtime should build
    expected, last = [], np.zeros(12, np.float32)
    for t in range(steps):
        window = {}
        for n in names:
            seq = readings[n][0].copy()
            if n == "last_action":
                seq[t] = last
                readings[n][0, t] = last
            first = np.repeat(seq[:1], 5, 0)
            window[n] = torch.from_numpy(np.concatenate([first, seq[:t + 1]])[-5:][None])
        last = policy.act(window)[0].numpy()
        expected.append(last)
    np.savez(tmp_path / "case.npz", expected=np.stack(expected),
             **{n: readings[n][0] for n in names if n != "last_action"})
    script = f"""
import sys
import numpy as np
sys.path.insert(0, {str(REPO)!r})
from msta.policies.onnx_runtime import OnnxStudent
case = np.load({str(tmp_path / 'case.npz')!r})
s = OnnxStudent({str(tmp_path / 'export')!r})
s.reset()
got = [s.step({{n: case[n][t] for n in s.sensors if n != "last_action"}}) for t in range(4)]
print(float(np.abs(np.stack(got) - case["expected"]).max()))
print("torch" in sys.modules)
"""
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                         timeout=300, check=True).stdout.split()
    assert float(out[0]) <= 1e-5
    assert out[1] == "False"


def test_cli_exports_a_checkpoint_and_rejects_bad_input(recorded, tmp_path, capsys):
    ckpt = student("gru", {}, recorded).save_pretrained(tmp_path / "ckpt")
    main([f"--policy={ckpt}", f"--output_dir={tmp_path / 'out'}", f"--dataset={recorded}",
          "--sensors=minimized", "--parity_windows=16", "--random_windows=8"])
    printed = capsys.readouterr().out
    assert "parity ok" in printed and "recorded windows" in printed
    spec = json.loads((tmp_path / "out" / "spec.json").read_text())
    assert spec["history"] == 7 and spec["source"]["dataset"] == str(recorded)
    assert (tmp_path / "out" / "student.onnx").stat().st_size > 0
    with pytest.raises(SystemExit):
        main([f"--policy={ckpt}", "--sensors=joint_pos,base_height"])
    assert "base_height" in capsys.readouterr().err
