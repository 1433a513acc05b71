"""Stage 1 itself (``msta-train``'s run, apart from its command line in
:mod:`msta.train.offline` so that ``--help`` answers before torch loads): the output
directory's checks, the resume check, and :func:`train`."""

from __future__ import annotations

import dataclasses
import json
import shutil
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path

import draccus
import numpy as np
import torch

from msta.data import sensors
from msta.data.budget import deadline_after
from msta.data.features import load_info
from msta.data.layout import LOCK_NAME
from msta.data.locate import locate_dataset
from msta.data.locking import hold_directory
from msta.data.msta_json import dataset_robot
from msta.data.stats import aggregate, load_stats
from msta.data.threads import run_threads
from msta.data.window_union import WindowUnion
from msta.data.windows import WindowDataset, episode_split
from msta.policies.base import StudentPolicy
from msta.policies.config import PolicyConfig
from msta.policies.factory import make_policy, select_device
from msta.train.config import training_mask_ratio
from msta.train.ddp import launched
from msta.train.loop import fit, load_windows, warn_if_not_learned
from msta.train.optim import seed_everything
from msta.train.push import push_stage1
from msta.train.state import atomic_json
from msta.train.train_config import RESUME_FIELDS, RESUME_LEGACY, TrainConfig

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
    bad = [k for k in RESUME_FIELDS if saved.get(k, RESUME_LEGACY.get(k)) != now.get(k)]
    if bad:
        raise ValueError(f"--resume=true with a different {bad} than {out / 'train_config.json'}"
                         f": saved {[saved.get(k) for k in bad]}, now {[now.get(k) for k in bad]}")


def dataset_inputs(policy: PolicyConfig, root: Path, given: bool = False,
                   more: Sequence[Path] = ()) -> PolicyConfig:
    """The student config ``policy`` with inputs the dataset at ``root`` (or one of ``more``)
    records.

    A student left with its class's default inputs (the paper's seven) on a dataset that
    lacks some of them (a Go1 dataset records no ``foot_contact``) reads the defaults the
    dataset has, in their order, and one line says so; the config is returned unchanged when
    the dataset records every input (an A1 dataset: the same student as before).

    Args:
        policy: the student's config.
        root: the dataset root.
        given: the inputs were named by the user (msta-train: ``--policy.input_sensors`` on
            its command line): a sensor the dataset lacks is then an error even when they
            equal the default.
        more: further datasets trained on together (``--more_datasets``): an input one of
            them records is kept.

    Raises:
        ValueError: (one line) named inputs the dataset does not record, or none of the
            default inputs recorded.
    """
    have = {c for r in (root, *more) for c in load_info(r)["features"]}
    missing = [n for n in policy.input_sensors if sensors.get(n).column not in have]
    if not missing:
        return policy
    robot = ", ".join(dict.fromkeys(dataset_robot(r) for r in (root, *more)))
    default = {f.name: f for f in dataclasses.fields(policy)}["input_sensors"].default
    kept = tuple(n for n in policy.input_sensors if n not in missing)
    lacks = (f"the dataset {root} (robot {robot}) does not record {', '.join(missing)}"
             if not more else f"no dataset (robots {robot}) records {', '.join(missing)}")
    if given or policy.input_sensors != default or not kept:
        raise ValueError(f"--policy.input_sensors names {', '.join(missing)} but {lacks}; name "
                         "inputs it records (or record them: msta-collect --extra_sensors)")
    print(f"msta-train: {lacks}: the student reads the default inputs it records, "
          f"--policy.input_sensors=[{','.join(kept)}]", flush=True)
    return replace(policy, input_sensors=kept)


