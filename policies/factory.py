"""Name -> policy registry: build a student from a config, load one from a checkpoint.

One registration per policy: :func:`register_policy` on the policy class registers the
class under its name and its ``config_class`` with draccus, so the name is at once a
``--policy.type`` choice, a ``config.json`` ``"type"``, a :func:`make_policy` /
:func:`load_policy` name and an entry of :func:`registered_policies` (which the baselines'
lists and the comparison tools read). The built-in students are every module under the
packages of :data:`BUILTIN_PACKAGES`, imported the first time a name is looked up (no
imports with side effects at module import): a new file there with a registered policy is
all a new built-in policy needs.
"""

from __future__ import annotations

import functools
import importlib
import pkgutil
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import torch

from msta.policies.base import StudentPolicy
from msta.policies.config import PolicyConfig
from msta.policies.resolve import resolve_pretrained

#: Packages whose modules hold the built-in students (imported, recursively, on first use).
BUILTIN_PACKAGES: tuple[str, ...] = ("msta.policies.msta", "msta.policies.baselines")
#: What a registered policy is: the paper's ``method`` (MSTA), one of the paper's
#: ``baseline`` students, or a ``reference`` learner that is neither.
KINDS: tuple[str, ...] = ("method", "baseline", "reference")

_POLICIES: dict[str, type[StudentPolicy]] = {}
_KIND: dict[str, str] = {}


def register_policy(
    name: str, kind: str = "baseline"
) -> Callable[[type[StudentPolicy]], type[StudentPolicy]]:
    """Class decorator: make ``name`` resolve to this policy class and its ``config_class``.

    Args:
        name: the policy's name (``--policy.type``, ``config.json``'s ``"type"``).
        kind: one of :data:`KINDS`.
    """
    if kind not in KINDS:
        raise ValueError(f"kind {kind!r} is not one of {KINDS}")

    def wrap(cls: type[StudentPolicy]) -> type[StudentPolicy]:
        if name in _POLICIES and _POLICIES[name] is not cls:
            raise ValueError(
                f"policy name {name!r} is already registered to {_POLICIES[name].__name__}"
            )
        config_class = cls.__dict__.get("config_class")
        if not (isinstance(config_class, type) and issubclass(config_class, PolicyConfig)):
            raise TypeError(f"{cls.__name__}.config_class must be a PolicyConfig subclass")
        PolicyConfig.register_subclass(name, config_class)  # raises on a name clash
        _POLICIES[name] = cls
        _KIND[name] = kind
        return cls

    return wrap


def unregister_policy(name: str) -> None:
    """Undo :func:`register_policy` (a policy defined for a test or in a notebook).

    Args:
        name: a registered name; built-ins cannot be removed.
    """
    if _POLICIES.get(name) is None:
        raise KeyError(f"unknown policy {name!r}")
    if _POLICIES[name].__module__.startswith(BUILTIN_PACKAGES):
        raise ValueError(f"{name!r} is a built-in policy")
    del _POLICIES[name], _KIND[name]
    PolicyConfig.get_known_choices().pop(name, None)


@functools.cache
def _import_builtins() -> None:
    for package in BUILTIN_PACKAGES:
        pkg = importlib.import_module(package)
        for info in pkgutil.walk_packages(pkg.__path__, f"{package}."):
            importlib.import_module(info.name)


def registered_policies(kind: str | None = None) -> list[str]:
    """Names of the registered students (built-ins imported first), sorted.

    Args:
        kind: only those of this kind (:data:`KINDS`); None: all.
    """
    if kind is not None and kind not in KINDS:
        raise ValueError(f"kind {kind!r} is not one of {KINDS}")
    _import_builtins()
    return sorted(n for n in _POLICIES if kind is None or _KIND[n] == kind)


def policy_kind(name: str) -> str:
    """The kind (:data:`KINDS`) policy ``name`` was registered with."""
    get_policy_class(name)
    return _KIND[name]


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
    _import_builtins()
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
