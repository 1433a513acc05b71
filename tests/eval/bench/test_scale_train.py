"""make bench-scale's training half at a tiny budget: today's single process, the same on
one core and a 2-process torchrun job are timed, and the report ends with the ratio."""

from __future__ import annotations

import re

import pytest

from msta.eval.bench.scale_train import TODAY, ScaleTrainConfig, report, run


def test_bench_scale_train_times_one_and_two_processes(tmp_path):
    cfg = ScaleTrainConfig(steps=8, batch_size=8, preset="tiny", procs=(2,), rounds=1,
                           episodes=3, frames=40, output_dir=str(tmp_path))
    figs = run(cfg)
    assert next(iter(figs)) == TODAY and figs[TODAY]["vs_today"] == 1.0
    (name, two), = [(k, v) for k, v in figs.items() if k.startswith("torchrun")]
    assert two["procs"] == 2 and two["samples_per_s"] > 0
    assert two["per_process"] == two["samples_per_s"] / 2
    assert two["vs_today"] == two["samples_per_s"] / figs[TODAY]["samples_per_s"]
    for r in ("run_0", "run_2"):  # msta-train's own outputs: the runs did train
        assert (tmp_path / r / "final" / "model.safetensors").is_file()
    last = report(cfg, figs).splitlines()[-1]
    assert re.fullmatch(rf"{re.escape(name)} vs 1 process: \d+\.\d\d", last)


def test_bench_scale_train_refuses_a_batch_that_does_not_split():
    with pytest.raises(ValueError, match="batch_size=9 does not split over 2 processes"):
        ScaleTrainConfig(batch_size=9)
