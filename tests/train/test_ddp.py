"""Training on several processes (train/ddp.py): real torchrun jobs of 2 CPU
processes (gloo) on a tiny MSTA student reach the single process's weights with the same
global batch, and resume after rank 0 is killed and after --max_minutes stops them; the
token-removal draws give every window its single-process mask for every student type."""

from __future__ import annotations

import csv
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from msta_test_helpers import tiny_student  # registered by tests/conftest.py
from safetensors.torch import load_file

from msta.data.windows import WindowDataset
from msta.policies.registry import registered_policies
from msta.train.cli import parse_cli
from msta.train.ddp import ShardedDraws
from msta.train.offline import main
from msta.train.stage1 import train
from msta.train.train_config import TrainConfig

REPO = Path(__file__).resolve().parents[2]
STEPS = 20
FLAGS = ["--policy.preset=tiny", "--policy.input_sensors=[command,joint_pos,gravity]",
         "--policy.history=5", "--batch_size=16", "--warmup_steps=2", "--progress=false",
         "--device=cpu", f"--steps={STEPS}", "--save_every=5", "--eval_every=10",
         "--log_every=5"]


def torchrun(*args: str, nproc: int = 2) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone",
           f"--nproc_per_node={nproc}", *args]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    return subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=300,
                          check=False)


def weights(run: Path) -> dict[str, torch.Tensor]:
    return load_file(str(run / "final" / "model.safetensors"))


def assert_same_weights(a: dict[str, torch.Tensor], b: dict[str, torch.Tensor]) -> None:
    """Equal to float rounding. The attention's key bias is left out: softmax does not
    depend on it, so its gradient is 0 in exact arithmetic and Adam turns the rounding
    noise of that 0 into lr-sized steps whose signs differ with any change in summation
    order (docs/scale.md)."""
    assert a.keys() == b.keys()
    for name, value in a.items():
        x, y = value.float(), b[name].float()
        if name.endswith("attn.qkv.bias"):
            d = x.numel() // 3
            x, y = torch.cat([x[:d], x[2 * d:]]), torch.cat([y[:d], y[2 * d:]])
        torch.testing.assert_close(x, y, rtol=1e-5, atol=1e-5, msg=name)


def losses(run: Path) -> list[float]:
    with open(run / "metrics.csv", newline="") as f:
        return [float(r["loss"]) for r in csv.DictReader(f)]


@pytest.fixture(scope="module")
def one_process(synthetic_dataset, tmp_path_factory) -> Path:
    """The reference: a plain process (no torchrun variables), as msta-train runs today."""
    out = tmp_path_factory.mktemp("ddp") / "one"
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # as each torchrun process (OMP_NUM_THREADS=1)
    try:
        train(parse_cli(TrainConfig, [f"--dataset={synthetic_dataset}", f"--output_dir={out}",
                                      *FLAGS], prog="msta-train"))
    finally:
        torch.set_num_threads(threads)
    return out


