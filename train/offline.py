"""``msta-train``: stage 1, offline behaviour cloning of the teacher's labels.

    msta-train --dataset=outputs/datasets/a1_teacher --policy.preset=cpu \\
        --output_dir=outputs/train/msta_cpu --steps=3000 --batch_size=64
    msta-train ... --resume=true          # continue exactly where a killed run stopped

Output directory::

    train_config.json                 the parsed configuration
    metrics.csv, tensorboard/         train and validation metrics
    checkpoints/<step>/pretrained_model/   config.json, model.safetensors, processor.json
    checkpoints/<step>/training_state/     optimizer, scheduler, RNG, sampler (no pickle)
    checkpoints/last -> <step>
    final/                            the final policy (``<PolicyClass>.from_pretrained``)

:func:`fit` is the training loop itself; stage 2 (``train/online.py``) calls it every round.
"""

from __future__ import annotations

import csv
import json
import os
import shutil
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import draccus
import numpy as np
import torch
from safetensors import SafetensorError
from tqdm import tqdm

from msta_data.errors import DatasetError, DirectoryLockedError
from msta_data.locking import LOCK_NAME, lock_directory
from policies.base import WEIGHTS_NAME, CheckpointError, PolicyConfig, StudentPolicy, load_weights
from policies.msta import MSTAConfig
from train.common import (
    LoopConfig,
    WindowSampler,
    atomic_json,
    load_training_state,
    make_optimizer,
    make_scheduler,
    parse_cli,
    save_training_state,
    seed_everything,
    select_device,
)
from train.push import PushError, check_push_to, push_stage1
from train.step import train_step, validate

CSV_FIELDS = ("step", "lr", "loss", "action_mse", "grad_norm", "samples_per_s",
              "val_loss", "val_loss_unmasked", "val_action_mse")
#: Fields that must match the saved train_config.json when resuming.
RESUME_FIELDS = ("dataset", "policy", "batch_size", "seed", "val_fraction", "mask_ratio")


@dataclass
class TrainConfig(LoopConfig):
    """Args:
        dataset: local dataset root, or a hub id ``[datasets/]user/name[@revision]``.
        policy: the student (``--policy.type=msta``, ``--policy.preset=cpu``,
            ``--policy.<field>=...``).
        output_dir: where checkpoints and metrics go (must be new unless ``resume``).
        resume: continue from ``output_dir/checkpoints/last``.
        val_fraction: share of episodes held out for validation (split by episode).
        device: ``auto`` (CUDA when available, else CPU), ``cpu``, ``cuda``, ``cuda:1``...
        num_threads: torch intra-op threads (0 = torch's default).
        push_to: hub model repo ``user/name``: push ``final/`` with tag ``stage1`` and a
            model card (HF_ENDPOINT / HF_TOKEN); empty = no push. See ``train/push.py``.
        push_private: create that repo as private.
    """

    dataset: str = ""
    policy: PolicyConfig = field(default_factory=MSTAConfig)
    output_dir: str = "outputs/train/msta"
    resume: bool = False
    val_fraction: float = 0.1
    device: str = "auto"
    num_threads: int = 0
    push_to: str = ""
    push_private: bool = False

    def __post_init__(self) -> None:
        super().__post_init__()
        check_push_to(self.push_to)
        if not 0.0 <= self.val_fraction < 1.0:
            raise ValueError(f"val_fraction={self.val_fraction} must be in [0, 1)")
        if self.num_threads < 0:
            raise ValueError(f"num_threads={self.num_threads} must be >= 0")


@dataclass
class FitResult:
    """What :func:`fit` reports."""

    step: int
    samples_per_s: float
    train: dict[str, float]
    val: dict[str, float]


