"""Benchmark: rollout throughput on Ray workers against today's single process, in one run.

    python -m msta.eval.bench.scale [--rounds 2] [--workers 1,2] [--output_dir outputs/bench_scale]

Three stages, each through its real entry point with the commands' defaults but the sizes
below: **collect** (msta-collect: the shipped PPO teacher records, the dataset is written;
recorded frames/s), **stage 2** (msta-correct's round rollouts: an MSTA student of the
``cpu`` preset drives, the teacher labels; frames/s), **eval** (msta-eval: the reference
teacher and two teacher rows, which walk, on the same trials; trial env steps/s).

Configurations: ``single`` is the process every command runs by default (MuJoCo's thread
pool and torch's threads over the machine's cores; msta-eval's torch on one thread), the
reference of every ratio; ``single-1-thread`` the same with torch on one thread (context:
how much of a difference is torch's threads); ``ray-N`` N Ray workers of one CPU each. Each
configuration first runs every stage once at a tiny size (workers started, imports and first
calls: a process pays them once; printed as warm-up), then all run round-robin for
``--rounds`` rounds, and each ratio is the median of per-round ratios, so a neighbour's burst
of CPU use hurts every configuration alike. Also measured: the committer alone (the writer
appending recorded episodes, frames/s), in collecting workers' worth. Results go to
``output_dir/results.json``; the last line is

    ray-<max workers> / single process: collect <r>, stage 2 <r>, eval <r>
"""

from __future__ import annotations

import json
import os
import shutil
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from msta.collect.ray_record import RecordJob, record_block, teacher_factory
from msta.collect.record import CollectConfig, collect
from msta.collect.sim.env import QuadrupedEnv
from msta.collect.sim.env_config import EnvConfig
from msta.data.cli import parse_config
from msta.data.sensors import DEFAULT_RECORDED
from msta.data.stats import load_stats
from msta.data.writer import DatasetWriter
from msta.eval.bench.outputs import own_output
from msta.eval.eval_config import EvalConfig
from msta.eval.evaluation import evaluate
from msta.policies.factory import load_policy, make_policy
from msta.policies.msta import MSTAConfig
from msta.policies.teacher.config import TeacherConfig
from msta.train.correct_config import CorrectConfig
from msta.train.stage2 import drive_and_label

#: What each stage's figure counts, per second of wall clock.
UNITS = {"collect": "frames/s", "stage2": "frames/s", "eval": "trial steps/s"}


@dataclass
class BenchScaleConfig:
    """Args:
        workers: Ray worker counts to measure, comma-separated (each against the single
            process).
        rounds: measurements per configuration (the median ratio counts).
        episodes: msta-collect's episodes per measurement (blocks of ``num_envs``: at
            least one block per worker).
        num_envs: environments simulated together (the single process's batch, a
            worker's block).
        episode_length_s: episode length (s) of every stage.
        stage2_episodes: stage-2 episodes per measurement (``episodes_per_round``).
        trials: msta-eval trials per run (rounds of ``num_envs``).
        committer_s: seconds the committer alone is timed.
        output_dir: datasets, the student and results.json.
    """

    workers: str = "1,2"
    rounds: int = 3
    episodes: int = 48
    num_envs: int = 8
    episode_length_s: float = 2.0
    stage2_episodes: int = 16
    trials: int = 32
    committer_s: float = 3.0
    output_dir: str = "outputs/bench_scale"

    def __post_init__(self) -> None:
        self.worker_list = [int(w) for w in self.workers.split(",") if w.strip()]
        if not self.worker_list or min(self.worker_list) < 1:
            raise ValueError(f"workers={self.workers!r}: comma-separated counts >= 1")
        if min(self.rounds, self.episodes, self.num_envs, self.stage2_episodes,
               self.trials) < 1:
            raise ValueError("rounds, episodes, num_envs, stage2_episodes and trials must "
                             "be >= 1")


def _timed(fn, *args) -> tuple[Any, float]:
    t0 = time.perf_counter()
    out = fn(*args)
    return out, time.perf_counter() - t0


