"""msta-eval on Ray workers (a real local Ray of 2 CPUs): the same figures with 1 and 2
workers as in one process, for the teacher and a (masked) student; a block's own error
reaches the caller as itself."""

from __future__ import annotations

import json

import pytest
from msta_test_helpers import record_gait, tiny_student

from msta.collect import ray_pool
from msta.eval.eval_config import EvalConfig
from msta.eval.evaluation import evaluate


@pytest.fixture(scope="module")
def student(tmp_path_factory):
    base = tmp_path_factory.mktemp("student")
    root = record_gait(base / "ds", episodes=2, seconds=0.5)
    return tiny_student("msta", {}, root).save_pretrained(base / "msta_tiny")


def run(tmp_path, student, workers: int, progress: bool = False) -> dict:
    """Teacher and student, token removal 0 / 25 / 50 %: 4 trials in 2 rounds of 2."""
    out = tmp_path / f"w{workers}"
    cfg = EvalConfig(policies=f"teacher,{student}", scenarios="token_removal", trials=4,
                     num_envs=2, episode_length_s=0.5, terrains="flat,stairs_up", levels="1",
                     output_dir=str(out), progress=progress, workers=workers)
    evaluate(cfg)
    return json.loads((out / "metrics.json").read_text())


def test_one_and_two_workers_give_the_single_process_figures(local_ray, student, tmp_path,
                                                            capsys):
    here = run(tmp_path, student, 0)
    one, two = run(tmp_path, student, 1), run(tmp_path, student, 2, progress=True)
    bars = capsys.readouterr().err.replace("\r", "\n")
    assert "reference teacher (Ray): " in bars and "trial" in bars  # as one process shows
    assert [r["status"] for r in here["runs"]] == ["ok", "n/a", "n/a", "ok", "ok", "ok"]
    masked = [r["raw"]["per_terrain"]["average"]["total"] for r in here["runs"][3:]]
    assert len(set(masked)) == 3  # the masks change the student's figures
    assert one == here and two == here  # every figure, interval and count; the config too
    assert ray_pool.shared_pool(2).workers == 2


def test_a_block_error_reaches_the_caller_as_itself(local_ray):
    class Job:  # defined here: Ray ships it by value (the workers cannot import tests/)
        def __init__(self, fail: int = -1) -> None:
            self.fail = fail

        def setup(self):
            return None

        def run(self, state, block):
            if block == self.fail:
                raise ValueError(f"block {block} is bad")
            return block

    pool = ray_pool.shared_pool(2)
    with pytest.raises(ValueError, match="^block 1 is bad$"):
        pool.map(Job(fail=1), [0, 1, 2], lambda i, r: None)
    got = []
    pool.map(Job(), [5, 6, 7], lambda i, r: got.append(r))
    assert got == [5, 6, 7]  # the pool stays usable, results in block order


def test_workers_and_a_cuda_device_are_one_line_errors(tmp_path):
    with pytest.raises(ValueError, match="needs --workers=0"):
        EvalConfig(output_dir=str(tmp_path), workers=1, device="cuda")
    with pytest.raises(ValueError, match="needs --workers >= 1"):
        EvalConfig(output_dir=str(tmp_path), ray_address="auto")
