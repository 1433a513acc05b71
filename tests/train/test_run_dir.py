"""Issue 15 (8, 9): one msta-train per --output_dir, and a run killed before its first
checkpoint starts again cleanly (with or without --resume)."""

from __future__ import annotations

import csv
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file

from train.cli import parse_cli
from train.offline import TrainConfig, main, train

REPO = Path(__file__).resolve().parents[2]
FAST = ["--policy.preset=tiny", "--policy.input_sensors=[command,joint_pos,gravity]",
        "--policy.history=5", "--batch_size=16", "--warmup_steps=2", "--progress=false",
        "--device=cpu", "--num_threads=1"]


def cfg_for(dataset: Path, out: Path, *extra: str) -> TrainConfig:
    return parse_cli(TrainConfig, [f"--dataset={dataset}", f"--output_dir={out}", *FAST, *extra],
                     prog="msta-train")


def _wait_for(path: Path, proc: subprocess.Popen, timeout: float = 120.0) -> None:
    end = time.monotonic() + timeout
    while not path.exists():
        assert proc.poll() is None, f"the first run exited with {proc.returncode}"
        assert time.monotonic() < end, f"{path} did not appear"
        time.sleep(0.1)


def test_a_second_run_on_the_same_output_dir_is_refused(synthetic_dataset, tmp_path):
    out = tmp_path / "run"
    first = subprocess.Popen(
        [sys.executable, "-m", "train.offline", f"--dataset={synthetic_dataset}",
         f"--output_dir={out}", *FAST, "--steps=100000", "--save_every=5", "--eval_every=0"],
        cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        env={**os.environ, "OMP_NUM_THREADS": "1"})
    try:
        _wait_for(out / "checkpoints" / "last", first)
        config = (out / "train_config.json").read_bytes()
        for extra in ([], ["--resume=true"]):
            with pytest.raises(SystemExit) as err:
                main([f"--dataset={synthetic_dataset}", f"--output_dir={out}", *FAST,
                      "--steps=3", *extra])
            assert f"another msta-train run (pid {first.pid}) holds" in str(err.value)
        assert (out / "train_config.json").read_bytes() == config
        assert first.poll() is None  # the first run is undisturbed
    finally:
        first.send_signal(signal.SIGKILL)
        first.wait(timeout=30)
    # the kill released the lock: the run resumes from its last checkpoint
    step = int((out / "checkpoints" / "last").resolve().name)
    train(cfg_for(synthetic_dataset, out, f"--steps={step + 2}", "--save_every=5",
                  "--eval_every=0", "--resume=true"))
    assert (out / "checkpoints" / "last").resolve().name == f"{step + 2:06d}"


class Crash(RuntimeError):
    pass


def _crash_at_2(step: int, metrics: dict) -> None:
    if step == 2:
        raise Crash


@pytest.mark.parametrize("resume", [False, True])
def test_a_run_killed_before_its_first_checkpoint_restarts_cleanly(synthetic_dataset, tmp_path,
                                                                   resume, capsys):
    args = ("--steps=4", "--save_every=0", "--eval_every=0", "--log_every=1")
    ref = train(cfg_for(synthetic_dataset, tmp_path / "ref", *args))
    out = tmp_path / "run"
    with pytest.raises(Crash):
        train(cfg_for(synthetic_dataset, out, *args), on_step=_crash_at_2)
    assert not (out / "checkpoints" / "last").exists() and (out / "metrics.csv").exists()
    final = train(cfg_for(synthetic_dataset, out, *args, f"--resume={str(resume).lower()}"))
    assert "killed before its first checkpoint; starting it again" in capsys.readouterr().out
    a, b = load_file(str(ref / "model.safetensors")), load_file(str(final / "model.safetensors"))
    assert all(torch.equal(a[k], b[k]) for k in a)  # the same run as one never interrupted
    with open(out / "metrics.csv", newline="") as f:
        assert [int(r["step"]) for r in csv.DictReader(f)] == [1, 2, 3, 4]
    assert len(list((out / "tensorboard").iterdir())) == 1
