"""msta-train vs lerobot-train on the same data, steps and seeds: does LeRobot's trainer
train the MSTA student as msta's own does?

For every seed: ``msta-train`` (in this process, :func:`msta.train.stage1.train`) and
``lerobot-train --policy.type=msta`` (a subprocess, the real command) train the same student
(the ``--preset``'s fields) for the same steps and batch size on the same training episodes
(msta-train's episode split for that seed; lerobot-train gets them as ``--dataset.episodes``).
Both checkpoints are then scored by msta-train's own validation
(:func:`msta.train.step.validate`) on that seed's held-out episodes, the LeRobot one after
:func:`lerobot_policy_msta.convert.lerobot_to_msta` (bit-exact), next to the untrained
student's score. What differs between the two runs: the order of the samples, the random
token removal (msta: its own generator; LeRobot: the global one) and the initial weights'
random stream, i.e. what another seed changes too.

Speed, measured in the same run: each trainer's training steps per second with the same
torch threads (``--num_threads``), after its first ``log_freq`` steps (warm-up): msta-train's
from the time between its steps, lerobot-train's from its own per-step timers (``updt_s``
+ ``data_s`` of its log lines, which cover loading, preprocessing and the update). The last
line printed is ``lerobot-train / msta-train steps/s: <ratio>``. docs/lerobot.md has a
measured run::

    python -m lerobot_policy_msta.compare_trainers --dataset=outputs/datasets/a1_tiny --steps=300 --batch_size=16 --seeds=[0,1,2]
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lerobot_policy_msta.convert import lerobot_to_msta
from msta.data.checks import check_at_least
from msta.data.cli import parse_config
from msta.data.locate import locate_dataset
from msta.data.stats import load_stats
from msta.data.windows import episode_split
from msta.policies.factory import load_policy, make_policy
from msta.policies.msta import PRESETS, MSTAConfig
from msta.train.loop import load_windows
from msta.train.optim import seed_everything
from msta.train.stage1 import train
from msta.train.step import validate
from msta.train.train_config import TrainConfig

FIGURES = ("loss_unmasked", "action_mse", "loss")


@dataclass
class CompareTrainersConfig:
    """Args:
        dataset: an msta dataset root (schema >= 2: it has observation.state).
        output_dir: runs and results.json go here (must not hold an earlier comparison).
        seeds: one msta-train and one lerobot-train run per seed.
        steps: optimizer steps of every run.
        batch_size: windows per step.
        preset: msta's policy preset both trainers get (cpu: d 64, 2 layers).
        val_fraction: msta-train's held-out share of episodes (split by seed).
        val_samples: validation windows scored (msta-train's --val_samples).
        log_freq: lerobot-train's --log_freq.
        noise_seeds: extra lerobot-train runs with these seeds on the first seed's split
            (the same data): how much the seed alone moves the score.
        num_threads: torch CPU threads of both trainers (msta-train's --num_threads,
            lerobot-train's --policy.num_threads).
    """

    dataset: str = ""
    output_dir: str = "outputs/lerobot_vs_msta"
    seeds: tuple[int, ...] = (0, 1, 2)
    steps: int = 300
    batch_size: int = 16
    preset: str = "cpu"
    val_fraction: float = 0.1
    val_samples: int = 1024
    log_freq: int = 50
    noise_seeds: tuple[int, ...] = ()
    num_threads: int = 1

    def __post_init__(self) -> None:
        self.seeds = tuple(int(s) for s in self.seeds)
        self.noise_seeds = tuple(int(s) for s in self.noise_seeds)
        check_at_least(self, 1, "steps", "batch_size", "val_samples", "log_freq", "num_threads")
        if self.steps < 2 * self.log_freq:
            raise ValueError(f"steps={self.steps} must be at least 2 x log_freq={self.log_freq} "
                             "(the first log_freq steps are warm-up, not timed)")
        if not self.seeds:
            raise ValueError("seeds is empty")
        if self.preset not in PRESETS:
            raise ValueError(f"unknown preset {self.preset!r}; known: {sorted(PRESETS)}")
        if not 0.0 < self.val_fraction < 1.0:
            raise ValueError(f"val_fraction={self.val_fraction} must be in (0, 1)")


def lerobot_train_args(cfg: CompareTrainersConfig, root: Path, episodes: Sequence[int],
                       seed: int, out: Path) -> list[str]:
    """The lerobot-train command line of one run."""
    exe = Path(sys.executable).with_name("lerobot-train")
    policy = [f"--policy.{k}={v}" for k, v in PRESETS[cfg.preset].items()]
    return [str(exe), "--policy.type=msta", "--dataset.repo_id=local/compare",
            f"--dataset.root={root}", f"--dataset.episodes=[{','.join(map(str, episodes))}]",
            *policy, "--policy.device=cpu", f"--steps={cfg.steps}",
            f"--batch_size={cfg.batch_size}", f"--seed={seed}", "--num_workers=0",
            f"--policy.num_threads={cfg.num_threads}",
            f"--save_freq={cfg.steps}", f"--log_freq={cfg.log_freq}", f"--output_dir={out}"]


def score(policy: Any, root: Path, episodes: Sequence[int], cfg: CompareTrainersConfig,
          seed: int) -> dict[str, float]:
    """msta-train's validation figures of ``policy`` on ``episodes``."""
    val = load_windows(root, policy, episodes)
    return validate(policy, val, cfg.batch_size, cfg.val_samples, policy.config.mask_ratio,
                    seed=seed)


def lerobot_run(cfg: CompareTrainersConfig, root: Path, split_seed: int, seed: int, out: Path
                ) -> dict[str, Any]:
    """lerobot-train with ``seed`` on the training episodes of ``split_seed``'s split, scored
    on its validation episodes (the checkpoint converted to msta's format, bit-exact)."""
    train_eps, val_eps = episode_split(root, cfg.val_fraction, split_seed)
    t0 = time.perf_counter()
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled"}
    args = lerobot_train_args(cfg, root, train_eps, seed, out / "lerobot")
    proc = subprocess.run(args, env=env, capture_output=True, text=True, check=False)
    (out / "lerobot_train.log").write_text(proc.stdout + proc.stderr)
    if proc.returncode:
        raise RuntimeError(f"lerobot-train failed (exit {proc.returncode}); see "
                           f"{out / 'lerobot_train.log'}")
    ckpt = out / "lerobot" / "checkpoints" / "last" / "pretrained_model"
    converted = lerobot_to_msta(ckpt, out / "lerobot_as_msta")
    return {**score(load_policy(converted), root, val_eps, cfg, split_seed),
            "wall_s": time.perf_counter() - t0,
            "steps_per_s": lerobot_steps_per_s(proc.stdout + proc.stderr, cfg.log_freq)}


def lerobot_steps_per_s(log: str, warmup: int) -> float:
    """Steps per second from lerobot-train's log lines (``step:N ... updt_s:U data_s:D``,
    the means over each ``log_freq`` window), the windows after step ``warmup``."""
    times = [float(u) + float(d) for n, u, d in re.findall(
        r"step:(\d+) .*?updt_s:([\d.]+) data_s:([\d.]+)", log) if int(n) > warmup]
    if not times:
        raise RuntimeError("no lerobot-train log line after the warm-up steps to time")
    return 1.0 / float(np.mean(times))


def run_seed(cfg: CompareTrainersConfig, root: Path, out: Path, seed: int) -> dict[str, Any]:
    """One seed: the untrained student, msta-train and lerobot-train, scored alike."""
    _, val_eps = episode_split(root, cfg.val_fraction, seed)
    native = MSTAConfig.from_preset(cfg.preset)
    seed_everything(seed)
    rec: dict[str, Any] = {"seed": seed, "val_episodes": val_eps,
                           "untrained": score(make_policy(native, load_stats(root)), root,
                                              val_eps, cfg, seed)}
    t0 = time.perf_counter()
    stamps: dict[int, float] = {}
    final = train(TrainConfig(dataset=str(root), policy=native, output_dir=str(out / "msta"),
                              steps=cfg.steps, batch_size=cfg.batch_size, seed=seed,
                              val_fraction=cfg.val_fraction, val_samples=cfg.val_samples,
                              eval_every=0, save_every=0, progress=False,
                              num_threads=cfg.num_threads),
                  on_step=lambda step, _: stamps.__setitem__(step, time.perf_counter()))
    last = cfg.steps - 1  # the step after the warm-up to the last but the final save
    rec["msta_train"] = {**score(load_policy(final), root, val_eps, cfg, seed),
                         "wall_s": time.perf_counter() - t0,
                         "steps_per_s": (last - cfg.log_freq) / (stamps[last] -
                                                                 stamps[cfg.log_freq])}
    rec["lerobot_train"] = lerobot_run(cfg, root, seed, seed, out)
    return rec


def noise_lines(split_seed: int, noise: list[dict[str, Any]]) -> str:
    """The extra lerobot-train runs on ``split_seed``'s split, one line each."""
    return "\n".join(f"lerobot-train --seed={r['seed']} on seed {split_seed}'s split: val MSE "
                     f"{r['loss_unmasked']:.4f}, action MSE {r['action_mse']:.5f}"
                     for r in noise)


def table(records: list[dict[str, Any]]) -> str:
    """Markdown: per seed and mean +- std over seeds, for each figure and trainer."""
    rows = ["| seed | untrained val MSE | msta-train val MSE | lerobot-train val MSE | "
            "msta-train action MSE | lerobot-train action MSE | steps/s msta / lerobot | "
            "wall s msta / lerobot |", "|---|---|---|---|---|---|---|---|"]
    for r in records:
        m, lr = r["msta_train"], r["lerobot_train"]
        rows.append(f"| {r['seed']} | {r['untrained']['loss_unmasked']:.4f} | "
                    f"{m['loss_unmasked']:.4f} | {lr['loss_unmasked']:.4f} | "
                    f"{m['action_mse']:.5f} | {lr['action_mse']:.5f} | "
                    f"{m['steps_per_s']:.1f} / {lr['steps_per_s']:.1f} | "
                    f"{m['wall_s']:.0f} / {lr['wall_s']:.0f} |")

    def stat(who: str, key: str, fmt: str) -> str:
        v = np.array([r[who][key] for r in records])
        return f"{v.mean():{fmt}} +- {v.std(ddof=1) if len(v) > 1 else 0.0:{fmt}}"

    rows.append(f"| mean +- std | {stat('untrained', 'loss_unmasked', '.4f')} | "
                f"{stat('msta_train', 'loss_unmasked', '.4f')} | "
                f"{stat('lerobot_train', 'loss_unmasked', '.4f')} | "
                f"{stat('msta_train', 'action_mse', '.5f')} | "
                f"{stat('lerobot_train', 'action_mse', '.5f')} | "
                f"{stat('msta_train', 'steps_per_s', '.1f')} / "
                f"{stat('lerobot_train', 'steps_per_s', '.1f')} | |")
    return "\n".join(rows)


def speed_line(records: list[dict[str, Any]], cfg: CompareTrainersConfig) -> str:
    """``lerobot-train / msta-train steps/s: <ratio>``: the mean of the per-seed ratios."""
    ratios = [r["lerobot_train"]["steps_per_s"] / r["msta_train"]["steps_per_s"]
              for r in records]
    return (f"lerobot-train / msta-train steps/s: {np.mean(ratios):.2f} (per seed "
            f"{', '.join(f'{x:.2f}' for x in ratios)}; batch {cfg.batch_size}, preset "
            f"{cfg.preset}, {cfg.num_threads} thread(s), after {cfg.log_freq} warm-up steps)")


def compare(cfg: CompareTrainersConfig) -> list[dict[str, Any]]:
    """Run every seed; write ``results.json`` and ``results.md`` in ``cfg.output_dir``."""
    root = locate_dataset(cfg.dataset, "--dataset")
    out = Path(cfg.output_dir)
    if (out / "results.json").exists():
        raise FileExistsError(f"{out} holds an earlier comparison; choose another --output_dir")
    records, noise = [], []
    for seed in cfg.seeds:
        run_dir = out / f"seed_{seed}"
        shutil.rmtree(run_dir, ignore_errors=True)  # an interrupted run starts again
        records.append(run_seed(cfg, root, run_dir, seed))
        print(table(records), flush=True)
    for seed in cfg.noise_seeds:
        run_dir = out / f"noise_seed_{seed}"
        shutil.rmtree(run_dir, ignore_errors=True)
        noise.append({"seed": seed, **lerobot_run(cfg, root, cfg.seeds[0], seed, run_dir)})
        print(noise_lines(cfg.seeds[0], noise[-1:]), flush=True)
    (out / "results.json").write_text(json.dumps(
        {"config": {**cfg.__dict__, "dataset": str(root)}, "runs": records, "noise": noise},
        indent=1) + "\n")
    speed = speed_line(records, cfg)
    (out / "results.md").write_text(table(records) + "\n\n" + noise_lines(cfg.seeds[0], noise)
                                     + "\n\n" + speed + "\n")
    print(speed, flush=True)
    return records


def main(argv: Sequence[str] | None = None) -> None:
    prog = "python -m lerobot_policy_msta.compare_trainers"
    cfg = parse_config(CompareTrainersConfig, argv, prog)
    try:
        compare(cfg)
    except (ValueError, FileNotFoundError, FileExistsError, RuntimeError) as e:
        raise SystemExit(f"{prog}: error: {e}") from None


if __name__ == "__main__":
    main()