def train(cfg: TrainConfig, on_step: Callable[[int, dict[str, float]], None] | None = None,
          inputs_given: bool = False) -> Path:
    """Run stage 1 and return ``output_dir/final``.

    Args:
        cfg: the parsed configuration.
        on_step: forwarded to :func:`fit` (tests use it to interrupt a run).
        inputs_given: ``cfg.policy.input_sensors`` were named by the user (msta-train:
            ``--policy.input_sensors`` on its command line), so the dataset must record each
            of them; otherwise default inputs the dataset lacks are left out
            (:func:`dataset_inputs`).

    The dataset is verified (``msta.data.locate.locate_dataset``) before ``output_dir`` is created; the
    run directory is then locked (``output_dir/.msta.lock``: a second msta-train on it gets
    a one-line error and changes nothing) until the run ends.
    """
    deadline = deadline_after(cfg.max_minutes)
    out = Path(cfg.output_dir)
    root = locate_dataset(cfg.dataset, "--dataset")  # verified before anything is created
    more = [locate_dataset(d, "--more_datasets") for d in cfg.more_datasets]
    if more and launched():
        raise ValueError("--more_datasets does not run under torchrun (one process only)")
    with hold_directory(out, "another msta-train run"):
        # the student as trained, before train_config.json is written or compared (--resume)
        policy = dataset_inputs(cfg.policy, root, inputs_given, more)
        # every checkpoint records its datasets' robots
        robots = tuple(dict.fromkeys(dataset_robot(r) for r in (root, *more)))
        if policy.robots != robots:
            policy = replace(policy, robots=robots)
        if policy is not cfg.policy:  # an A1 dataset: the config as given
            cfg = replace(cfg, policy=policy)
        return _train_locked(cfg, root, out, on_step, deadline, more)


def union_windows(policy: StudentPolicy, roots: Sequence[Path], seed: int,
                  val_fraction: float) -> tuple[WindowUnion, WindowUnion | None, list, list]:
    """Training and validation windows of several datasets (each split by episode), each
    dataset's of the student's inputs it records; returns them and the episode splits."""
    splits = [episode_split(r, val_fraction, seed) for r in roots]
    inputs = policy.required_sensors
    parts: tuple[list, list] = ([], [])
    for r, split in zip(roots, splits):
        have = load_info(r)["features"]
        own = [s for s in inputs if sensors.get(s).column in have]
        if len(own) < len(inputs):
            policy.check_absent()  # its samples go without those inputs
        for part, eps in zip(parts, split):
            if eps:
                part.append(WindowDataset(r, own, policy.config.history,
                                          extra_columns=policy.target_columns, episodes=eps))
    train_ds = WindowUnion(parts[0], inputs)
    val_ds = WindowUnion(parts[1], inputs) if parts[1] else None
    return train_ds, val_ds, [e for s in splits for e in s[0]], [e for s in splits for e in s[1]]


def union_stats(roots: Sequence[Path]) -> dict:
    """The datasets' statistics aggregated per column (``msta.data.stats.aggregate``), less
    the columns whose shape differs between them (``observation.state``, the concatenation of
    each robot's own sensors, which a student of per-sensor columns does not read)."""
    each = [load_stats(r) for r in roots]
    shapes: dict[str, set] = {}
    for st in each:
        for col, v in st.items():
            shapes.setdefault(col, set()).add(np.shape(v["mean"]))
    return aggregate({c: v for c, v in st.items() if len(shapes[c]) == 1} for st in each)


def _train_locked(cfg: TrainConfig, root: Path, out: Path,
                  on_step: Callable[[int, dict[str, float]], None] | None,
                  deadline: float | None = None, more: Sequence[Path] = ()) -> Path:
    """:func:`train` once the run directory is locked."""
    resuming = prepare_output(out, cfg.resume)
    if resuming:
        check_resume_config(out, cfg)
    torch.set_num_threads(run_threads(out, cfg.num_threads, resuming))
    device = select_device(cfg.device)
    seed_everything(cfg.seed)
    stats = union_stats((root, *more)) if more else load_stats(root)
    policy = make_policy(cfg.policy, stats).to(device)  # robots: the datasets'
    if more:
        train_ds, val_ds, train_eps, val_eps = union_windows(
            policy, (root, *more), cfg.seed, cfg.val_fraction)
    else:
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
    print(f"dataset {', '.join(map(str, (root, *more)))}: {len(train_eps)} train episodes ({len(train_ds):,} windows), "
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
