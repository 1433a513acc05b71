"""The training loop itself (:func:`fit`): stage 1 (``msta-train``) runs it once, stage 2
(``msta-correct``) every round."""

from __future__ import annotations

import csv
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from msta_data.budget import TimeLimitReached, passed
from msta_data.windows import WindowDataset
from policies.base import CheckpointError, StudentPolicy
from train.config import LoopConfig
from train.optim import make_optimizer, make_scheduler
from train.sampling import WindowSampler
from train.state import restore_checkpoint, save_checkpoint
from train.step import train_step, validate

CSV_FIELDS = ("step", "lr", "loss", "action_mse", "grad_norm", "samples_per_s",
              "val_loss", "val_loss_unmasked", "val_action_mse")


@dataclass
class FitResult:
    """What :func:`fit` reports."""

    step: int
    samples_per_s: float
    train: dict[str, float]
    val: dict[str, float]


# ----- metrics ---------------------------------------------------------------------------
class MetricsLogger:
    """Rows to ``metrics.csv`` and scalars to TensorBoard; a resume drops later rows.

    Args:
        out: run directory.
        start_step: the step training (re)starts from; CSV rows and TensorBoard events
            after it (written by a killed run) are discarded.
    """

    def __init__(self, out: Path, start_step: int) -> None:
        from torch.utils.tensorboard import SummaryWriter

        self.path = out / "metrics.csv"
        rows: list[dict[str, str]] = []
        if self.path.exists():
            with open(self.path, newline="") as f:
                rows = [r for r in csv.DictReader(f) if int(r["step"]) <= start_step]
        self._file = open(self.path, "w", newline="")  # noqa: SIM115 (closed in close())
        self._csv = csv.DictWriter(self._file, CSV_FIELDS)
        self._csv.writeheader()
        self._csv.writerows(rows)
        self._file.flush()
        self.tb = SummaryWriter(str(out / "tensorboard"), purge_step=start_step + 1)

    def log(self, step: int, row: dict[str, float]) -> None:
        self._csv.writerow({"step": step, **{k: f"{v:.6g}" for k, v in row.items()}})
        self._file.flush()
        for k, v in row.items():
            tag = f"val/{k[4:]}" if k.startswith("val_") else f"train/{k}"
            self.tb.add_scalar(tag, v, step)

    def close(self) -> None:
        self._file.close()
        self.tb.close()


# ----- weight averaging ------------------------------------------------------------------
class WeightEMA:
    """Exponential moving average of a policy's parameters (``LoopConfig.ema_decay``).

    After step t the average moves towards the weights by ``1 - min(decay, (1+t)/(10+t))``
    (the usual warm-up, so early steps do not freeze the start weights in). Its state is
    one safetensors file in the checkpoint's training state, so a resumed run averages on
    exactly as an uninterrupted one.

    Args:
        policy: the trained policy.
        decay: per-step decay in (0, 1).
    """

    FILE = "ema.safetensors"

    def __init__(self, policy: StudentPolicy, decay: float) -> None:
        self.decay = decay
        self.params = dict(policy.named_parameters())
        self.avg = {n: p.detach().clone() for n, p in self.params.items()}
        self.t = 0

    @torch.no_grad()
    def update(self) -> None:
        self.t += 1
        w = 1.0 - min(self.decay, (1.0 + self.t) / (10.0 + self.t))
        for n, p in self.params.items():
            self.avg[n].lerp_(p.detach(), w)

    @torch.no_grad()
    def apply(self) -> None:
        """Copy the averaged weights into the policy."""
        for n, p in self.params.items():
            p.copy_(self.avg[n])

    def save(self, directory: Path) -> None:
        from safetensors.torch import save_file

        save_file({n: v.contiguous() for n, v in self.avg.items()}, str(directory / self.FILE),
                  metadata={"t": str(self.t), "decay": repr(self.decay)})

    def load(self, directory: Path) -> None:
        from safetensors import safe_open

        path = directory / self.FILE
        if not path.is_file():
            raise CheckpointError(f"{directory}: no {self.FILE}, but this run averages weights "
                                  "(--ema_decay); resume with the --ema_decay it was started with")
        with safe_open(str(path), "pt", device="cpu") as f:
            meta = f.metadata() or {}
            if set(f.keys()) != set(self.avg):
                raise CheckpointError(f"{path}: its tensors are not this policy's parameters")
            for n in self.avg:
                self.avg[n].copy_(f.get_tensor(n))
        self.t = int(meta.get("t", 0))


