"""msta-compare under torchrun (2 CPU processes, gloo): rank 0 rolls out, appends and
evaluates once, every rank trains; stage 1 gives the single process's student, and stage 2
appends one round once. (The round's episodes are not byte-identical to the single
process's: a student whose weights differ by float rounding drives the simulator onto
another path; docs/scale.md.)"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import torch
from msta_test_helpers import record_gait  # registered by tests/conftest.py
from safetensors.torch import load_file

from msta.data.features import load_info
from msta.eval.apps.compare import main

REPO = Path(__file__).resolve().parents[3]
TINY = ["--policies=msta", "--preset=tiny", "--stage1_steps=10", "--stage2_rounds=1",
        "--stage2_steps=5", "--episodes_per_round=2", "--stage2_episode_length_s=0.3",
        "--stage2_num_envs=2", "--batch_size=8", "--trials=2", "--eval_terrains=flat",
        "--eval_episode_length_s=0.5", "--teacher.type=gait", "--progress=false",
        "--num_threads=1"]


def test_compare_under_torchrun_trains_the_single_process_student(tmp_path):
    root = record_gait(tmp_path / "teacher", 3, 0.4)
    main([f"--dataset={root}", f"--output_dir={tmp_path / 'one'}", *TINY])
    res = subprocess.run(
        [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=2",
         "-m", "msta.eval.apps.compare", f"--dataset={root}", f"--output_dir={tmp_path / 'two'}",
         *TINY], cwd=REPO, capture_output=True, text=True, timeout=300, check=False,
        env={**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1"})
    assert res.returncode == 0, res.stderr[-3000:]
    assert res.stdout.count("round 1: appended 2 student episodes") == 1  # rank 0 alone
    one, two = tmp_path / "one", tmp_path / "two"
    for out in (one, two):
        assert load_info(out / "runs/msta/dataset")["total_episodes"] == 3 + 2
        assert (out / "checkpoints/msta/model.safetensors").is_file()
    a = load_file(str(one / "runs/msta/stage1/final/model.safetensors"))
    b = load_file(str(two / "runs/msta/stage1/final/model.safetensors"))
    for name, value in a.items():
        if not name.endswith("attn.qkv.bias"):  # why: tests/train/test_ddp.py
            torch.testing.assert_close(value, b[name], rtol=1e-5, atol=1e-5, msg=name)
    assert (two / "comparison.md").is_file()
