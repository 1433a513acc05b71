"""Choosing a teacher from the command line: ``--teacher.type=gait`` / ``--teacher.path=...``."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, is_dataclass
from pathlib import Path

import numpy as np

from msta.data.revision import content_revision, file_parts
from msta.data.robot import A1, RobotDescription, load_robot
from msta.policies.teacher.base import Teacher, make_teacher, register_teacher, teacher_names


@register_teacher("zero")
class ZeroTeacher:
    """Holds the default pose (action 0). A baseline and a fast stand-in for tests.

    Args:
        robot: the robot it acts for (its joint count; None: the A1).
    """

    name = "zero"
    sensors: tuple[str, ...] = ("joint_pos",)

    def __init__(self, robot: RobotDescription | None = None) -> None:
        self.num_joints = (robot or A1).num_joints

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        """(N, joints) zeros: the default pose."""
        return np.zeros((len(obs["joint_pos"]), self.num_joints), dtype=np.float32)

    def reset(self, ids: np.ndarray) -> None:
        pass


#: which constructor argument receives ``TeacherConfig.path`` for each teacher type
PATH_ARGUMENT = {"rma": "pretrained", "imported": "spec"}
#: The DART warm start shipped with msta (``--teacher.type=rma --teacher.path=<it>``): the
#: gait controller imitated by ``msta-train-teacher --ppo.iterations=0`` (10 DART iterations;
#: ``produced_by.json`` in the folder; docs/results/2026-12-04-teacher-quality-rma.md).
SHIPPED_RMA = Path(__file__).resolve().parent / "checkpoints" / "rma_dart"
#: The PPO-trained RMA teacher shipped with msta, the default teacher of every command (no
#: ``--teacher.*`` option): rsl_rl's PPO from ``SHIPPED_RMA``; survives stairs and discrete
#: obstacles better than the gait controller, whose labels contradict a student-driven robot
#: (docs/teacher_quality.md, ``produced_by.json`` in the folder).
SHIPPED_RMA_PPO = Path(__file__).resolve().parent / "checkpoints" / "rma_ppo"
#: PPO-trained RMA teachers shipped for the other shipped robots (robot name -> checkpoint):
#: the Go1's, ``msta-train-teacher --env.robot=go1`` (``produced_by.json`` in the folder;
#: docs/robots.md). Every command simulating such a robot takes it in place of the A1's
#: (:meth:`TeacherConfig.on_robot`).
SHIPPED_ROBOT_RMA = {"go1": Path(__file__).resolve().parent / "checkpoints" / "go1_ppo"}


@dataclass
class TeacherConfig:
    """Args:
        type: registered teacher name: rma (the RMA MLP; the default; without ``path`` the
            shipped PPO teacher ``rma_ppo``, the DART warm start with
            ``--teacher.path=policies/teacher/checkpoints/rma_dart``), gait (the gait
            controller, no training), imported (needs ``path`` to a spec file), zero.
        path: checkpoint directory (rma) or spec file (imported).
    """

    # "" (nothing chosen) becomes the best shipped teacher in __post_init__: the command line
    # builds a group from the class defaults plus the options given, so ``--teacher.type=gait``
    # must not inherit a default path
    type: str = ""
    path: str = ""

    def __post_init__(self) -> None:
        if not self.type:
            self.type = "rma"
        if self.type not in teacher_names():
            raise ValueError(f"unknown teacher type {self.type!r}; registered: {teacher_names()}")
        if self.type == "rma" and not self.path:
            self.path = str(SHIPPED_RMA_PPO)
        if self.type in PATH_ARGUMENT and not self.path:
            raise ValueError(f"teacher type {self.type!r} needs --teacher.path "
                             f"({PATH_ARGUMENT[self.type]})")
        if self.path and not Path(self.path).exists():
            raise FileNotFoundError(f"teacher path {self.path!r} does not exist")

    def for_robot(self, robot: str) -> TeacherConfig | None:
        """The teacher for ``robot`` (a spec's name): this one, unless it is one of the A1's
        shipped RMA checkpoints (their joint angles read relative to the A1's default pose)
        and ``robot`` is another; then the robot's shipped teacher (``SHIPPED_ROBOT_RMA``),
        or None where msta ships none."""
        trained_on_a1 = bool(self.path) and Path(self.path).resolve() in (SHIPPED_RMA,
                                                                          SHIPPED_RMA_PPO)
        if robot == "a1" or not trained_on_a1:
            return self
        own = SHIPPED_ROBOT_RMA.get(robot)
        return TeacherConfig(type="rma", path=str(own)) if own is not None else None

    def on_robot(self, robot: str, prog: str, option: str = "--robot") -> TeacherConfig:
        """The teacher ``prog`` runs on ``robot`` (``option``'s value: a shipped robot's name
        or a spec file's path): :meth:`for_robot`'s, a swap said in one printed line; a
        one-line error where this one was trained on the A1 and msta ships none for it."""
        name = load_robot(robot).name
        own = self.for_robot(name)
        if own is None:
            raise ValueError(f"{option}={robot}: the teacher {self.path} was trained on the "
                             f"A1; give {name}'s own (--teacher.path=<dir of "
                             f"msta-train-teacher --env.robot={robot}>) or --teacher.type=gait")
        if own is not self:
            print(f"{prog}: robot {name} takes its shipped teacher {own.label}, not "
                  f"{self.label} (trained on the A1)", flush=True)
        return own

    @property
    def label(self) -> str:
        """The teacher as reports name it: ``rma (rma_ppo)``, ``gait``."""
        return f"{self.type} ({Path(self.path).name})" if self.path else self.type


def build_teacher(cfg: TeacherConfig, robot: RobotDescription | None = None) -> Teacher:
    """Instantiate the configured teacher for a robot.

    Args:
        cfg: the teacher's options.
        robot: the simulated robot, with the control numbers in force
            (``EnvConfig.teacher_robot``); None: the A1.
    """
    if cfg.type in PATH_ARGUMENT:
        return make_teacher(cfg.type, robot=robot, **{PATH_ARGUMENT[cfg.type]: cfg.path})
    return make_teacher(cfg.type, robot=robot)


def teacher_revision(cfg: TeacherConfig, robot: RobotDescription | None = None) -> str:
    """``<type>-<12 hex>`` (:func:`msta.data.revision.content_revision`): the type, then the
    teacher's files (names and bytes) or, for a teacher without files, its config as JSON
    (built for ``robot``, as :func:`build_teacher`: the gait controller's numbers follow it).

    Args:
        cfg: the teacher's options.
        robot: the simulated robot (None: the A1).
    """
    parts: list[bytes | str] = [cfg.type]
    if cfg.path:
        parts += file_parts(cfg.path)
    else:
        teacher = build_teacher(cfg, robot)
        conf = getattr(teacher, "cfg", None) or getattr(teacher, "config", None)
        if conf is not None and is_dataclass(conf):
            parts.append(json.dumps(asdict(conf), sort_keys=True, default=str))
    return content_revision(parts, prefix=cfg.type)
