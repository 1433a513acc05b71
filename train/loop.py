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

from msta.data.budget import TimeLimitReached, passed
from msta.data.windows import WindowDataset
from msta.policies.base import StudentPolicy
from msta.train.config import LoopConfig
from msta.train.ddp import FitJob, Group, current, join, launched, leave
from msta.train.optim import WeightEMA, make_optimizer, make_scheduler
from msta.train.sampling import WindowSampler
from msta.train.state import restore_checkpoint, save_checkpoint
from msta.train.step import batch_absent, draw_sensor_dropout, draw_step_mask, train_step, validate

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
        # lazy: TensorBoard loads only when a run logs
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


# ----- the loop --------------------------------------------------------------------------
@dataclass
class _Run:
    """What one :func:`fit` call trains with: the optimizer and its companions, the state a
    checkpoint saves, the step reached, and the speed counters."""

    optimizer: Any
    scheduler: Any
    sampler: WindowSampler
    gen: torch.Generator
    ema: WeightEMA | None
    mask_ratio: float
    step: int = 0
    train_time: float = 0.0
    samples: int = 0
    group: Group | None = None  # under torchrun (msta.train.ddp)
    loss_fn: Any = None  # policy.loss inside DDP, under torchrun

    @property
    def main(self) -> bool:
        """This process writes (the only one, or rank 0 of a torchrun job)."""
        return self.group is None or self.group.main

    @property
    def state(self) -> dict[str, Any]:
        return {"optimizer": self.optimizer, "scheduler": self.scheduler,
                "sampler": self.sampler, "mask_generator": self.gen}

    def samples_per_s(self) -> float:
        return self.samples / max(self.train_time, 1e-9)


def _start(policy: StudentPolicy, n: int, cfg: LoopConfig, out: Path, resume: bool,
           weights: np.ndarray | None, group: Group | None = None) -> _Run:
    """Optimizer, schedule, sampler, mask generator and weight average, restored from
    ``out/checkpoints/last`` when resuming (by every rank of a torchrun job)."""
    if cfg.mask_ratio is None:
        raise ValueError("fit needs the mask ratio it trains at: resolve it with "
                         "msta.train.config.training_mask_ratio first")
    mask_ratio = cfg.mask_ratio
    if cfg.sensor_dropout and not policy.supports_absent:
        raise ValueError(f"--sensor_dropout needs a student that removes channels per sample; "
                         f"{policy.config.type} cannot")
    if cfg.sensor_dropout and group is not None:
        raise ValueError("--sensor_dropout does not run under torchrun (one process only)")
    optimizer = make_optimizer(policy, cfg.lr, cfg.weight_decay, cfg.optimizer)
    scheduler = make_scheduler(optimizer, cfg)
    sampler = WindowSampler(n, cfg.batch_size, cfg.seed, weights)
    gen = torch.Generator(device=policy.device).manual_seed(cfg.seed)
    ema = WeightEMA(policy, cfg.ema_decay) if cfg.ema_decay > 0 else None
    run = _Run(optimizer, scheduler, sampler, gen, ema, mask_ratio, group=group)
    if resume and (out / "checkpoints" / "last").exists():
        run.step = restore_checkpoint(out, policy, run.state, ema, max_step=cfg.steps)
        scheduler.lr_lambdas[0].total = cfg.steps  # a raised --steps stretches the cosine
    if group is not None:  # after the restore: DDP starts from rank 0's weights
        run.loss_fn = group.wrap(policy, cfg.batch_size)
    return run


def _one_step(policy: StudentPolicy, train_ds: Any, cfg: LoopConfig,
              run: _Run) -> dict[str, float]:
    """One optimizer step (and the weight average's); the result is the average at the end."""
    t0 = time.perf_counter()
    rows = run.sampler.next_batch()  # the global batch: the same for any number of processes
    rows = rows if run.group is None else run.group.shard(rows)
    batch = train_ds.get_batch(rows)
    absent = batch_absent(train_ds, rows, draw_sensor_dropout(
        policy, len(rows), cfg.sensor_dropout, run.gen) if cfg.sensor_dropout else None)
    mask = draw_step_mask(run.mask_ratio, cfg.unmasked_share, run.gen)
    metrics = train_step(policy, run.optimizer, run.scheduler, batch, cfg.grad_clip,
                         mask, run.gen, dummy_tokens=cfg.dummy_tokens,
                         loss_fn=run.loss_fn, absent=absent)
    if run.ema is not None:
        run.ema.update()
    run.train_time += time.perf_counter() - t0
    run.samples += cfg.batch_size
    run.step += 1
    if run.ema is not None and run.step == cfg.steps:
        run.ema.apply()  # the result is the average: validated and saved below
    return metrics


def _log_row(policy: StudentPolicy, val_ds: Any | None, cfg: LoopConfig, run: _Run,
             metrics: dict[str, float]) -> tuple[dict[str, float], dict[str, float] | None]:
    """(the metrics row due at this step, empty when none is; the validation when it ran)."""
    row: dict[str, float] = {}
    step, val = run.step, None
    if step % cfg.log_every == 0 or step == cfg.steps:
        row.update({k: metrics[k] for k in ("lr", "loss", "action_mse", "grad_norm")})
        if run.group is not None:  # each rank's loss is its share's: their mean
            row.update(run.group.mean({k: row[k] for k in ("loss", "action_mse")}))
        row["samples_per_s"] = run.samples_per_s()
    if val_ds is not None and ((cfg.eval_every and step % cfg.eval_every == 0)
                               or step == cfg.steps):
        val = validate(policy, val_ds, cfg.batch_size, cfg.val_samples, run.mask_ratio,
                       seed=cfg.seed)
        row.update({f"val_{k}": v for k, v in val.items()})
    return row, val