@pytest.fixture(scope="module")
def two_processes(synthetic_dataset, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("ddp") / "two"
    res = torchrun("-m", "msta.train.offline", f"--dataset={synthetic_dataset}",
                   f"--output_dir={out}", *FLAGS)
    assert res.returncode == 0, res.stderr[-3000:]
    (out / "stdout.txt").write_text(res.stdout)
    return out


def test_two_processes_reach_the_single_process_weights(one_process, two_processes):
    assert_same_weights(weights(one_process), weights(two_processes))
    np.testing.assert_allclose(losses(two_processes), losses(one_process), rtol=1e-4)
    assert len(losses(one_process)) == STEPS // 5
    # the closing line's train loss is metrics.csv's last one (the ranks' mean, not rank 0's)
    printed = (two_processes / "stdout.txt").read_text()
    assert f"train loss {losses(two_processes)[-1]:.4g}" in printed, printed[-500:]
    ckpts = sorted(p.name for p in (two_processes / "checkpoints").iterdir())
    assert ckpts == ["000005", "000010", "000015", "000020", "last"]


def test_resume_under_torchrun_after_a_kill_and_a_time_limit(synthetic_dataset, tmp_path, one_process,
                                                      two_processes):
    out = tmp_path / "killed"
    args = [f"--dataset={synthetic_dataset}", f"--output_dir={out}", *FLAGS]
    res = torchrun(str(REPO / "tests/train/ddp_kill_worker.py"), "12", *args)
    assert res.returncode != 0 and "SIGKILL" in res.stderr, res.stderr[-3000:]
    assert (out / "checkpoints" / "last").resolve().name == "000010"
    assert not (out / "final").exists()
    # resumed with a time limit: every rank stops after the first step, rank 0 saves it
    res = torchrun("-m", "msta.train.offline", "--resume=true", "--max_minutes=0.0001", *args)
    assert res.returncode != 0 and "--max_minutes reached" in res.stdout, res.stderr[-3000:]
    assert "(exitcode: 75)" in res.stderr
    assert (out / "checkpoints" / "last").resolve().name == "000011"
    res = torchrun("-m", "msta.train.offline", "--resume=true", *args)  # the same command, resumed
    assert res.returncode == 0, res.stderr[-3000:]
    assert (out / "checkpoints" / "last").resolve().name == "000020"
    # resumed at step 10 and at 11, the job equals the uninterrupted ones
    resumed = weights(out)
    for name, a in weights(two_processes).items():
        assert torch.equal(a, resumed[name]), name
    assert_same_weights(weights(one_process), resumed)
    assert losses(out) == losses(two_processes)


@pytest.mark.parametrize("name", registered_policies())
def test_every_window_gets_its_single_process_mask(synthetic_dataset, name):
    """Two ranks' shards of a batch, each under ShardedDraws, give the loss of the whole
    batch in one process and leave the mask generator where the single process leaves it;
    drawn by each rank for its own shard instead, rank 1's masks (and loss) differ."""
    policy = tiny_student(name, {}, synthetic_dataset).train()
    ds = WindowDataset(synthetic_dataset, policy.required_sensors, policy.config.history,
                       extra_columns=(policy.config.action_key,))
    batch = ds.get_batch(np.random.default_rng(0).permutation(len(ds))[:16])
    halves = [{k: v[r * 8:(r + 1) * 8] for k, v in batch.items()} for r in range(2)]
    kw = {"mask_ratio": 0.5, **({"dummy_tokens": 3} if policy.supports_dummy_tokens else {})}

    def gen() -> torch.Generator:
        return torch.Generator().manual_seed(7)

    with torch.no_grad():
        g = gen()
        whole = policy.loss(batch, generator=g, **kw)[0]
        parts = []
        for r in range(2):
            gr = gen()
            with ShardedDraws(gr, r, 2, 8):
                parts.append(policy.loss(halves[r], generator=gr, **kw)[0])
            assert torch.equal(gr.get_state(), g.get_state())
        plain = policy.loss(halves[1], generator=gen(), **kw)[0]  # rank 1's own draws
    torch.testing.assert_close(sum(parts) / 2, whole, rtol=1e-5, atol=1e-7)
    assert abs(float(plain - parts[1])) > 1e-6


def test_a_batch_that_does_not_split_is_refused(synthetic_dataset, tmp_path, monkeypatch):
    monkeypatch.setenv("RANK", "0")
    monkeypatch.setenv("WORLD_SIZE", "3")
    monkeypatch.setenv("LOCAL_RANK", "0")
    with pytest.raises(SystemExit, match="batch_size=16 does not split over 3 processes"):
        main([f"--dataset={synthetic_dataset}", f"--output_dir={tmp_path / 'o'}", *FLAGS])
    assert not (tmp_path / "o").exists()


def test_torchrun_variables_left_in_a_shell_end_in_one_line_not_a_wait(synthetic_dataset,
                                                                       tmp_path):
    """RANK / WORLD_SIZE / LOCAL_RANK / MASTER_ADDR / MASTER_PORT of a job that is gone:
    msta-train says what it waits for, then stops with one line when the others never come
    (it waited 7 days)."""
    import socket
    import time

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    env = {**os.environ, "RANK": "0", "WORLD_SIZE": "2", "LOCAL_RANK": "0",
           "MASTER_ADDR": "127.0.0.1", "MASTER_PORT": str(port),
           "MSTA_DDP_JOIN_TIMEOUT_S": "3"}
    start = time.monotonic()
    proc = subprocess.run([sys.executable, "-m", "msta.train.offline",
                           f"--dataset={synthetic_dataset}", f"--output_dir={tmp_path / 'o'}",
                           *FLAGS], cwd=REPO, env=env, capture_output=True, text=True,
                          timeout=120, check=False)
    assert proc.returncode != 0 and time.monotonic() - start < 60
    lines = proc.stderr.strip().splitlines()
    assert "torchrun job of 2 processes (RANK=0 WORLD_SIZE=2" in proc.stderr
    assert "waiting up to 3 s for the other ranks" in proc.stderr
    assert lines[-1].startswith("msta-train: error: the torchrun job did not form within 3 s")
    assert "unset them to train in one process" in lines[-1]
    assert "Traceback" not in proc.stderr


def test_a_bad_join_timeout_is_one_line(synthetic_dataset, tmp_path, monkeypatch):
    for name, value in (("RANK", "0"), ("WORLD_SIZE", "2"), ("LOCAL_RANK", "0"),
                        ("MSTA_DDP_JOIN_TIMEOUT_S", "nan")):
        monkeypatch.setenv(name, value)
    with pytest.raises(SystemExit, match=r"MSTA_DDP_JOIN_TIMEOUT_S='nan' must be seconds in"):
        main([f"--dataset={synthetic_dataset}", f"--output_dir={tmp_path / 'o'}", *FLAGS])


def test_after_the_job_forms_a_rank_waits_longer_than_the_join_limit():
    """The join is bounded (MSTA_DDP_JOIN_TIMEOUT_S); the wait for rank 0's next loop is
    not: rank 1 waits 5 s for rank 0 under a 2 s join limit."""
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=2",
           str(REPO / "tests/train/ddp_slow_rank0.py")]
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MSTA_DDP_JOIN_TIMEOUT_S": "2"}
    res = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=300,
                         check=False)
    assert res.returncode == 0, res.stderr[-3000:]
    assert "rank 0: done" in res.stdout and "rank 1: done" in res.stdout