# ----- dataset and output directory ------------------------------------------------------
def resolve_dataset(spec: str) -> Path:
    """A local, verified dataset root for ``spec`` (a directory, or a hub id pulled once).

    Args:
        spec: a directory, or ``[datasets/]user/name[@revision]`` (``msta_data.locate``: a
            spec written as a path is never looked up on a hub, and no hub is asked unless
            ``HF_ENDPOINT`` is set).

    Raises:
        FileNotFoundError: no such directory (absolute path named) or not a dataset.
        DatasetIntegrityError: a committed file is missing or changed (file named).
    """
    from msta_data.integrity import verify_dataset
    from msta_data.locate import locate

    if not spec:
        raise ValueError("--dataset is required (a dataset root or a hub id)")
    path = locate(spec, "dataset", "--dataset")
    if not (path / "meta" / "info.json").is_file():
        raise FileNotFoundError(f"--dataset {spec!r}: {path / 'meta' / 'info.json'} missing "
                                "(not a LeRobot v3.0 dataset)")
    verify_dataset(path, "full")
    return path


#: What a run directory holds besides checkpoints (a run killed before its first checkpoint
#: leaves only these, and starts again from step 0).
RUN_ARTIFACTS = frozenset({"train_config.json", "metrics.csv", "tensorboard", "checkpoints",
                           LOCK_NAME})


def prepare_output(out: Path, resume: bool) -> bool:
    """Refuse to mix runs: a fresh run needs an empty directory, a resume a checkpoint.

    A directory holding only the artifacts of a run killed before its first checkpoint
    (``RUN_ARTIFACTS``, no ``checkpoints/last``) is cleared and the run starts from step 0,
    with or without ``--resume``.

    Returns:
        True when training continues from ``checkpoints/last``.
    """
    last = out / "checkpoints" / "last"
    if last.exists():
        if not resume:
            raise FileExistsError(f"{out} holds a run (checkpoint {last.resolve().name}); pass "
                                  "--resume=true to continue it or choose another --output_dir")
        return True
    names = {p.name for p in out.iterdir()} if out.is_dir() else set()
    ckpts = out / "checkpoints"
    unfinished = names and names <= RUN_ARTIFACTS and (
        not ckpts.is_dir() or all(p.name.endswith(".tmp") for p in ckpts.iterdir()))
    if unfinished and names - {LOCK_NAME}:
        print(f"msta-train: {out} holds a run killed before its first checkpoint; starting it "
              "again from step 0", flush=True)
        for name in names - {LOCK_NAME}:
            path = out / name
            shutil.rmtree(path) if path.is_dir() else path.unlink()
    elif names - {LOCK_NAME}:
        if resume:
            raise FileNotFoundError(f"--resume=true but {last} does not exist and {out} holds "
                                    "other files (nothing to resume; choose another "
                                    "--output_dir)")
        raise FileExistsError(f"{out} is not empty; pass --resume=true to continue that run or "
                              "choose another --output_dir")
    return False


def lock_run(out: Path) -> int:
    """Create ``out`` and take its lock (one msta-train per directory); returns the fd."""
    out.mkdir(parents=True, exist_ok=True)
    return lock_directory(out, "another msta-train run")


def check_resume_config(out: Path, cfg: TrainConfig) -> None:
    saved = json.loads((out / "train_config.json").read_text())
    now = draccus.encode(cfg)
    bad = [k for k in RESUME_FIELDS if saved.get(k) != now.get(k)]
    if bad:
        raise ValueError(f"--resume=true with a different {bad} than {out / 'train_config.json'}"
                         f": saved {[saved.get(k) for k in bad]}, now {[now.get(k) for k in bad]}")


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


