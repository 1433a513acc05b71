"""msta.data.threads: each process computes with the cores other work leaves free."""

from __future__ import annotations

import subprocess
import sys
import threading
import time

import pytest

from msta.data import threads as T


def test_the_rule_shares_the_free_cores():
    assert T.auto_threads(processes=1, cores=8, busy=0.0) == 8
    assert T.auto_threads(processes=1, cores=2, busy=1.0) == 1      # another job: one left
    assert T.auto_threads(processes=1, cores=2, busy=2.6) == 1      # all busy: still one
    assert T.auto_threads(processes=2, cores=8, busy=0.4) == 4      # torchrun: shared
    assert T.auto_threads(processes=3, cores=8, busy=2.0) == 2
    assert T.auto_threads(processes=4, cores=2, busy=0.0) == 1


def test_busy_cores_count_the_other_work_on_this_processes_cpus():
    """A busy process beside this one is one busy core, on this process's own CPUs; this
    process's own work is not counted (the load average would still count finished work,
    and the whole host's)."""
    stat = ("cpu  9 9 9 9 9 9 9 9 0 0\ncpu0 10 0 10 80 0 0 0 0 0 0\n"
            "cpu1 50 0 50 0 0 0 0 0 0 0\ncpu2 0 0 0 100 0 0 0 0 0 0\n")
    assert T.cpu_times(stat, {0, 2}) == (20, 200) and T.cpu_times(stat, {1}) == (100, 100)
    busy = [subprocess.Popen([sys.executable, "-c", "while True:\n    pass\n"])]
    try:
        time.sleep(1.0)
        during = T.busy_cores(interval_s=0.3)
    finally:
        for p in busy:
            p.kill()
            p.wait()
    assert 0.6 <= during  # one core's worth, give or take the sampling
    stop = threading.Event()
    spin = threading.Thread(target=lambda: [None for _ in iter(stop.is_set, True)])
    spin.start()  # this process keeps one core busy: its own work, not other work
    try:
        own = T.busy_cores(interval_s=0.3)
    finally:
        stop.set()
        spin.join()
    assert own < 0.5, own


def test_torchruns_local_world_size_counts(monkeypatch):
    monkeypatch.setenv("LOCAL_WORLD_SIZE", "2")
    assert T.run_processes() == 2
    monkeypatch.setenv("LOCAL_WORLD_SIZE", "x")
    assert T.run_processes() == 1


def test_counts_are_checked_in_one_line():
    assert T.resolve_threads(3) == 3 and T.resolve_threads(0) >= 1
    for bad in (-1, T.max_threads() + 1, 100_000):
        with pytest.raises(ValueError, match=r"num_threads=-?\d+ must be in \[0, \d+\]"):
            T.resolve_threads(bad)


def test_msta_train_refuses_a_huge_thread_count_in_one_line(tmp_path):
    """(Was: --num_threads=100000 started thousands of threads.)"""
    res = subprocess.run([sys.executable, "-m", "msta.train.offline", "--dataset=x",
                          f"--output_dir={tmp_path / 'o'}", "--num_threads=100000"],
                         capture_output=True, text=True, timeout=120, check=False)
    err = res.stderr.strip()
    assert res.returncode == 2 and "\n" not in err and "num_threads=100000 must be in" in err


def test_a_resumed_run_keeps_the_thread_count_its_first_session_chose(tmp_path, monkeypatch):
    """--num_threads=0 follows the machine's load; a resume uses the first session's count
    again (sums in another order would break bit-identical resumes), a given count wins."""
    from msta.data import threads as T

    monkeypatch.setattr(T, "auto_threads", lambda processes=None: 2)
    assert T.run_threads(tmp_path, 0, resuming=False) == 2
    monkeypatch.setattr(T, "auto_threads", lambda processes=None: 1)  # the machine got busy
    assert T.run_threads(tmp_path, 0, resuming=True) == 2
    assert T.run_threads(tmp_path, 3, resuming=True) == 3
    assert T.run_threads(tmp_path / "new", 0, resuming=False) == 1
    (tmp_path / "threads.json").write_text('{"threads": 100000}')  # edited: not trusted
    assert T.run_threads(tmp_path, 0, resuming=True) == 1