def bench_collect(args: BenchScaleConfig, out: Path, workers: int) -> float:
    """msta-collect's recorded frames/s (the dataset written)."""
    root = out / f"collect_w{workers}"
    shutil.rmtree(root, ignore_errors=True)
    cfg = CollectConfig(episodes=args.episodes, num_envs=args.num_envs, root=str(root),
                        episode_length_s=args.episode_length_s, progress=False,
                        workers=workers)
    _, dt = _timed(collect, cfg)
    with DatasetWriter.open(root) as w:
        return w.num_frames / dt


def make_student(out: Path) -> Path:
    """An MSTA student of the cpu preset (random weights) with the statistics of a teacher
    collection: it costs what a trained one costs per step."""
    stats = load_stats(out / "collect_w0")
    return make_policy(MSTAConfig.from_preset("cpu"), stats).save_pretrained(out / "student")


def bench_stage2(args: BenchScaleConfig, student: Any, workers: int) -> float:
    """msta-correct's round rollouts (the student drives, the teacher labels): frames/s."""
    cfg = CorrectConfig(episodes_per_round=args.stage2_episodes, num_envs=args.num_envs,
                        episode_length_s=args.episode_length_s, progress=False,
                        workers=workers)
    (episodes, _), dt = _timed(drive_and_label, cfg, student, 1, "bench")
    return sum(len(f["action"]) for f, _ in episodes) / dt


def bench_eval(args: BenchScaleConfig, out: Path, workers: int) -> float:
    """msta-eval of the reference teacher and two teacher rows (they walk: full-length
    trials; a random student falls at once): trial env steps/s."""
    cfg = EvalConfig(policies="teacher,teacher:gait", scenarios="token_removal",
                     trials=args.trials, num_envs=args.num_envs,
                     episode_length_s=args.episode_length_s,
                     output_dir=str(out / f"eval_w{workers}"), progress=False,
                     workers=workers)
    metrics, dt = _timed(evaluate, cfg)
    lengths = [r["raw"]["per_terrain"]["average"]["length"] for r in metrics["runs"]
               if r["status"] == "ok"] + [metrics["reference"]["per_terrain"]["average"]["length"]]
    max_steps = round(cfg.episode / EnvConfig().dt)
    return sum(lengths) * args.trials * max_steps / dt


def run_config(args: BenchScaleConfig, out: Path, name: str, student: Any
               ) -> dict[str, float]:
    """Every stage in configuration ``name``: ``single``, ``single-1-thread`` (torch on
    one thread; eval's default already), ``ray-<N>``."""
    workers = int(name.split("-")[1]) if name.startswith("ray-") else 0
    threads = torch.get_num_threads()
    if name == "single-1-thread":
        torch.set_num_threads(1)
    try:
        rates = {"collect": bench_collect(args, out, workers),
                 "stage2": bench_stage2(args, student, workers)}
        if name != "single-1-thread":
            rates["eval"] = bench_eval(args, out, workers)
    finally:
        torch.set_num_threads(threads)
    return rates


def committer_rate(args: BenchScaleConfig, out: Path) -> float:
    """The committer alone: frames/s the writer appends (validation, Parquet, checksums,
    commits) for one block of teacher episodes, written again and again for
    ``committer_s``."""
    env_cfg = EnvConfig(num_envs=args.num_envs, episode_length_s=args.episode_length_s)
    job = RecordJob(env_cfg, teacher_factory(TeacherConfig(), 0.0, 0), DEFAULT_RECORDED)
    keys = np.arange(args.num_envs)
    eps, _ = record_block(QuadrupedEnv(job.sim_config(len(keys))), job.make_actor(0, len(keys)),
                          0, keys, DEFAULT_RECORDED)
    root = out / "committer"
    shutil.rmtree(root, ignore_errors=True)
    t0, frames = time.perf_counter(), 0
    with DatasetWriter.create(root, "local/committer") as w:
        while time.perf_counter() - t0 < args.committer_s:
            for f, _, _ in eps:
                w.add_episode(f, {"terrain": "flat", "terrain_level": 0, "source": "teacher",
                                  "round": 0, "policy": "bench", "policy_revision": "",
                                  "seed": 0})
                frames += len(f["action"])
    return frames / (time.perf_counter() - t0)


