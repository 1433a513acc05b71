"""Name -> policy registry: build a student from a config, load one from a checkpoint.

Configs register themselves with draccus (``@PolicyConfig.register_subclass("msta")``),
policy classes with :func:`register_policy`. Built-in policies are imported lazily, the
first time a name is looked up (no imports with side effects at module import).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from policies.base import PolicyConfig, StudentPolicy, resolve_pretrained

#: Built-in policy name -> module whose import registers its config and policy class.
BUILTIN_POLICIES: dict[str, str] = {
    "msta": "policies.msta",
    "gru": "policies.baselines",
    "rma_tcn": "policies.baselines",
    "tert_concat": "policies.baselines",
    "tert_separate": "policies.baselines",
    "tert_mask": "policies.baselines",
    "mlp": "policies.baselines",
}

_POLICIES: dict[str, type[StudentPolicy]] = {}


def register_policy(name: str) -> Callable[[type[StudentPolicy]], type[StudentPolicy]]:
    """Class decorator: make ``name`` resolve to this policy class.

    Args:
        name: the same name its config is registered under.
    """

    def wrap(cls: type[StudentPolicy]) -> type[StudentPolicy]:
        if name in _POLICIES and _POLICIES[name] is not cls:
            raise ValueError(
                f"policy name {name!r} is already registered to {_POLICIES[name].__name__}"
            )
        _POLICIES[name] = cls
        return cls

    return wrap


def _import_builtins() -> None:
    for module in BUILTIN_POLICIES.values():
        importlib.import_module(module)


def known_policies() -> list[str]:
    _import_builtins()
    return sorted(_POLICIES)


def get_policy_class(name: str) -> type[StudentPolicy]:
    """Policy class registered under ``name``; the error lists the known names."""
    _import_builtins()
    try:
        return _POLICIES[name]
    except KeyError:
        raise KeyError(f"unknown policy {name!r}; known policies: {sorted(_POLICIES)}") from None


def get_config_class(name: str) -> type[PolicyConfig]:
    """Config dataclass registered under ``name``."""
    get_policy_class(name)  # imports the built-in and checks the name
    return PolicyConfig.get_choice_class(name)


def make_config(name: str, **overrides: Any) -> PolicyConfig:
    """A config of policy ``name``; unknown override keys raise.

    Args:
        name: registered policy name, e.g. ``"msta"``.
        overrides: field values.
    """
    return PolicyConfig.from_dict({"type": name, **overrides})


def make_policy(cfg: PolicyConfig, stats: Mapping[str, Mapping[str, Any]]) -> StudentPolicy:
    """A freshly initialized student for ``cfg`` with a processor built from dataset stats.

    Args:
        cfg: a registered policy config.
        stats: lerobot stats.json layout: ``{column: {"mean": [...], "std": [...], ...}}``.
    """
    cls = get_policy_class(cfg.type)
    processor = cls.processor_class.from_stats(cfg, stats)
    return cls(cfg, processor)


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
    directory = resolve_pretrained(path_or_repo_id, revision)
    _import_builtins()
    cfg = PolicyConfig.load(directory)
    return get_policy_class(cfg.type).from_pretrained(directory, device=device,
                                                      max_params=max_params)