# ----- checkpoints -----------------------------------------------------------------------
def save_checkpoint(out: Path, step: int, policy: StudentPolicy, state: dict[str, Any],
                    ema: WeightEMA | None = None) -> Path:
    """``checkpoints/<step>/`` written under a temporary name, renamed, then ``last`` moved."""
    ckpts = out / "checkpoints"
    final, tmp = ckpts / f"{step:06d}", ckpts / f"{step:06d}.tmp"
    shutil.rmtree(tmp, ignore_errors=True)
    policy.save_pretrained(tmp / "pretrained_model")
    save_training_state(tmp / "training_state", step, **state)
    if ema is not None:
        ema.save(tmp / "training_state")
    shutil.rmtree(final, ignore_errors=True)
    os.replace(tmp, final)
    link = ckpts / "last.tmp"
    link.unlink(missing_ok=True)
    link.symlink_to(final.name)
    os.replace(link, ckpts / "last")
    return final


def restore_checkpoint(out: Path, policy: StudentPolicy, state: dict[str, Any],
                       ema: WeightEMA | None = None) -> int:
    """Load ``checkpoints/last`` into the policy and the loop state; returns its step."""
    last = (out / "checkpoints" / "last").resolve()
    weights = last / "pretrained_model" / WEIGHTS_NAME
    if not weights.is_file():
        raise FileNotFoundError(f"checkpoint {last} has no {weights.name}")
    load_weights(policy, weights)
    if ema is not None:
        ema.load(last / "training_state")
    try:
        return load_training_state(last / "training_state", **state)
    except (ValueError, KeyError, TypeError, RuntimeError, SafetensorError) as e:
        raise CheckpointError(f"{last / 'training_state'}: cannot restore ({type(e).__name__}: "
                              f"{str(e).splitlines()[0] if str(e) else ''})") from None


# ----- the loop --------------------------------------------------------------------------
def fit(policy: StudentPolicy, train_ds: Any, val_ds: Any | None, cfg: LoopConfig,
        out: Path, resume: bool, weights: np.ndarray | None = None,
        on_step: Callable[[int, dict[str, float]], None] | None = None,
        desc: str = "train") -> FitResult:
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
    """
    out.mkdir(parents=True, exist_ok=True)
    mask_ratio = _mask(policy, cfg.mask_ratio)
    if hasattr(policy.config, "mask_ratio"):  # the saved config.json says what was used
        policy.config.mask_ratio = mask_ratio
    optimizer = make_optimizer(policy, cfg.lr, cfg.weight_decay)
    scheduler = make_scheduler(optimizer, cfg)
    sampler = WindowSampler(len(train_ds), cfg.batch_size, cfg.seed, weights)
    gen = torch.Generator(device=policy.device).manual_seed(cfg.seed)
    state = {"optimizer": optimizer, "scheduler": scheduler, "sampler": sampler,
             "mask_generator": gen}
    step = 0
    ema = WeightEMA(policy, cfg.ema_decay) if cfg.ema_decay > 0 else None
    if resume and (out / "checkpoints" / "last").exists():
        step = restore_checkpoint(out, policy, state, ema)
        scheduler.lr_lambdas[0].total = cfg.steps  # a raised --steps stretches the cosine
    logger = MetricsLogger(out, step)
    bar = tqdm(total=cfg.steps, initial=step, disable=not cfg.progress, desc=desc, unit="step")
    train_time, samples, metrics, val = 0.0, 0, {}, {}
    try:
        while step < cfg.steps:
            t0 = time.perf_counter()
            batch = train_ds.get_batch(sampler.next_batch())
            metrics = train_step(policy, optimizer, scheduler, batch, cfg.grad_clip,
                                 mask_ratio, gen)
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
            if (cfg.save_every and step % cfg.save_every == 0) or step == cfg.steps:
                save_checkpoint(out, step, policy, state, ema)
            bar.update(1)
            bar.set_postfix(loss=f"{metrics['loss']:.4f}",
                            samples_s=f"{samples / max(train_time, 1e-9):.0f}")
            if on_step is not None:
                on_step(step, metrics)
    finally:
        bar.close()
        logger.close()
    return FitResult(step, samples / train_time if train_time else 0.0, metrics, val)


def _mask(policy: StudentPolicy, mask_ratio: float | None) -> float:
    return float(getattr(policy.config, "mask_ratio", 0.0) if mask_ratio is None else mask_ratio)


# ----- stage 1 ---------------------------------------------------------------------------
def load_windows(root: Path, policy: StudentPolicy, episodes: Sequence[int]) -> Any:
    """A ``WindowDataset`` of the policy's sensors, window and action column."""
    from msta_data.windows import WindowDataset

    T = int(getattr(policy.config, "history", 15))
    key = getattr(policy.config, "action_key", "action")
    return WindowDataset(root, policy.required_sensors, T, extra_columns=(key,),
                         episodes=episodes)


