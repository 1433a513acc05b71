"""The teacher protocol and registry.

A teacher maps a batch of observations (student sensors plus privileged signals, keyed by
registry name, each (N, dim) float32) to actions in the simulator's convention: (N, 12)
offsets from the default pose in units of the simulator's ``control.action_scale``
(joint target = DEFAULT_POSE + action_scale * action; default
``msta.data.robot.ACTION_SCALE``). Teachers are deterministic and
batched over environments; stateful ones (e.g. a gait phase) are told about episode
starts through ``reset``.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Protocol, runtime_checkable

import numpy as np

from msta.data.sensors import get


@runtime_checkable
class Teacher(Protocol):
    """What every teacher provides."""

    #: registry name, e.g. "gait", "rma", "imported"
    name: str
    #: registry sensor names read by ``act`` (validated against msta.data.sensors)
    sensors: tuple[str, ...]

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        """(N, 12) float actions for a batch of observations."""
        ...

    def reset(self, ids: np.ndarray) -> None:
        """Environments ``ids`` start a new episode (clear any per-env state)."""
        ...


TEACHERS: dict[str, Callable[..., Teacher]] = {}
#: The built-in teachers and the module that registers each, imported on first use (rma and
#: imported load torch), so a command line checks ``--teacher.type`` without them.
BUILTIN_TEACHERS: dict[str, str] = {
    "gait": "msta.policies.teacher.gait",
    "imported": "msta.policies.teacher.imported",
    "rma": "msta.policies.teacher.rma",
    "zero": "msta.policies.teacher.config",
}


def register_teacher(name: str) -> Callable:
    """Class decorator: make a teacher constructible by name (``make_teacher``)."""

    def wrap(cls):
        if name in TEACHERS:
            raise ValueError(f"teacher {name!r} registered twice")
        TEACHERS[name] = cls
        return cls

    return wrap


def teacher_names() -> list[str]:
    """Every teacher name a config may give: the registered ones and the built-ins."""
    return sorted(set(TEACHERS) | set(BUILTIN_TEACHERS))


def make_teacher(name: str, **kwargs) -> Teacher:
    """Build a registered teacher by name (a built-in's module is imported first)."""
    if name not in TEACHERS and name in BUILTIN_TEACHERS:
        importlib.import_module(BUILTIN_TEACHERS[name])
    if name not in TEACHERS:
        raise KeyError(f"unknown teacher {name!r}; registered: {teacher_names()}")
    return TEACHERS[name](**kwargs)


def check_obs(teacher: Teacher, obs: dict[str, np.ndarray]) -> int:
    """Validate that ``obs`` holds every sensor the teacher reads; return the batch size."""
    n = None
    for name in teacher.sensors:
        spec = get(name)
        if name not in obs:
            raise KeyError(f"teacher {teacher.name!r} needs sensor {name!r}, missing from obs "
                           f"(has {sorted(obs)})")
        x = obs[name]
        if x.ndim != 2 or x.shape[1] != spec.dim:
            raise ValueError(f"sensor {name!r} has shape {x.shape}, expected (N, {spec.dim})")
        if n is not None and x.shape[0] != n:
            raise ValueError(f"sensor {name!r} has batch {x.shape[0]}, others have {n}")
        n = x.shape[0]
    return int(n or 0)
