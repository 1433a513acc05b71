"""``make device-check`` at tiny scale on the CPU: every stage runs and reports its figures."""

import json

from msta.eval.apps.device_check import DeviceCheckConfig, run


def test_device_check_runs_every_stage_on_the_cpu_and_says_so(tmp_path):
    out = tmp_path / "check"
    figs = run(DeviceCheckConfig(output_dir=str(out), scale="tiny", device="cpu",
                                 num_threads=1))
    saved = json.loads((out / "device_check.json").read_text())
    assert saved == json.loads(json.dumps(figs))
    assert saved["device"] == "cpu" and saved["machine"]["cpu_cores"] >= 1
    assert saved["stage1_samples_per_s"]["cpu"] > 0
    assert saved["parity"] == {"compared": False, "why": "no CUDA device: CPU only"}
    assert saved["stage2"]["rollout"]["env_steps_per_s"] > 0
    assert saved["stage2"]["train"]["train_samples_per_s"] > 0
    assert set(saved["eval"]) == {"mask 0", "mask 0.25", "mask 0.5"}
    assert all(0.0 <= r["survival"] <= 1.0 and r["trials"] == 2 for r in saved["eval"].values())
    assert set(saved["seconds"]) == {"dataset", "stage 1 on cpu", "stage 2 on cpu", "eval on cpu",
                                     "torchrun training"}
    (name, row), = saved["torchrun"].items()  # no CUDA: the CPU's 2 gloo processes alone
    assert name.startswith("cpu: torchrun 2 x") and name.endswith("(gloo)")
    assert row["processes"] == 2 and row["samples_per_s"] > 0
    assert row["per_process"] == row["samples_per_s"] / 2
    assert row["vs_single_process"] == row["samples_per_s"] / row["single_process_samples_per_s"]


def test_device_check_refuses_an_unknown_scale():
    import pytest

    with pytest.raises(ValueError, match="scale='huge'"):
        DeviceCheckConfig(scale="huge")
