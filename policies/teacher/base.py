"""The teacher protocol and registry.

A teacher maps a batch of observations (student sensors plus privileged signals, keyed by
registry name, each (N, dim) float32) to actions in the simulator's convention: (N, 12)
offsets from the robot's default pose in units of the simulator's ``control.action_scale``
(joint target = default pose + action_scale * action). Teachers are deterministic and
batched over environments; stateful ones (e.g. a gait phase) are told about episode
starts through ``reset``.

A teacher is built for a robot (``make_teacher(name, robot=...)``; none: the A1): the
simulated robot's description with the control numbers in force
(``msta.collect.sim.env_config.EnvConfig.teacher_robot``). Teachers are privileged: on a
robot that offers no ``foot_contact`` they read the simulator's own contacts,
``true_contact``, in its place (:func:`teacher_view`, :data:`PRIVILEGED_COPIES`).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Protocol, runtime_checkable

import numpy as np

from msta.data.robot import RobotDescription
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


def make_teacher(name: str, robot: RobotDescription | None = None, **kwargs) -> Teacher:
    """Build a registered teacher by name (a built-in's module is imported first).

    Args:
        name: the registered name, e.g. ``"gait"``.
        robot: the robot it acts for (its constructor's ``robot``; None: the A1); every
            sensor the teacher reads must be one the robot offers, or have its privileged
            copy among them (:data:`PRIVILEGED_COPIES`), else a one-line ``ValueError``.
        **kwargs: the teacher's other constructor arguments.
    """
    if name not in TEACHERS and name in BUILTIN_TEACHERS:
        importlib.import_module(BUILTIN_TEACHERS[name])
    if name not in TEACHERS:
        raise KeyError(f"unknown teacher {name!r}; registered: {teacher_names()}")
    teacher = TEACHERS[name](robot=robot, **kwargs)
    if robot is not None:
        check_robot(teacher, robot)
    return teacher


#: Sensor a teacher reads -> the privileged signal that stands in for it on a robot that
#: does not offer it (the simulator's truth; students never read it).
PRIVILEGED_COPIES: dict[str, str] = {"foot_contact": "true_contact"}


def teacher_view(obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """``obs`` as a teacher reads it: a sensor of :data:`PRIVILEGED_COPIES` that ``obs``
    lacks is its privileged copy when ``obs`` holds that (on the A1, which offers
    ``foot_contact``, ``obs`` itself is returned).

    Args:
        obs: registry-keyed observations.
    """
    stand_ins = {s: obs[c] for s, c in PRIVILEGED_COPIES.items() if s not in obs and c in obs}
    return {**obs, **stand_ins} if stand_ins else obs


def check_robot(teacher: Teacher, robot: RobotDescription) -> None:
    """One-line ``ValueError`` naming the robot and its sensors if ``teacher`` reads a
    sensor that ``robot`` offers neither itself nor as its privileged copy.

    Args:
        teacher: a built teacher (its ``sensors``).
        robot: the robot it acts for.
    """
    offered = set(robot.sensors)
    missing = [s for s in teacher.sensors
               if s not in offered and PRIVILEGED_COPIES.get(s) not in offered]
    if missing:
        raise ValueError(f"teacher {teacher.name!r} reads {missing}, which the robot "
                         f"{robot.name!r} does not offer; its sensors: {list(robot.sensors)}")


def check_obs(teacher: Teacher, obs: dict[str, np.ndarray]) -> int:
    """Validate that ``obs`` (a :func:`teacher_view`) holds every sensor the teacher reads;
    return the batch size."""
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
