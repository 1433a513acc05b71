"""``make device-check`` / ``python -m msta.eval.apps.device_check``: the CUDA path of every stage, in one
prepared call sized for a lent GPU machine (<= ~6 min on one GPU and 16 cores before the
torchrun stage, which adds two CPU runs of 20 steps and two CUDA runs of 300; not yet timed).

1. **dataset**: the shipped PPO teacher (``rma_ppo``) records DART episodes on levels 0-2;
2. **stage 1**: msta-train, ``paper`` preset (d = 128, 4 x 4, T = 15, mask 0.75), on the
   main device (CUDA when present) and, for the same number of steps, a short run on the CPU:
   training samples/s on each;
3. **parity**: the stage-1 checkpoint's actions on the same windows computed on the CPU
   and on CUDA (max and mean absolute difference, in the action's units and in its std);
4. **stage 2**: msta-correct, one round (the student drives, half of the robots at test
   mask 0.5, the teacher labels, retraining) on the main device: env steps/s and samples/s;
5. **eval**: msta-eval of the teacher and the round's student on the main device (test
   masks 0 / 25 / 50 %): normalized linear tracking and survival, and the time it took;
6. **torchrun**: msta-train on the same dataset under torchrun (train/ddp.py) beside
   today's single process: on CUDA one process per GPU (NCCL), on the CPU 2 processes
   sharing the cores (gloo); samples/s in all, per process / GPU, and the ratio.

Every figure goes to ``output_dir/device_check.json`` and a table on stdout, beside the
machine (GPU name, cores, torch). Without CUDA the same stages run on the CPU alone (the
parity row says so): nothing here requires a GPU. ``--scale=tiny`` runs the pipeline in
seconds (the test suite runs it).
"""

from __future__ import annotations

import csv
import json
import os
import platform
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from msta.data.cli import parse_config
from msta.data.output_dirs import clear_output_dir, command_output_dir
from msta.data.threads import check_threads, resolve_threads
from msta.data.windows import WindowDataset
from msta.eval.apps.demo import easy_terrain_dataset
from msta.eval.apps.train_scaling import measure
from msta.eval.eval_config import EvalConfig
from msta.eval.evaluation import evaluate
from msta.policies.checkpoint import PolicyPath
from msta.policies.factory import load_policy, select_device
from msta.policies.msta import MSTAConfig
from msta.policies.teacher.config import TeacherConfig
from msta.train.config import STAGE2_MASK_RATIO, STAGE2_ROLLOUT_MASK_RATIOS
from msta.train.correct_config import CorrectConfig, RoundEvalConfig
from msta.train.stage1 import train
from msta.train.stage2 import correct
from msta.train.train_config import TrainConfig

#: scale -> (episodes, episode s, gpu steps, cpu steps, batch, round episodes, round steps,
#: eval trials, eval episode s, preset)
#: What the check writes at the top of its --output_dir (a run from before the marker), and
#: the names of those only it writes.
OUTPUTS = frozenset({"dataset", "device_check.json", "eval", "progress.json", "torchrun",
                     "stage1", "stage1_cpu", "stage2", "stage2_dataset"})
OUTPUTS_SIGN = frozenset({"device_check.json", "stage1_cpu", "stage2_dataset", "torchrun"})
SCALES: dict[str, tuple[int, float, int, int, int, int, int, int, float, str]] = {
    "tiny": (4, 1.0, 4, 2, 8, 2, 2, 2, 1.0, "tiny"),
    "device": (256, 10.0, 1500, 40, 256, 128, 600, 100, 5.0, "paper"),
}
#: scale -> (steps on CUDA, steps on the CPU, batch, preset) of the torchrun runs
TORCHRUN: dict[str, tuple[int, int, int, str]] = {
    "tiny": (8, 8, 8, "tiny"),
    "device": (300, 20, 256, "paper"),
}


@dataclass
class DeviceCheckConfig:
    """Args:
        output_dir: every stage's outputs and device_check.json (cleared first).
        scale: device (sized for a lent GPU machine, ~6 min) or tiny (seconds: the pipeline).
        device: the main device: auto (CUDA when present), cpu, cuda, cuda:<index>.
        num_threads: torch threads on the CPU (0: the cores other work leaves free, msta.data.threads).
    """

    output_dir: str = "outputs/device_check"
    scale: str = "device"
    device: str = "auto"
    num_threads: int = 0

    def __post_init__(self) -> None:
        if self.scale not in SCALES:
            raise ValueError(f"scale={self.scale!r}: choose one of {', '.join(SCALES)}")
        check_threads(self.num_threads)