def train(cfg: TrainConfig, on_step: Callable[[int, dict[str, float]], None] | None = None
          ) -> Path:
    """Run stage 1 and return ``output_dir/final``.

    Args:
        cfg: the parsed configuration.
        on_step: forwarded to :func:`fit` (tests use it to interrupt a run).

    The dataset is verified (``resolve_dataset``) before ``output_dir`` is created; the
    run directory is then locked (``output_dir/.msta.lock``: a second msta-train on it gets
    a one-line error and changes nothing) until the run ends.
    """
    out = Path(cfg.output_dir)
    root = resolve_dataset(cfg.dataset)  # verified before anything is created
    lock = lock_run(out)
    try:
        return _train_locked(cfg, root, out, on_step)
    finally:
        os.close(lock)


def _train_locked(cfg: TrainConfig, root: Path, out: Path,
                  on_step: Callable[[int, dict[str, float]], None] | None) -> Path:
    """:func:`train` once the run directory is locked."""
    from msta_data.stats import load_stats
    from msta_data.windows import episode_split
    from policies.factory import make_policy

    resuming = prepare_output(out, cfg.resume)
    if resuming:
        check_resume_config(out, cfg)
    if cfg.num_threads:
        torch.set_num_threads(cfg.num_threads)
    device = select_device(cfg.device)
    seed_everything(cfg.seed)
    policy = make_policy(cfg.policy, load_stats(root)).to(device)
    train_eps, val_eps = episode_split(root, cfg.val_fraction, cfg.seed)
    train_ds = load_windows(root, policy, train_eps)
    val_ds = load_windows(root, policy, val_eps) if val_eps else None
    if not resuming:
        atomic_json(out / "train_config.json", draccus.encode(cfg))
    n_params = sum(p.numel() for p in policy.parameters())
    print(f"dataset {root}: {len(train_eps)} train episodes ({len(train_ds):,} windows), "
          f"{len(val_eps)} validation; {cfg.policy.type} policy with {n_params:,} parameters "
          f"on {device}, {torch.get_num_threads()} threads")
    res = fit(policy, train_ds, val_ds, cfg.loop_part(), out, resuming, on_step=on_step)
    final = policy.save_pretrained(out / "final")
    shutil.copy(out / "train_config.json", final / "train_config.json")
    val = ", ".join(f"val {k} {v:.4g}" for k, v in res.val.items())
    print(f"trained {res.step} steps ({res.samples_per_s:.1f} samples/s this run); "
          f"train loss {res.train.get('loss', float('nan')):.4g}{'; ' + val if val else ''}"
          f"\nfinal policy: {final}")
    warn_if_not_learned(res.val)
    if cfg.push_to:
        push_stage1(cfg, root, out, final)
    return final


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


#: Errors a user's input causes (a damaged dataset, a locked directory, a bad checkpoint or
#: value): the CLIs print them as one line naming the file, without a traceback.
USER_ERRORS = (PushError, DatasetError, DirectoryLockedError, CheckpointError,
               FileNotFoundError, FileExistsError, ValueError)


def main(argv: Sequence[str] | None = None) -> None:
    cfg = parse_cli(TrainConfig, argv, prog="msta-train")
    try:
        train(cfg)
    except USER_ERRORS as e:
        raise SystemExit(f"msta-train: error: {e}") from None


if __name__ == "__main__":
    main()
