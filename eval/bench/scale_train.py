"""Training samples/s at 1 and 2 processes: ``python -m msta.eval.bench.scale_train``.

msta-train on one dataset (synthetic frames in every recorded column, the MSTA ``cpu``
preset, batch 64, mask 0.75) as it runs today (one process on every core), the same on one
core, and under torchrun (:mod:`msta.train.ddp`): 1 process, and 2 processes with half of
the cores each. Every run is a fresh command of its own; runs go round-robin and each ratio
is the median over rounds of the ratio within a round, so a neighbour's burst of CPU use
hurts every configuration alike. Samples/s is for the global batch, from msta-train's own
timing of its training steps after the first quarter of them
(:mod:`msta.eval.apps.train_scaling`).

The last line is ``torchrun 2 x <t> threads vs 1 process: <ratio>`` (2-process samples/s
over today's single process on the same cores). ``--device=cuda`` runs one process per GPU
(NCCL; ``--procs`` up to the GPU count).
"""

from __future__ import annotations

import os
import shutil
import statistics
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from msta.data.cli import parse_config
from msta.data.writer import DatasetWriter
from msta.eval.apps.train_scaling import measure
from msta.eval.bench.data import PROVENANCE, make_episodes
from msta.eval.bench.outputs import own_output
from msta.train.ddp import check_batch

#: today's run: one plain process on every core (the reference of every ratio)
TODAY = "1 process (today)"


@dataclass
class ScaleTrainConfig:
    """Args:
        steps: optimizer steps of every run (samples/s is measured over the last 3/4).
        batch_size: the global batch (windows per step, for any number of processes).
        preset: MSTA preset (cpu, paper, tiny).
        procs: process counts run under torchrun (each with cores / N threads on the CPU).
        rounds: round-robin repetitions: samples/s of the best round, ratios to today's run
            as the median of the rounds' (each round's runs close in time).
        episodes: synthetic episodes in the dataset.
        frames: frames per episode.
        device: cpu, or cuda (one process per GPU).
        output_dir: where the dataset and runs go (empty: a temporary folder, removed).
    """

    steps: int = 24
    batch_size: int = 64
    preset: str = "cpu"
    procs: tuple[int, ...] = (1, 2)
    rounds: int = 3
    episodes: int = 20
    frames: int = 500
    device: str = "cpu"
    output_dir: str = ""

    def __post_init__(self) -> None:
        if self.steps < 1 or self.rounds < 1 or self.episodes < 2 or self.frames < 20:
            raise ValueError("steps and rounds must be >= 1, episodes >= 2, frames >= 20")
        self.procs = tuple(int(n) for n in self.procs)
        if not self.procs or min(self.procs) < 1:
            raise ValueError(f"procs={self.procs}: give process counts >= 1")
        for n in self.procs:
            check_batch(self.batch_size, n)
        if self.device not in ("cpu", "cuda"):
            raise ValueError(f"device={self.device!r}: cpu or cuda")


def make_dataset(root: Path, episodes: int, frames: int) -> Path:
    """A dataset of synthetic frames (every recorded column; training speed does not depend
    on the values)."""
    with DatasetWriter.create(root, "local/bench_scale") as w:
        for ep in make_episodes(episodes, frames):
            w.add_episode(ep, PROVENANCE)
    return root


def configurations(cfg: ScaleTrainConfig) -> list[tuple[str, int, int]]:
    """(name, torchrun processes (0 = plain), threads per process) of every run: today's
    plain process on every core, the same on one core (the per-core figure), then torchrun
    with each of ``procs`` sharing the cores."""
    cores = os.cpu_count() or 1
    confs = [(TODAY, 0, cores)]
    if cfg.device == "cpu" and cores > 1:
        confs.append(("1 process, 1 thread", 0, 1))
    for n in cfg.procs:
        each = max(cores // n, 1)
        confs.append((f"torchrun {n} x {each} thread{'s' * (each > 1)}", n, each))
    return confs


def run(cfg: ScaleTrainConfig) -> dict[str, Any]:
    """Every configuration, round-robin; returns {name: {procs, threads, samples_per_s (the
    best round's), per_process, vs_today (the median over rounds of the ratio to today's run
    of the same round), rounds}}."""
    work = own_output(cfg.output_dir, "python -m msta.eval.bench.scale_train",
                      frozenset({"dataset"}), ("run_",)) if cfg.output_dir \
        else Path(tempfile.mkdtemp(prefix="msta_scale_train_"))
    try:
        shutil.rmtree(work / "dataset", ignore_errors=True)
        dataset = make_dataset(work / "dataset", cfg.episodes, cfg.frames)
        confs = configurations(cfg)
        got: dict[str, list[float]] = {name: [] for name, _, _ in confs}
        for _ in range(cfg.rounds):
            for name, procs, threads in confs:
                got[name].append(measure(dataset, work, procs, cfg.device, threads, cfg.preset,
                                         cfg.steps, cfg.batch_size))
        today = got[TODAY]
        return {name: {"procs": max(procs, 1), "threads": threads,
                       "samples_per_s": max(got[name]),
                       "per_process": max(got[name]) / max(procs, 1),
                       "vs_today": statistics.median(x / t for x, t in zip(got[name], today,
                                                                            strict=True)),
                       "rounds": got[name]}
                for name, procs, threads in confs}
    finally:
        if not cfg.output_dir:
            shutil.rmtree(work, ignore_errors=True)


def report(cfg: ScaleTrainConfig, figs: dict[str, Any]) -> str:
    """The table and the ratio lines (the last: 2 processes vs today's single process)."""
    unit = "GPU" if cfg.device == "cuda" else "process"
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    lines = [f"msta-train, MSTA {cfg.preset} preset, batch {cfg.batch_size}, {cfg.steps} steps, "
             f"{cfg.device}, {os.cpu_count()} cores (load average {load}), {cfg.rounds} rounds",
             "", f"| run | processes | threads each | samples/s (best round) | per {unit} "
             "| vs today (median of rounds) |", "|---|---|---|---|---|---|"]
    for name, f in figs.items():
        lines.append(f"| {name} | {f['procs']} | {f['threads']} | {f['samples_per_s']:.0f} | "
                     f"{f['per_process']:.0f} | {f['vs_today']:.2f} |")
    lines.append("")
    one = figs.get("1 process, 1 thread")
    for name, f in figs.items():
        if name.startswith("torchrun") and one is not None and f["threads"] == 1:
            lines.append(f"{name} vs 1 process, 1 thread (best rounds): "
                         f"{f['samples_per_s'] / one['samples_per_s']:.2f}")
    for name, f in figs.items():
        if name.startswith("torchrun"):
            lines.append(f"{name} vs 1 process: {f['vs_today']:.2f}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    cfg = parse_config(ScaleTrainConfig, argv, prog="python -m msta.eval.bench.scale_train")
    print(report(cfg, run(cfg)), flush=True)


if __name__ == "__main__":
    main()