def machine() -> dict[str, Any]:
    """What ran: host, cores, torch, and the GPU when there is one."""
    info = {"host": platform.node(), "cpu_cores": os.cpu_count(), "torch": torch.__version__,
            "python": platform.python_version(), "cuda": torch.cuda.is_available()}
    if info["cuda"]:
        props = torch.cuda.get_device_properties(0)
        info.update(gpu=props.name, gpu_memory_gib=round(props.total_memory / 2**30, 1),
                    cuda_version=torch.version.cuda)
    return info


def last_samples_per_s(run: Path) -> float:
    """The cumulative samples/s msta-train logged last (metrics.csv)."""
    with open(run / "metrics.csv") as f:
        rows = [r for r in csv.DictReader(f) if r.get("samples_per_s")]
    return float(rows[-1]["samples_per_s"])


def stage1(root: Path, out: Path, device: str, steps: int, batch: int, preset: str) -> Path:
    return train(TrainConfig(
        dataset=str(root), policy=MSTAConfig.from_preset(preset), output_dir=str(out),
        device=device, steps=steps, batch_size=batch, warmup_steps=min(100, max(steps // 5, 1)),
        eval_every=steps, save_every=steps, log_every=max(steps // 4, 1), progress=False))


def parity(ckpt: Path, root: Path, device: str) -> dict[str, Any]:
    """The same checkpoint's actions on the CPU and on ``device`` for 512 windows."""
    if torch.device(device).type != "cuda":
        return {"compared": False, "why": "no CUDA device: CPU only"}
    cpu = load_policy(ckpt, device="cpu")
    gpu = load_policy(ckpt, device=device)
    ds = WindowDataset(root, cpu.required_sensors, cpu.config.history, extra_columns=("action",))
    idx = np.unique(np.linspace(0, len(ds) - 1, min(len(ds), 512)).round().astype(np.int64))
    batch = {k: v for k, v in ds.get_batch(idx).items() if k != "action"}
    with torch.no_grad():
        a_cpu = cpu.act(batch).cpu().numpy()
        a_gpu = gpu.act(batch).cpu().numpy()
    diff = np.abs(a_cpu - a_gpu)
    std = np.maximum(a_cpu.std(0), 1e-6)
    return {"compared": True, "windows": len(idx), "max_abs": float(diff.max()),
            "mean_abs": float(diff.mean()), "max_in_action_std": float((diff / std).max())}


def stage2(ckpt: Path, root: Path, out: Path, device: str, episodes: int, steps: int,
           batch: int, seconds: float) -> tuple[Path, dict[str, Any]]:
    copy = out.parent / "stage2_dataset"
    shutil.copytree(root, copy)
    correct(CorrectConfig(
        policy=PolicyPath(str(ckpt)), dataset=str(copy), output_dir=str(out), rounds=1,
        episodes_per_round=episodes, num_envs=min(episodes, 64), episode_length_s=seconds,
        steps=steps, batch_size=batch, lr=1e-3, beta=0.0, mask_ratio=STAGE2_MASK_RATIO,
        teacher=TeacherConfig(), rollout_mask_ratios=STAGE2_ROLLOUT_MASK_RATIOS,
        warmup_steps=min(20, max(steps // 5, 1)), eval_every=steps, save_every=steps,
        eval=RoundEvalConfig(enabled=False), device=device, progress=False))
    rounds = json.loads((out / "progress.json").read_text())["rounds"]
    rec = rounds.get("1", rounds.get(1, {}))
    return out / "round_1", {k: rec[k] for k in ("rollout", "train") if k in rec}


def evaluate_student(ckpt: Path, out: Path, device: str, trials: int,
                     seconds: float) -> dict[str, Any]:
    metrics = evaluate(EvalConfig(
        policies=f"teacher,{ckpt}", suite="quick", scenarios="token_removal", output_dir=str(out),
        trials=trials, levels="0,1,2", episode_length_s=seconds, device=device,
        teacher=TeacherConfig(), progress=False))
    rows = {}
    for run in metrics["runs"]:
        if run["policy"] == "teacher" or run.get("status") != "ok":
            continue
        avg = run["normalized"]["per_terrain"]["average"]
        rows[f"mask {run['spec']['mask_ratio']:g}"] = {
            "lin_tracking": avg["lin_tracking"],
            "survival": run["raw"]["per_terrain"]["average"]["survival"], "trials": trials}
    return rows


def torchrun_training(root: Path, work: Path, main: str, scale: str) -> dict[str, Any]:
    """msta-train under torchrun and as today's single process, same data and steps: on
    CUDA (when ``main`` is) one process per GPU, on the CPU 2 processes sharing the cores."""
    gpu_steps, cpu_steps, batch, preset = TORCHRUN[scale]
    cores = os.cpu_count() or 1
    runs = [("cpu", 2, cpu_steps, "gloo")]
    if torch.device(main).type == "cuda":
        runs.insert(0, ("cuda", torch.cuda.device_count(), gpu_steps, "NCCL"))
    rows = {}
    for dev, n, steps, backend in runs:
        each = max(cores // n, 1)
        one = measure(root, work / dev, 0, dev, cores, preset, steps, batch)
        many = measure(root, work / dev, n, dev, each, preset, steps, batch)
        rows[f"{dev}: torchrun {n} x {each} thread{'s' * (each > 1)} ({backend})"] = {
            "processes": n, "samples_per_s": many, "per_process": many / n,
            "single_process_samples_per_s": one, "vs_single_process": many / one}
    return rows


def timed(figures: dict[str, Any], name: str, fn, *args):
    t0 = time.time()
    result = fn(*args)
    figures.setdefault("seconds", {})[name] = round(time.time() - t0, 1)
    print(f"[device-check] {name}: {figures['seconds'][name]:.0f} s", flush=True)
    return result


def run(cfg: DeviceCheckConfig) -> dict[str, Any]:
    """Every stage; returns (and writes) the figures."""
    eps, ep_s, steps, cpu_steps, batch, r_eps, r_steps, trials, ev_s, preset = SCALES[cfg.scale]
    torch.set_num_threads(resolve_threads(cfg.num_threads))
    main = str(select_device(cfg.device))
    out = clear_output_dir(cfg.output_dir, "make device-check", legacy=OUTPUTS,
                           sign=OUTPUTS_SIGN)
    figs: dict[str, Any] = {"machine": machine(), "device": main, "scale": cfg.scale,
                            "threads": torch.get_num_threads()}
    print(f"[device-check] {json.dumps(figs['machine'])}; main device {main}", flush=True)
    teacher = TeacherConfig()
    root = timed(figs, "dataset", easy_terrain_dataset, out / "dataset", eps, ep_s,
                 "check/a1_teacher", teacher, 0.5)
    ckpt = timed(figs, f"stage 1 on {main}", stage1, root, out / "stage1", main, steps, batch,
                 preset)
    figs["stage1_samples_per_s"] = {main: last_samples_per_s(out / "stage1")}
    if main != "cpu":
        timed(figs, "stage 1 on cpu", stage1, root, out / "stage1_cpu", "cpu", cpu_steps, batch,
              preset)
        figs["stage1_samples_per_s"]["cpu"] = last_samples_per_s(out / "stage1_cpu")
    figs["parity"] = parity(ckpt, root, main)
    student, figs["stage2"] = timed(figs, f"stage 2 on {main}", stage2, ckpt, root,
                                    out / "stage2", main, r_eps, r_steps, batch, ep_s)
    figs["eval"] = timed(figs, f"eval on {main}", evaluate_student, student, out / "eval", main,
                         trials, ev_s)
    figs["torchrun"] = timed(figs, "torchrun training", torchrun_training, root,
                             out / "torchrun", main, cfg.scale)
    (out / "device_check.json").write_text(json.dumps(figs, indent=1) + "\n")
    print_summary(figs)
    return figs


def print_summary(figs: dict[str, Any]) -> None:
    print("\n| figure | value |\n|---|---|")
    for dev, sps in figs["stage1_samples_per_s"].items():
        print(f"| stage-1 samples/s on {dev} | {sps:,.0f} |")
    p = figs["parity"]
    print("| CPU vs CUDA actions | " + (f"max {p['max_abs']:.2e} (mean {p['mean_abs']:.2e}; "
          f"{p['max_in_action_std']:.2e} action std) over {p['windows']} windows"
          if p["compared"] else p["why"]) + " |")
    tr = figs["stage2"].get("train", {})
    ro = figs["stage2"].get("rollout", {})
    print(f"| stage-2 env steps/s | {ro.get('env_steps_per_s', float('nan')):,.0f} |")
    print(f"| stage-2 samples/s | {tr.get('train_samples_per_s', float('nan')):,.0f} |")
    for cond, r in figs["eval"].items():
        lin = r["lin_tracking"]
        print(f"| eval {cond}: lin. tracking vs teacher / survival ({r['trials']} trials) | "
              f"{lin if lin is None else round(lin, 3)} / {r['survival']:.3f} |")
    for name, r in figs["torchrun"].items():
        one = r["single_process_samples_per_s"]
        print(f"| {name}: samples/s, per process, vs one process ({one:,.0f}) | "
              f"{r['samples_per_s']:,.0f}, {r['per_process']:,.0f}, "
              f"{r['vs_single_process']:.2f} |")
    for name, s in figs["seconds"].items():
        print(f"| time: {name} | {s:.0f} s |")


def main(argv: list[str] | None = None) -> None:
    prog = "python -m msta.eval.apps.device_check"
    cfg = parse_config(DeviceCheckConfig, argv, prog=prog)
    command_output_dir(cfg.output_dir, "make device-check", prog, legacy=OUTPUTS,  # refuse early
                       sign=OUTPUTS_SIGN)
    run(cfg)


if __name__ == "__main__":
    main()