# ----- the loop --------------------------------------------------------------------------
def fit(policy: StudentPolicy, train_ds: Any, val_ds: Any | None, cfg: LoopConfig,
        out: Path, resume: bool, weights: np.ndarray | None = None,
        on_step: Callable[[int, dict[str, float]], None] | None = None,
        desc: str = "train", deadline: float | None = None) -> FitResult:
    """Train ``policy`` on random windows of ``train_ds`` for ``cfg.steps`` steps.

    Args:
        policy: the student, already on its device (trained in place).
        train_ds: a ``WindowDataset`` whose batches carry the action target.
        val_ds: validation windows, or None.
        cfg: optimizer, schedule, logging and checkpoint settings.
        out: run directory (metrics, TensorBoard, checkpoints).
        resume: continue from ``out/checkpoints/last`` when it exists.
        weights: optional per-window sampling weights (stage 2 favours recent rounds).
        on_step: called as ``on_step(step, metrics)`` after every step (and its logging and
            checkpoint); an exception raised there stops training like a crash would.
        desc: progress-bar label.
        deadline: a ``time.monotonic()`` time (``--max_minutes``): once it has passed, the
            step in progress ends with a checkpoint and :class:`TimeLimitReached` is raised
            (``resume`` continues from that step).
    """
    if cfg.dummy_tokens and not policy.supports_dummy_tokens:
        raise ValueError(f"dummy_tokens={cfg.dummy_tokens}: a {policy.config.type!r} student "
                         "has no token input to append them to (MSTA students only)")
    out.mkdir(parents=True, exist_ok=True)
    mask_ratio = _mask(policy, cfg.mask_ratio)
    policy.config.mask_ratio = mask_ratio  # the saved config.json says what was used
    optimizer = make_optimizer(policy, cfg.lr, cfg.weight_decay, cfg.optimizer)
    scheduler = make_scheduler(optimizer, cfg)
    sampler = WindowSampler(len(train_ds), cfg.batch_size, cfg.seed, weights)
    gen = torch.Generator(device=policy.device).manual_seed(cfg.seed)
    state = {"optimizer": optimizer, "scheduler": scheduler, "sampler": sampler,
             "mask_generator": gen}
    step = 0
    ema = WeightEMA(policy, cfg.ema_decay) if cfg.ema_decay > 0 else None
    if resume and (out / "checkpoints" / "last").exists():
        step = restore_checkpoint(out, policy, state, ema, max_step=cfg.steps)
        scheduler.lr_lambdas[0].total = cfg.steps  # a raised --steps stretches the cosine
    logger = MetricsLogger(out, step)
    bar = tqdm(total=cfg.steps, initial=step, disable=not cfg.progress, desc=desc, unit="step")
    train_time, samples, metrics, val = 0.0, 0, {}, {}
    try:
        while step < cfg.steps:
            t0 = time.perf_counter()
            batch = train_ds.get_batch(sampler.next_batch())
            metrics = train_step(policy, optimizer, scheduler, batch, cfg.grad_clip,
                                 mask_ratio, gen, dummy_tokens=cfg.dummy_tokens)
            if ema is not None:
                ema.update()
            train_time += time.perf_counter() - t0
            samples += cfg.batch_size
            step += 1
            if ema is not None and step == cfg.steps:
                ema.apply()  # the result is the average: validated and saved below
            row: dict[str, float] = {}
            if step % cfg.log_every == 0 or step == cfg.steps:
                row.update({k: metrics[k] for k in ("lr", "loss", "action_mse", "grad_norm")})
                row["samples_per_s"] = samples / max(train_time, 1e-9)
            if val_ds is not None and ((cfg.eval_every and step % cfg.eval_every == 0)
                                       or step == cfg.steps):
                val = validate(policy, val_ds, cfg.batch_size, cfg.val_samples,
                               mask_ratio, seed=cfg.seed)
                row.update({f"val_{k}": v for k, v in val.items()})
            if row:
                logger.log(step, row)
            stopping = step < cfg.steps and passed(deadline)
            if (cfg.save_every and step % cfg.save_every == 0) or step == cfg.steps or stopping:
                save_checkpoint(out, step, policy, state, ema)
            bar.update(1)
            bar.set_postfix(loss=f"{metrics['loss']:.4f}",
                            samples_s=f"{samples / max(train_time, 1e-9):.0f}")
            if on_step is not None:
                on_step(step, metrics)
            if stopping:
                raise TimeLimitReached(f"{desc}: step {step} of {cfg.steps}, checkpoint saved")
    finally:
        bar.close()
        logger.close()
    return FitResult(step, samples / train_time if train_time else 0.0, metrics, val)


def _mask(policy: StudentPolicy, mask_ratio: float | None) -> float:
    return float(policy.config.mask_ratio if mask_ratio is None else mask_ratio)


def load_windows(root: Path, policy: StudentPolicy, episodes: Sequence[int]) -> Any:
    """A ``WindowDataset`` of the policy's sensors, window and action column."""
    T, key = policy.config.history, policy.config.action_key
    return WindowDataset(root, policy.required_sensors, T, extra_columns=(key,),
                         episodes=episodes)


#: Final validation loss (z-scored actions, unmasked) above which msta-train warns; the
#: mean action scores ~1.0; on the demo's data the MSTA cpu preset reaches 0.08-0.2 and
#: a GRU ~0.07.
NOT_LEARNED_LOSS = 0.5


def warn_if_not_learned(val: dict[str, float]) -> bool:
    """Print a warning when the final unmasked validation loss says the student has not
    learned to use its inputs; returns whether it warned."""
    loss = val.get("loss_unmasked")
    if loss is None or not loss > NOT_LEARNED_LOSS:
        return False
    print(f"WARNING: final val loss_unmasked {loss:.3g} > {NOT_LEARNED_LOSS} (predicting the mean "
          "action scores ~1.0): the student has not learned to use its inputs. Train longer "
          "(--steps), check --lr, or see docs/msta_model.md.", flush=True)
    return True
