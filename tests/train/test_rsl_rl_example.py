"""docs/rsl_rl.md's example runs as written: a user's own rsl_rl configuration, msta's
``RslVecEnv`` and rsl_rl's ``OnPolicyRunner``, two PPO iterations on 16 robots, in a fresh
process in an empty folder (as a user would paste it)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import torch

DOC = Path(__file__).resolve().parents[2] / "docs" / "rsl_rl.md"


def example() -> str:
    """The python block under the doc's "A runnable example" heading."""
    text = DOC.read_text().split("## A runnable example", 1)[1]
    return re.search(r"```python\n(.*?)```", text, re.DOTALL).group(1)


def test_the_docs_rsl_rl_example_trains_and_saves(tmp_path):
    env = {**os.environ, "MUJOCO_GL": "egl"}
    run = subprocess.run([sys.executable, "-c", example()], cwd=tmp_path, env=env,
                         capture_output=True, text=True, timeout=600, check=False)
    assert run.returncode == 0, run.stderr[-3000:]
    out = run.stdout
    assert "Learning iteration 0/2" in out and "Learning iteration 1/2" in out
    assert "Total steps: 768" in out  # 2 iterations x 24 steps x 16 robots
    assert out.rstrip().splitlines()[-1] == "actions (16, 12)"
    run_dir = tmp_path / "outputs" / "rsl_rl_example"
    first, last = (torch.load(run_dir / f"model_{i}.pt", weights_only=True) for i in (0, 1))
    assert last["iter"] == 1
    # the second iteration's update moved the actor
    assert any(not torch.equal(first["actor_state_dict"][k], v)
               for k, v in last["actor_state_dict"].items())
    assert list(run_dir.glob("events.out.tfevents.*"))
