"""``make bench-startup`` measures every command and its reference in one run."""

from __future__ import annotations

import sys

from msta.eval.bench.startup import StartupConfig, commands, first_line, measure


def test_the_benchmark_times_every_command_and_the_first_line(tmp_path):
    best = measure(StartupConfig(rounds=1, output_dir=str(tmp_path / "bench")))
    assert set(commands()) <= set(best) and "msta-train" in best
    assert {"reference", "msta-train first line"} <= set(best)
    assert all(s > 0 for s in best.values())


def test_first_line_waits_for_a_line(tmp_path):
    """The clock stops at the first non-empty line, not at the process start."""
    slow = [sys.executable, "-c", "import time; print(); time.sleep(0.5); print('x')"]
    assert first_line(slow) >= 0.5
