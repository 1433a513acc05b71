"""Stage 1 itself (``msta-train``'s run, apart from its command line in
:mod:`msta.train.offline` so that ``--help`` answers before torch loads): the output
directory's checks, the resume check, and :func:`train`."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import draccus
import torch

from msta.data.budget import deadline_after
from msta.data.layout import LOCK_NAME
from msta.data.locate import locate_dataset
from msta.data.locking import hold_directory
from msta.data.msta_json import dataset_robot
from msta.data.stats import load_stats
from msta.data.threads import run_threads
from msta.data.windows import episode_split
from msta.policies.factory import make_policy, select_device
from msta.train.config import training_mask_ratio
from msta.train.loop import fit, load_windows, warn_if_not_learned
from msta.train.optim import seed_everything
from msta.train.push import push_stage1
from msta.train.state import atomic_json
from msta.train.train_config import RESUME_FIELDS, TrainConfig

# ----- dataset and output directory ------------------------------------------------------
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


def check_resume_config(out: Path, cfg: TrainConfig) -> None:
    saved = json.loads((out / "train_config.json").read_text())
    now = draccus.encode(cfg)
    bad = [k for k in RESUME_FIELDS if saved.get(k) != now.get(k)]
    if bad:
        raise ValueError(f"--resume=true with a different {bad} than {out / 'train_config.json'}"
                         f": saved {[saved.get(k) for k in bad]}, now {[now.get(k) for k in bad]}")


def train(cfg: TrainConfig, on_step: Callable[[int, dict[str, float]], None] | None = None
          ) -> Path:
    """Run stage 1 and return ``output_dir/final``.

    Args:
        cfg: the parsed configuration.
        on_step: forwarded to :func:`fit` (tests use it to interrupt a run).

    The dataset is verified (``msta.data.locate.locate_dataset``) before ``output_dir`` is created; the
    run directory is then locked (``output_dir/.msta.lock``: a second msta-train on it gets
    a one-line error and changes nothing) until the run ends.
    """
    deadline = deadline_after(cfg.max_minutes)
    out = Path(cfg.output_dir)
    root = locate_dataset(cfg.dataset, "--dataset")  # verified before anything is created
    with hold_directory(out, "another msta-train run"):
        return _train_locked(cfg, root, out, on_step, deadline)


def _train_locked(cfg: TrainConfig, root: Path, out: Path,
                  on_step: Callable[[int, dict[str, float]], None] | None,
                  deadline: float | None = None) -> Path:
    """:func:`train` once the run directory is locked."""
    resuming = prepare_output(out, cfg.resume)
    if resuming:
        check_resume_config(out, cfg)
    torch.set_num_threads(run_threads(out, cfg.num_threads, resuming))
    device = select_device(cfg.device)
    seed_everything(cfg.seed)
    policy = make_policy(cfg.policy, load_stats(root)).to(device)
    # every checkpoint records the robot the dataset simulated (msta-correct, msta-eval check it)
    policy.config.robots = (dataset_robot(root),)
    train_eps, val_eps = episode_split(root, cfg.val_fraction, cfg.seed)
    train_ds = load_windows(root, policy, train_eps)
    val_ds = load_windows(root, policy, val_eps) if val_eps else None
    if not resuming:  # without max_minutes: how long each call ran is not the run's config
        atomic_json(out / "train_config.json",
                    {k: v for k, v in draccus.encode(cfg).items() if k != "max_minutes"})
    # the checkpoint's config.json records the ratio stage 1 trains at (--mask_ratio, when
    # given, over --policy.mask_ratio); stage 2 reads it there and keeps it
    policy.config.mask_ratio = training_mask_ratio(cfg.mask_ratio, policy.config.mask_ratio)
    n_params = sum(p.numel() for p in policy.parameters())
    print(f"dataset {root}: {len(train_eps)} train episodes ({len(train_ds):,} windows), "
          f"{len(val_eps)} validation; {cfg.policy.type} policy with {n_params:,} parameters "
          f"on {device}, {torch.get_num_threads()} threads")
    res = fit(policy, train_ds, val_ds, replace(cfg.loop_part(), mask_ratio=policy.config.mask_ratio),
              out, resuming, on_step=on_step, deadline=deadline)
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
