"""Build a student from a config, load one from a checkpoint, pick a device (the torch side
of :mod:`msta.policies.registry`, which says what a policy name means)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch

from msta.policies.base import StudentPolicy
from msta.policies.config import PolicyConfig
from msta.policies.registry import _import_builtins, get_policy_class
from msta.policies.resolve import resolve_pretrained


def make_policy(cfg: PolicyConfig, stats: Mapping[str, Mapping[str, Any]]) -> StudentPolicy:
    """A freshly initialized student for ``cfg`` with a processor built from dataset stats.

    Args:
        cfg: a registered policy config.
        stats: lerobot stats.json layout: ``{column: {"mean": [...], "std": [...], ...}}``.
    """
    cls = get_policy_class(cfg.type)
    processor = cls.processor_class.from_stats(cfg, stats)
    return cls(cfg, processor)


def select_device(name: str = "auto") -> torch.device:
    """``auto``: CUDA when available, else CPU; otherwise ``cpu``, ``cuda`` or
    ``cuda:<index>`` (the devices msta runs on; anything else is a one-line ValueError here,
    not a traceback at the first tensor).

    Args:
        name: "auto", "cpu", "cuda", "cuda:1", ...
    """
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    bad = f"unknown device {name!r}; use auto, cpu, cuda or cuda:<index>"
    try:
        device = torch.device(name)
    except RuntimeError:
        raise ValueError(bad) from None
    if device.type not in ("cpu", "cuda"):
        raise ValueError(bad)
    if device.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"device {name!r} requested but CUDA is not available")
    if device.type == "cuda" and device.index is not None \
            and device.index >= torch.cuda.device_count():
        raise ValueError(f"device {name!r}: this machine has {torch.cuda.device_count()} "
                         "CUDA device(s)")
    return device


def load_policy(
    path_or_repo_id: str | Path, revision: str | None = None, device: str = "cpu",
    max_params: int | None = None,
) -> StudentPolicy:
    """Load any registered student from a checkpoint (its config.json names the type).

    Args:
        path_or_repo_id: checkpoint directory, or hub id ``user/name[@revision]``.
        revision: hub revision for repo ids.
        device: where to put the weights.
        max_params: parameter limit (``StudentPolicy.from_pretrained``).

    Raises:
        CheckpointError: a malformed, oversized or mismatched file (named).
    """
    directory = resolve_pretrained(path_or_repo_id, revision, policy_class=get_policy_class)
    _import_builtins()
    cfg = PolicyConfig.load(directory)
    return get_policy_class(cfg.type).from_pretrained(directory, device=device,
                                                      max_params=max_params)


def load_config(directory: str | Path) -> PolicyConfig:
    """The student config a local checkpoint directory holds, a LeRobot msta checkpoint's
    included (its msta fields); every error names the file."""
    return PolicyConfig.load(resolve_pretrained(directory, policy_class=get_policy_class))
