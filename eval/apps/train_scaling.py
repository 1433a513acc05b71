"""msta-train as a plain process or as a torchrun job, timed: the runs behind
``make bench-scale``'s training figures (eval/bench/scale_train.py) and ``make
device-check``'s torchrun row (eval/apps/device_check.py).

Every run is a fresh command of its own. Samples/s is for the global batch, from
msta-train's own timing of its training steps (no start-up, validation or checkpoint), after
the first quarter of the steps (their one-off costs left out).
"""

from __future__ import annotations

import csv
import os
import shutil
import subprocess
import sys
from pathlib import Path

#: msta-train flags of every run (besides dataset, output, preset, steps, batch, device).
TRAIN_FLAGS = ("--warmup_steps=10", "--eval_every=0", "--save_every=0", "--val_samples=64",
               "--progress=false")


def train_command(procs: int, dataset: Path, out: Path, preset: str, steps: int, batch: int,
                  device: str, threads: int) -> list[str]:
    """msta-train as a plain process (``procs`` = 0) or under torchrun with ``procs``."""
    launch = [sys.executable, "-m", "msta.train.offline"] if procs == 0 else [
        sys.executable, "-m", "torch.distributed.run", "--standalone",
        f"--nproc_per_node={procs}", "-m", "msta.train.offline"]
    return [*launch, f"--dataset={dataset}", f"--output_dir={out}", f"--policy.preset={preset}",
            f"--steps={steps}", f"--batch_size={batch}", f"--device={device}",
            f"--num_threads={threads}", f"--log_every={max(steps // 4, 1)}", *TRAIN_FLAGS]


def samples_per_s(run: Path, batch: int) -> float:
    """Training samples/s after the first logged step, from msta-train's cumulative figures:
    step k logged at c_k samples/s took k * batch / c_k seconds of training so far."""
    with open(run / "metrics.csv", newline="") as f:
        rows = [(int(r["step"]), float(r["samples_per_s"])) for r in csv.DictReader(f)
                if r.get("samples_per_s")]
    (k0, c0), (k1, c1) = rows[0], rows[-1]
    if k1 == k0:
        return c1
    return (k1 - k0) * batch / (k1 * batch / c1 - k0 * batch / c0)


def measure(dataset: Path, work: Path, procs: int, device: str, threads: int, preset: str,
            steps: int, batch: int) -> float:
    """One run's samples/s (``procs`` = 0: today's plain process) in ``work/run_<procs>``.

    Raises:
        RuntimeError: the run failed (its last stderr lines).
    """
    out = work / f"run_{procs}"
    shutil.rmtree(out, ignore_errors=True)
    env = {**os.environ, "OMP_NUM_THREADS": str(threads)}
    if not threads:  # msta-train's default decides (OMP_NUM_THREADS=0 means nothing)
        env.pop("OMP_NUM_THREADS")
    res = subprocess.run(train_command(procs, dataset, out, preset, steps, batch, device,
                                       threads), capture_output=True, text=True, env=env,
                         check=False)
    if res.returncode:
        raise RuntimeError(f"msta-train with {procs or 'no'} torchrun processes failed:\n"
                           f"{res.stderr[-3000:]}")
    return samples_per_s(out, batch)
