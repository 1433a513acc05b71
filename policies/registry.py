"""Name -> policy registry, without torch: what a policy name means.

One registration per policy: :func:`register_policy` on the policy class registers the
class under its name and its ``config_class`` with draccus, so the name is at once a
``--policy.type`` choice, a ``config.json`` ``"type"``, a
:func:`msta.policies.factory.make_policy` / :func:`~msta.policies.factory.load_policy` name
and an entry of :func:`registered_policies` (which the baselines' lists and the comparison
tools read). The built-in students are every module under the packages of
:data:`BUILTIN_PACKAGES`, imported the first time a name is looked up (no imports with side
effects at module import): a new file there with a registered policy is all a new built-in
policy needs. A command line needs only the configs: :func:`register_builtin_configs` imports
the built-in config modules (:data:`BUILTIN_CONFIGS`, no torch), so ``--help`` and the
parsing of ``--policy.type`` answer before torch loads.
"""

from __future__ import annotations

import functools
import importlib
import pkgutil
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from msta.policies.config import PolicyConfig

if TYPE_CHECKING:
    from msta.policies.base import StudentPolicy

#: Packages whose modules hold the built-in students (imported, recursively, on first use).
BUILTIN_PACKAGES: tuple[str, ...] = ("msta.policies.msta", "msta.policies.baselines")
#: Modules holding the built-in students' configs (each registers its names with draccus).
BUILTIN_CONFIGS: tuple[str, ...] = ("msta.policies.msta.configuration_msta",
                                    "msta.policies.baselines.configs")
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
        if PolicyConfig.get_known_choices().get(name) is not config_class:
            # a built-in config registered itself at import (BUILTIN_CONFIGS); any other
            # class under a taken name raises
            PolicyConfig.register_subclass(name, config_class)
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
def register_builtin_configs() -> None:
    """Register the built-in students' config classes with draccus (``--policy.type``
    choices, ``config.json`` types) by importing their config modules only: no torch."""
    for module in BUILTIN_CONFIGS:
        importlib.import_module(module)


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
