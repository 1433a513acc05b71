"""Issue 15 (8, 9): one msta-train per --output_dir, and a run killed before its first
checkpoint starts again cleanly (with or without --resume). Issue 41 (13): a resume
refuses a tampered training state (a step that is not an integer in [0, --steps]) and a
``checkpoints/last`` that leads to another run."""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file

from msta.train.cli import parse_cli
from msta.train.offline import main
from msta.train.stage1 import train
from msta.train.train_config import TrainConfig

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
        [sys.executable, "-m", "msta.train.offline", f"--dataset={synthetic_dataset}",
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


# ----- issue 41 (13): the resume state is checked ------------------------------------------
@pytest.fixture(scope="module")
def finished(synthetic_dataset, tmp_path_factory) -> Path:
    """A run of 3 steps with its checkpoint 000003 (read-only: tests resume copies)."""
    out = tmp_path_factory.mktemp("finished") / "run"
    train(cfg_for(synthetic_dataset, out, "--steps=3", "--save_every=3", "--eval_every=0"))
    return out


def _resume_fails(dataset: Path, out: Path, steps: int = 6) -> str:
    """Resume the run in ``out``: it must end in one line naming the problem, with nothing
    trained or logged."""
    ckpts, metrics = sorted(p.name for p in (out / "checkpoints").iterdir()), \
        (out / "metrics.csv").read_bytes()
    with pytest.raises(SystemExit) as err:
        main([f"--dataset={dataset}", f"--output_dir={out}", *FAST, f"--steps={steps}",
              "--save_every=3", "--eval_every=0", "--resume=true"])
    message = str(err.value)
    assert message.startswith("msta-train: error: ") and "\n" not in message, message
    assert sorted(p.name for p in (out / "checkpoints").iterdir()) == ckpts
    assert (out / "metrics.csv").read_bytes() == metrics
    return message


@pytest.mark.parametrize("step", [1e12, 10**12, -1, "3", 2])
def test_a_tampered_resume_step_is_refused(synthetic_dataset, finished, tmp_path, step):
    out = tmp_path / "run"
    shutil.copytree(finished, out, symlinks=True)
    path = out / "checkpoints" / "000003" / "training_state" / "training_step.json"
    info = json.loads(path.read_text())
    info["step"] = step
    path.write_text(json.dumps(info))
    assert str(path) in _resume_fails(synthetic_dataset, out)


def test_a_resume_with_fewer_steps_than_done_says_how_many(synthetic_dataset, finished,
                                                            tmp_path):
    out = tmp_path / "run"
    shutil.copytree(finished, out, symlinks=True)
    assert "step 3 is beyond --steps=2; give --steps=3 or more" in _resume_fails(
        synthetic_dataset, out, steps=2)


@pytest.mark.parametrize("spelling", ["absolute", "relative"])
def test_a_last_pointer_to_another_run_is_refused(synthetic_dataset, finished, tmp_path,
                                                  spelling):
    out = tmp_path / "run"
    shutil.copytree(finished, out, symlinks=True)
    last = out / "checkpoints" / "last"
    stranger = finished / "checkpoints" / "000003"  # another run's checkpoint
    last.unlink()
    last.symlink_to(stranger if spelling == "absolute"
                    else os.path.relpath(stranger, last.parent))
    assert last.resolve() == stranger.resolve()
    assert "outside this run's checkpoints" in _resume_fails(synthetic_dataset, out)
