"""Training-speed benchmark of the MSTA student: ``python -m msta.eval.bench.train``.

Measures training samples/s (processor + forward + backward + fused AdamW step, batch 64) for
the ``paper`` and ``cpu`` presets at mask ratios 0, 0.5 and 0.75, in fp32 and with bf16
autocast, and the machine's dense fp32 matmul rate (torch.mm on the model's own linear
shapes) in the same run. Configurations run round-robin and the best round counts, so a
neighbour's burst of CPU use hurts every configuration alike. The last two lines are

    masking speed-up (0.75 vs 0): <paper fp32 samples/s at 0.75 / at 0>
    matmul share: <paper fp32 model FLOP/s at 0.75 / fp32 torch.mm FLOP/s>

Model FLOPs count the matmuls of attention (QK^T, AV) and of the linear layers,
forward + backward = 3x forward; embeddings, norms and the head are left out.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import torch

from msta.data import sensors
from msta.data.cli import parse_config
from msta.policies.factory import make_policy
from msta.policies.msta import MSTAConfig, MSTAPolicy
from msta.policies.msta.removal import num_kept

BATCH = 64
ALPHAS = (0.0, 0.5, 0.75)


def synthetic_stats(cfg: MSTAConfig) -> dict[str, dict[str, list[float]]]:
    """Zero-mean unit-std statistics for every input column and the action."""
    stats = {
        sensors.get(n).column: {
            "mean": [0.0] * sensors.get(n).dim,
            "std": [1.0] * sensors.get(n).dim,
        }
        for n in cfg.input_sensors
    }
    stats[cfg.action_key] = {"mean": [0.0] * cfg.action_dim, "std": [1.0] * cfg.action_dim}
    return stats


def synthetic_batch(cfg: MSTAConfig, batch: int, gen: torch.Generator) -> dict[str, torch.Tensor]:
    out = {
        n: torch.randn(batch, cfg.history, sensors.get(n).dim, generator=gen)
        for n in cfg.input_sensors
    }
    if "foot_contact" in out:
        out["foot_contact"] = (out["foot_contact"] > 0).float()
    out[cfg.action_key] = torch.randn(batch, cfg.action_dim, generator=gen)
    return out


def train_flops_per_sample(cfg: MSTAConfig, mask_ratio: float) -> float:
    """Matmul FLOPs of one training sample (forward + backward = 3 x forward)."""
    n = sum(sensors.get(s).dim for s in cfg.input_sensors) * cfg.history
    L, d = num_kept(n, mask_ratio) + 1, cfg.dim
    hidden = round(cfg.mlp_ratio * d)
    linear = 2 * L * (3 * d * d + d * d + 2 * d * hidden)  # qkv, proj, mlp up + down
    attention = 2 * 2 * L * L * d  # QK^T and AV over all heads
    return 3.0 * cfg.num_layers * (linear + attention)


@dataclass
class Case:
    name: str
    step: Callable[[], None]
    samples_per_step: int
    flops_per_step: float
    best: float = 0.0  # best samples/s (or FLOP/s for the matmul case)
    rounds: list[float] = field(default_factory=list)


def training_case(preset: str, alpha: float, bf16: bool, gen: torch.Generator) -> Case:
    cfg = MSTAConfig.from_preset(preset, mask_ratio=alpha)
    policy: MSTAPolicy = make_policy(cfg, synthetic_stats(cfg)).train()
    opt = torch.optim.AdamW(policy.parameters(), lr=1e-4, fused=True)  # one kernel per tensor
    batch = synthetic_batch(cfg, BATCH, gen)

    def step() -> None:
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
            loss, _ = policy.loss(batch)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()

    name = f"{preset:5s} alpha={alpha:.2f} {'bf16' if bf16 else 'fp32'}"
    return Case(name, step, BATCH, BATCH * train_flops_per_sample(cfg, alpha))


def matmul_case(cfg: MSTAConfig, alpha: float) -> Case:
    """torch.mm on the linear-layer shapes of ``cfg`` at ``alpha`` with batch BATCH."""
    n = sum(sensors.get(s).dim for s in cfg.input_sensors) * cfg.history
    m, d = BATCH * (num_kept(n, alpha) + 1), cfg.dim
    h = round(cfg.mlp_ratio * d)
    shapes = [(m, d, 3 * d), (m, d, d), (m, d, h), (m, h, d)]
    mats = [(torch.randn(a, b), torch.randn(b, c)) for a, b, c in shapes]
    flops = sum(2.0 * a * b * c for a, b, c in shapes)

    def step() -> None:
        for a, b in mats:
            torch.mm(a, b)

    return Case(f"torch.mm fp32 {shapes}", step, 1, flops)


def run_round(case: Case, min_seconds: float) -> None:
    steps, t0 = 0, time.perf_counter()
    while True:
        case.step()
        steps += 1
        elapsed = time.perf_counter() - t0
        if elapsed >= min_seconds:
            break
    rate = steps * case.samples_per_step / elapsed
    case.rounds.append(rate)
    case.best = max(case.best, rate)


def bf16_accuracy(preset: str, gen: torch.Generator) -> tuple[float, float]:
    """(relative prediction error, gradient cosine) of bf16 autocast vs fp32 on one batch."""
    cfg = MSTAConfig.from_preset(preset)
    policy = make_policy(cfg, synthetic_stats(cfg)).train()
    batch = synthetic_batch(cfg, BATCH, gen)
    preds, grads = [], []
    for bf16 in (False, True):
        policy.zero_grad()
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
            pred = policy(batch, generator=torch.Generator().manual_seed(0))
            loss = torch.nn.functional.mse_loss(pred.float(), batch[cfg.action_key])
        loss.backward()
        preds.append(pred.detach().float())
        grads.append(
            torch.cat([p.grad.flatten() for p in policy.parameters() if p.grad is not None])
        )
    rel = float((preds[1] - preds[0]).norm() / preds[0].norm())
    return rel, float(torch.nn.functional.cosine_similarity(grads[0], grads[1], dim=0))


def make_cases(gen: torch.Generator) -> dict[tuple[str, float, bool], Case]:
    """fp32 for both presets at every alpha; bf16 autocast for the paper preset at every
    alpha and for the cpu preset at the training default."""
    keys = [("paper", a, bf) for a in ALPHAS for bf in (False, True)]
    keys += [("cpu", a, False) for a in ALPHAS] + [("cpu", 0.75, True)]
    return {k: training_case(*k, gen) for k in keys}


def tokens_kept(preset: str, alpha: float) -> int:
    cfg = MSTAConfig.from_preset(preset)
    return num_kept(sum(sensors.get(s).dim for s in cfg.input_sensors) * cfg.history, alpha) + 1


def report(cases: dict[tuple[str, float, bool], Case], mm: Case, gen: torch.Generator) -> None:
    mm_rate = mm.best * mm.flops_per_step
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    print(
        f"\nbatch {BATCH}, {torch.get_num_threads()} threads, torch {torch.__version__}, "
        f"load average {load} (other processes slow small-op training most)"
    )
    print(f"dense fp32 matmul: {mm_rate / 1e9:.1f} GFLOP/s ({mm.name})")
    print(f"{'case':28s} {'tokens':>6s} {'samples/s':>10s} {'GFLOP/s':>8s} {'share':>6s}  rounds")
    for (preset, alpha, _), case in cases.items():
        flops = case.best * case.flops_per_step / case.samples_per_step
        rounds = " ".join(f"{r:.1f}" for r in case.rounds)
        print(
            f"{case.name:28s} {tokens_kept(preset, alpha):6d} {case.best:10.1f} "
            f"{flops / 1e9:8.1f} {flops / mm_rate:6.2f}  [{rounds}]"
        )
    rel, cos = bf16_accuracy("paper", gen)
    print(
        f"bf16 autocast vs fp32 (paper, one batch): prediction rel. error {rel:.1e}, "
        f"gradient cosine {cos:.4f}"
    )
    for preset, alpha in [("paper", 0.0), ("paper", 0.5), ("paper", 0.75), ("cpu", 0.75)]:
        ratio = cases[(preset, alpha, True)].best / cases[(preset, alpha, False)].best
        print(f"bf16/fp32 speed, {preset} alpha {alpha:.2f}: {ratio:.2f}x")
    cpu = cases[("cpu", 0.75, False)].best / cases[("cpu", 0.0, False)].best
    print(f"cpu preset masking speed-up (0.75 vs 0): {cpu:.2f}")
    paper = cases[("paper", 0.75, False)]
    share = paper.best * paper.flops_per_step / paper.samples_per_step / mm_rate
    print(f"masking speed-up (0.75 vs 0): {paper.best / cases[('paper', 0.0, False)].best:.2f}")
    print(f"matmul share: {share:.2f}")


@dataclass
class BenchTrainConfig:
    """Args:
        rounds: round-robin rounds over every case (the best round counts).
        seconds: minimum time per case and round (s).
        num_threads: torch threads.
    """

    rounds: int = 3
    seconds: float = 0.5
    num_threads: int = 2

    def __post_init__(self) -> None:
        if self.rounds < 1 or self.num_threads < 1 or not self.seconds > 0:
            raise ValueError("rounds and num_threads must be >= 1 and seconds > 0")


def main(argv: list[str] | None = None) -> None:
    args = parse_config(BenchTrainConfig, argv, prog="python -m msta.eval.bench.train")
    torch.set_num_threads(args.num_threads)
    gen = torch.Generator().manual_seed(0)
    cases = make_cases(gen)
    mm = matmul_case(MSTAConfig.from_preset("paper"), 0.75)
    every = [mm, *cases.values()]
    for case in every:  # warm-up: allocator, kernel selection
        case.step()
    for r in range(args.rounds):
        for case in every:
            run_round(case, args.seconds)
        print(f"round {r + 1}/{args.rounds} done", flush=True)
    report(cases, mm, gen)


if __name__ == "__main__":
    main()
