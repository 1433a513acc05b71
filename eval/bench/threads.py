"""msta-train's thread default against fixed thread counts, on an idle and a loaded machine:
``make bench-threads`` / ``python -m msta.eval.bench.threads``.

msta-train runs on one dataset (synthetic frames in every recorded column, the MSTA ``cpu``
preset, batch 64) with ``--num_threads=0`` (the default: the cores other work leaves free,
:mod:`msta.data.threads`) and with each fixed count from 1 to the usable cores (the highest
is what torch took before the default existed). Every run is a fresh command, so the
default reads the machine as a user's command would. The loaded state runs ``--load`` busy
processes (default: half the cores, at least 1) beside every run, as another user's job
would. Runs go round-robin over ``--rounds``; each setting keeps its best round. Samples/s is
for the batch, from msta-train's own timing after the first quarter of its steps.

The last line is ``default vs best: idle <r>, loaded <r>`` (the default's samples/s over the
best fixed count's in the same state).
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from msta.data.cli import parse_config
from msta.data.threads import usable_cores
from msta.eval.apps.train_scaling import measure
from msta.eval.bench.outputs import own_output
from msta.eval.bench.scale_train import make_dataset

#: the setting name of msta-train's default (``--num_threads=0``)
DEFAULT = "default"
STATES = ("idle", "loaded")
#: a process that keeps one core busy, as another job would
BUSY = "while True:\n    pass\n"


@dataclass
class BenchThreadsConfig:
    """Args:
        steps: msta-train steps of every run.
        batch_size: windows per step.
        preset: the MSTA preset trained.
        rounds: passes over every (state, setting); each keeps its best.
        episodes: synthetic episodes in the dataset.
        frames: frames per episode.
        load: busy processes in the loaded state (0: half the usable cores, at least 1).
        states: the machine states measured (idle, loaded).
        output_dir: the dataset, the runs and results.json.
    """

    steps: int = 120
    batch_size: int = 64
    preset: str = "cpu"
    rounds: int = 2
    episodes: int = 8
    frames: int = 200
    load: int = 0
    states: tuple[str, ...] = STATES
    output_dir: str = "outputs/bench_threads"

    def __post_init__(self) -> None:
        if self.steps < 8 or self.rounds < 1 or self.episodes < 2 or self.frames < 20:
            raise ValueError("steps must be >= 8, rounds >= 1, episodes >= 2, frames >= 20")
        if self.batch_size < 1 or not 0 <= self.load <= 4 * usable_cores():
            raise ValueError(f"batch_size must be >= 1 and load in [0, {4 * usable_cores()}]")
        self.states = tuple(self.states)
        if not self.states or set(self.states) - set(STATES):
            raise ValueError(f"states={self.states}: choose from {', '.join(STATES)}")


def settings() -> list[tuple[str, int]]:
    """(name, --num_threads) of every run: the default, then 1 .. the usable cores."""
    return [(DEFAULT, 0), *((f"{n} thread{'s' * (n > 1)}", n)
                            for n in range(1, usable_cores() + 1))]


@contextmanager
def machine_state(state: str, load: int) -> Iterator[None]:
    """``loaded``: ``load`` busy processes (half the cores when 0) run while inside."""
    if state == "idle":
        yield
        return
    n = load or max(1, usable_cores() // 2)
    procs = [subprocess.Popen([sys.executable, "-c", BUSY]) for _ in range(n)]
    try:
        time.sleep(2.0)  # they are running when the first run reads the machine
        yield
    finally:
        for p in procs:
            p.kill()
            p.wait()


def run(cfg: BenchThreadsConfig, out: Path) -> dict[str, Any]:
    """{state: {setting: best samples/s}} over every round, and the default's ratios."""
    dataset = make_dataset(out / "dataset", cfg.episodes, cfg.frames) \
        if not (out / "dataset").is_dir() else out / "dataset"
    best: dict[str, dict[str, float]] = {s: {} for s in cfg.states}
    for r in range(cfg.rounds):
        for state in cfg.states:
            with machine_state(state, cfg.load):
                for name, threads in settings():
                    rate = measure(dataset, out / state / f"t{threads}", 0, "cpu", threads,
                                   cfg.preset, cfg.steps, cfg.batch_size)
                    best[state][name] = max(best[state].get(name, 0.0), rate)
                    print(f"round {r + 1}/{cfg.rounds} {state:6s} {name:10s} {rate:8.1f} "
                          "samples/s", flush=True)
    ratios = {s: best[s][DEFAULT] / max(v for k, v in best[s].items() if k != DEFAULT)
              for s in cfg.states}
    return {"cores": usable_cores(), "steps": cfg.steps, "batch_size": cfg.batch_size,
            "preset": cfg.preset, "rounds": cfg.rounds, "samples_per_s": best,
            "default_vs_best": ratios}


def main(argv: list[str] | None = None) -> None:
    prog = "python -m msta.eval.bench.threads"
    cfg = parse_config(BenchThreadsConfig, argv, prog=prog)
    out = own_output(cfg.output_dir, prog, frozenset({"dataset", "results.json", *STATES}),
                     sign=frozenset(STATES))
    res = run(cfg, out)
    (out / "results.json").write_text(json.dumps(res, indent=1) + "\n")
    names = [n for n, _ in settings()]
    print(f"\n{res['cores']} usable cores; msta-train {cfg.preset} preset, batch "
          f"{cfg.batch_size}, {cfg.steps} steps, best of {cfg.rounds} round(s), samples/s:")
    print("| state | " + " | ".join(names) + " |\n|" + "---|" * (len(names) + 1))
    for state, row in res["samples_per_s"].items():
        print(f"| {state} | " + " | ".join(f"{row[n]:.0f}" for n in names) + " |")
    print("default vs best: " + ", ".join(f"{s} {r:.2f}"
                                          for s, r in res["default_vs_best"].items()))


if __name__ == "__main__":
    main()