def fit(policy: StudentPolicy, train_ds: Any, val_ds: Any | None, cfg: LoopConfig,
        out: Path, resume: bool, weights: np.ndarray | None = None,
        on_step: Callable[[int, dict[str, float]], None] | None = None,
        desc: str = "train", deadline: float | None = None) -> FitResult:
    """Train ``policy`` on random windows of ``train_ds`` for ``cfg.steps`` steps.

    Args:
        policy: the student, already on its device (trained in place; its config is left
            as it is).
        train_ds: a ``WindowDataset`` whose batches carry the action target.
        val_ds: validation windows, or None.
        cfg: optimizer, schedule, logging and checkpoint settings; ``mask_ratio`` resolved
            (:func:`msta.train.config.training_mask_ratio`, by the stage that calls).
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
    group = current()
    if group is not None:  # under torchrun: the other ranks train this loop with rank 0
        group.send(FitJob.of(policy, train_ds, cfg, out, resume, weights, deadline is not None))
    return _fit(policy, train_ds, val_ds, cfg, out, resume, weights, on_step, desc, deadline,
                group)


def _fit(policy: StudentPolicy, train_ds: Any, val_ds: Any | None, cfg: LoopConfig,
         out: Path, resume: bool, weights: np.ndarray | None,
         on_step: Callable[[int, dict[str, float]], None] | None, desc: str,
         deadline: float | None, group: Group | None, sync_stop: bool = False) -> FitResult:
    """:func:`fit` on this process (rank 0 writes; ``sync_stop``: rank 0 has a deadline)."""
    if group is None or group.main:
        out.mkdir(parents=True, exist_ok=True)
    run = _start(policy, len(train_ds), cfg, out, resume, weights, group)
    logger = MetricsLogger(out, run.step) if run.main else None
    bar = tqdm(total=cfg.steps, initial=run.step, disable=not (cfg.progress and run.main),
               desc=desc, unit="step")
    metrics: dict[str, float] = {}
    val: dict[str, float] = {}
    try:
        while run.step < cfg.steps:
            metrics = _one_step(policy, train_ds, cfg, run)
            row, new_val = _log_row(policy, val_ds, cfg, run, metrics)
            val = val if new_val is None else new_val
            metrics.update({k: row[k] for k in ("loss", "action_mse") if k in row})  # ranks' mean
            if row and logger is not None:
                logger.log(run.step, row)
            stopping = run.step < cfg.steps and passed(deadline)
            if group is not None and (sync_stop or deadline is not None):
                stopping = group.any(stopping)  # every rank stops after the same step
            if run.main and ((cfg.save_every and run.step % cfg.save_every == 0)
                             or run.step == cfg.steps or stopping):
                save_checkpoint(out, run.step, policy, run.state, run.ema)
            bar.update(1)
            bar.set_postfix(loss=f"{metrics['loss']:.4f}", samples_s=f"{run.samples_per_s():.0f}")
            if on_step is not None:
                on_step(run.step, metrics)
            if stopping and run.main:
                raise TimeLimitReached(f"{desc}: step {run.step} of {cfg.steps}, checkpoint saved")
            if stopping:
                break
    finally:
        bar.close()
        if logger is not None:
            logger.close()
    return FitResult(run.step, run.samples / run.train_time if run.train_time else 0.0,
                     metrics, val)


def follow(group: Group) -> None:
    """A torchrun rank other than 0: train every loop rank 0 starts (:class:`FitJob`), with
    it, until its command ends (:func:`rank0_runs`)."""
    while (job := group.receive()) is not None:
        torch.set_num_threads(job.threads)
        policy = job.policy.to(group.device(job.device))
        dataset = job.dataset.load() if hasattr(job.dataset, "load") else job.dataset
        _fit(policy, dataset, None, job.cfg, job.out, job.resume, job.weights, None, "train",
             None, group, job.sync_stop)


def rank0_runs[T](run: Callable[[], T], batch_size: int) -> T:
    """Run a training command in a plain process, or as a torchrun job
    (:mod:`msta.train.ddp`).

    A plain process: ``run()``. Under torchrun: rank 0 returns ``run()`` (then tells the
    other ranks to stop); every other rank trains each :func:`fit` rank 0 starts
    (:func:`follow`) and then exits the process (``SystemExit(0)``): it never returns. When
    rank 0 fails, it exits with its error and torchrun stops the others; when it stops at
    ``--max_minutes``, the others end with it.

    Args:
        run: the command.
        batch_size: the command's global batch (checked to split over the ranks first).
    """
    where = launched()
    if where is None:
        return run()
    group = join(where, batch_size)
    if not group.main:
        follow(group)
        leave()
        raise SystemExit(0)
    try:
        result = run()  # another error: rank 0 exits with it and torchrun stops the others
    except TimeLimitReached:  # at a safe point: every rank is waiting for the next loop
        group.send(None)
        leave()
        raise
    group.send(None)
    leave()
    return result


def load_windows(root: Path, policy: StudentPolicy, episodes: Sequence[int]) -> Any:
    """A ``WindowDataset`` of the policy's sensors, window and target columns (the action,
    and what else the policy trains on: ``policy.target_columns``)."""
    return WindowDataset(root, policy.required_sensors, policy.config.history,
                         extra_columns=policy.target_columns, episodes=episodes)


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
