"""msta-finetune's run (described in :mod:`msta.train.finetune`, which holds its command
line): the prepared start (new sensors, window, frozen groups), then msta-correct's rounds."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from msta.data import layout
from msta.data import sensors as registry
from msta.data.features import load_info
from msta.data.locate import locate_checkpoint
from msta.data.stats import load_stats
from msta.policies.base import StudentPolicy
from msta.policies.factory import load_config
from msta.policies.msta import MSTAPolicy
from msta.train.correct_progress import CorrectProgress
from msta.train.finetune_config import (
    FinetuneConfig,
    sensor_names,
    trainable_modules,
)
from msta.train.stage2 import PhaseHook, correct
from msta.train.state import atomic_json

#: The fine-tuned checkpoint's record of its start and sensors (beside config.json).
RECORD = "finetune.json"
RECORD_FORMAT = "msta-finetune/1"


def module_of(name: str) -> str:
    """``model.sensor_embed.joint_pos`` -> ``sensor_embed`` (MSTAPolicy parameter names)."""
    return name.removeprefix("model.").split(".")[0]


def freeze(policy: StudentPolicy, modules: Sequence[str]) -> list[str]:
    """``requires_grad`` False on every parameter outside ``modules``; returns the names of
    the trainable ones (an error when there are none)."""
    names = []
    for name, p in policy.named_parameters():
        p.requires_grad_(module_of(name) in modules)
        if p.requires_grad:
            names.append(name)
    if not names:
        raise ValueError(f"trainable={modules} selects no parameter of this student")
    return names


def check_source(cfg: FinetuneConfig) -> tuple[Path, tuple[str, ...]]:
    """(starting checkpoint, the fine-tuned student's inputs): the one-line errors about the
    checkpoint come before output_dir is touched."""
    ckpt = locate_checkpoint(cfg.policy.path, "--policy.path")
    config = load_config(ckpt)
    if config.type != "msta":  # the baselines have no transformer to freeze
        raise ValueError(f"{ckpt} holds a {config.type!r} student; msta-finetune trains the "
                         "token embeddings of a frozen MSTA transformer, which the baselines "
                         "do not have (msta-correct retrains any student whole)")
    kept = sensor_names(cfg.sensors, config.input_sensors)
    if layout.is_dataset_root(Path(cfg.dataset)):  # a hub id is checked once it is pulled
        check_recorded(Path(cfg.dataset), [s for s in kept if s not in config.input_sensors])
    return ckpt, kept


def check_recorded(root: Path, added: Sequence[str]) -> None:
    """An added sensor must be a column of the dataset the rounds retrain on."""
    have = load_info(root)["features"]
    for name in added:
        if registry.get(name).column not in have:
            raise ValueError(f"the dataset {root} does not record {name!r}, which the student "
                             f"would read; record one that does (msta-collect "
                             f"--extra_sensors={name})")


class Preparation:
    """msta-correct's ``prepare`` hook: restrict the student's inputs, freeze it, and record
    what was done in every checkpoint of ``output_dir``.

    Args:
        cfg: the configuration.
        source: the starting checkpoint.
        sensors: the fine-tuned student's inputs (kept ones, then added ones).
    """

    def __init__(self, cfg: FinetuneConfig, source: Path, sensors: tuple[str, ...]) -> None:
        self.cfg, self.source, self.sensors = cfg, source, sensors
        self.added = [s for s in sensors if s not in load_config(source).input_sensors]
        self.record: dict[str, Any] | None = None

    def __call__(self, policy: StudentPolicy, root: Path) -> StudentPolicy:
        if not isinstance(policy, MSTAPolicy):
            raise TypeError(f"a {policy.config.type!r} student cannot be fine-tuned here "
                             "(MSTA only)")
        new = [s for s in self.sensors if s not in policy.config.input_sensors]  # none on resume
        check_recorded(root, new)
        student = policy.with_inputs(self.sensors, self.cfg.history,
                                     load_stats(root) if new else None)
        names = freeze(student, trainable_modules(self.cfg.trainable))
        params = dict(student.named_parameters())
        n = sum(params[k].numel() for k in names)
        total = sum(p.numel() for p in params.values())
        self.record = {"format": RECORD_FORMAT, "source": str(self.source),
                       "input_sensors": list(self.sensors), "added_sensors": self.added,
                       "history": self.cfg.history,
                       "trainable": self.cfg.trainable, "trained_parameters": names,
                       "trained_numel": n, "total_numel": total}
        print(f"msta-finetune: {self.source} on {', '.join(self.sensors)} at T = "
              f"{self.cfg.history}; training {self.cfg.trainable} ({n:,} of {total:,} "
              f"parameters: {', '.join(sorted({module_of(k) for k in names}))}), the "
              "transformer blocks frozen")
        return student

    def write(self, out: Path) -> None:
        """``finetune.json`` into every checkpoint in ``out`` (idempotent)."""
        if self.record is None:
            return
        for d in (out / "start", *sorted(out.glob("round_*"))):
            if (d / "model.safetensors").is_file():
                atomic_json(d / RECORD, self.record)


def finetune(cfg: FinetuneConfig, on_phase: PhaseHook | None = None) -> CorrectProgress:
    """Run (or resume) msta-finetune; returns its progress.json record.

    Args:
        cfg: the parsed configuration.
        on_phase: as :func:`msta.train.stage2.correct`'s (after finetune.json is written).
    """
    source, kept = check_source(cfg)
    prep, out = Preparation(cfg, source, kept), Path(cfg.output_dir)

    def hook(phase: str, r: int) -> None:
        prep.write(out)  # every phase: a checkpoint saved before a kill gets its record too
        if on_phase is not None:
            on_phase(phase, r)

    return correct(cfg, on_phase=hook, prepare=prep)  # "done": the last write, still locked