def measure(args: BenchScaleConfig, out: Path) -> dict[str, Any]:
    """Every configuration round-robin, after a warm-up of each; per-round rates."""
    import ray  # lazy: Ray (~0.7 s) loads only with --workers or a Ray address


    if not ray.is_initialized():  # one local Ray, a CPU for every worker of every pool
        ray.init(num_cpus=sum(args.worker_list), include_dashboard=False,
                 log_to_driver=False, logging_level="warning")
    bench_collect(replace(args, episodes=1, episode_length_s=0.1), out, 0)
    student = load_policy(make_student(out), device="cpu")
    names = ["single", "single-1-thread", *(f"ray-{w}" for w in args.worker_list)]
    tiny = replace(args, episodes=max(args.worker_list), stage2_episodes=args.num_envs,
                   trials=max(args.worker_list), episode_length_s=0.1)
    warm = {}
    for name in names:  # workers started, imports and first calls paid: out of the figures
        _, warm[name] = _timed(run_config, tiny, out, name, student)
    rates: dict[str, dict[str, list[float]]] = {}
    load = [round(os.getloadavg()[0], 1)]  # the machine's other work, before and after
    for r in range(args.rounds):
        for name in names:
            for stage, v in run_config(args, out, name, student).items():
                rates.setdefault(stage, {}).setdefault(name, []).append(v)
            print(f"round {r} {name}: " + ", ".join(
                f"{s} {rates[s][name][-1]:,.0f}" for s in rates if name in rates[s]), flush=True)
    load.append(round(os.getloadavg()[0], 1))
    return {"rates": rates, "warm_up_s": {k: round(v, 1) for k, v in warm.items()},
            "load": load}


def summarize(args: BenchScaleConfig, m: dict[str, Any], committer: float) -> dict[str, Any]:
    """Median rate per stage and configuration, and its median per-round ratio to the
    single process's."""
    rows: dict[str, Any] = {}
    for stage, by in m["rates"].items():
        single = np.asarray(by["single"])
        rows[stage] = {name: {"per_s": float(np.median(v)),
                              "ratio": float(np.median(np.asarray(v) / single))}
                       for name, v in by.items()}
    return {"units": UNITS, "stages": rows, "warm_up_s": m["warm_up_s"],
            "committer_frames_per_s": committer, "cpus": os.cpu_count(),
            "load_average_1min": m["load"],
            "config": {k: v for k, v in vars(args).items() if k != "worker_list"}}


def main(argv: list[str] | None = None) -> None:
    prog = "python -m msta.eval.bench.scale"
    args = parse_config(BenchScaleConfig, argv, prog=prog)
    out = own_output(args.output_dir, prog, frozenset({"results.json", "committer", "student"}),
                     ("collect_w", "eval_w", "stage2_w"), sign=frozenset({"committer"}))
    m = measure(args, out)
    res = summarize(args, m, committer_rate(args, out))
    (out / "results.json").write_text(json.dumps(res, indent=1) + "\n")
    names = list(res["stages"]["collect"])
    print(f"\n{os.cpu_count()} CPUs (1-min load average before / after: {m['load']}); "
          f"episodes of {args.episode_length_s} s in blocks of {args.num_envs}; "
          f"{args.rounds} rounds; warm-up (s) {m['warm_up_s']}")
    print("| stage | unit | " + " | ".join(names) + " |\n|---|---|" + "---|" * len(names))
    for stage, row in res["stages"].items():
        print(f"| {stage} | {UNITS[stage]} | " + " | ".join(
            f"{row[n]['per_s']:,.0f} ({row[n]['ratio']:.2f})" if n in row else "-"
            for n in names) + " |")
    first, committer = args.worker_list[0], res["committer_frames_per_s"]
    per_worker = res["stages"]["collect"][f"ray-{first}"]["per_s"] / first
    print(f"committer alone: {committer:,.0f} frames/s = {committer / per_worker:.0f} "
          f"collecting workers' worth ({per_worker:,.0f} frames/s each)")
    top = f"ray-{max(args.worker_list)}"
    print(f"{top} / single process: " + ", ".join(
        f"{s.replace('stage2', 'stage 2')} {res['stages'][s][top]['ratio']:.2f}"
        for s in ("collect", "stage2", "eval")))


if __name__ == "__main__":
    main()
