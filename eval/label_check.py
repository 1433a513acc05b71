"""Are a teacher's labels sound on the states a student drives into? (stage 2's premise)

    python -m msta.eval.label_check --policy.path=outputs/demo/stage1/final --num_envs=60 \\
        --student_seconds=3 --episode_length_s=5

The student drives every robot for ``--student_seconds`` while the teacher sees every
observation (as it does when it labels in msta-correct); then the teacher takes over and
drives to ``--episode_length_s``. If its labels on the student's states are sound, the
takeover keeps the robots up about as well as a teacher restarted at that moment. Rows:

* ``teacher``: the teacher alone (the reference of the tracking ratio);
* ``student``: the student alone;
* ``takeover shadow``: the teacher as it records its own data (its plan assumes it drove);
* ``takeover follow``: the teacher following the robot (``follow_robot``, msta-correct's
  default labelling; teachers without that attribute skip the row);
* ``takeover reset``: the teacher restarted at the takeover.

Every row runs through msta's one rollout loop (:func:`msta.collect.rollout.rollout`) on the
same robots, terrains (levels 0 to ``--max_level``), commands and seeds. Survival is msta's
one figure (:func:`msta.eval.metrics.survival`: the share of robots that did not fall, with a
95 % Wilson interval); linear tracking (the per-step return over the whole episode,
:func:`msta.collect.rollout.step_quantities`' ``lin``, a fallen robot scoring 0 from its fall
on) is divided by the teacher's on the same robots, with a 95 % delta-method interval over
the paired robots (eval/intervals.py).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from msta.collect.rollout import Step, fell, rollout, step_quantities
from msta.collect.sim.env import QuadrupedEnv
from msta.collect.sim.env_config import EnvConfig, load_sim_robot
from msta.collect.sim.terrain import TerrainConfig
from msta.data.checks import check_at_least
from msta.data.cli import parse_config, usage_error
from msta.data.locate import locate_checkpoint
from msta.data.robot import LEGACY_ROBOT
from msta.eval.intervals import ratio_interval
from msta.eval.metrics import survival
from msta.policies.actor import StudentActor
from msta.policies.checkpoint import PolicyPath
from msta.policies.config import check_trained_on
from msta.policies.factory import load_policy
from msta.policies.teacher.config import TeacherConfig, build_teacher

PROG = "python -m msta.eval.label_check"
MODES = ("teacher", "student", "takeover shadow", "takeover follow", "takeover reset")


@dataclass
class LabelCheckConfig:
    """Args:
        policy: the trained student (``--policy.path``: a checkpoint directory or a hub id
            ``user/name[@revision]``).
        teacher: the teacher whose labels are checked (``--teacher.type``, ``--teacher.path``).
        robot: the simulated robot, the one the teacher is built for and the student was
            trained on: a shipped robot's name (a1, go1) or a spec file's path
            (docs/robots.md).
        num_envs: robots simulated per row (every row drives the same robots).
        student_seconds: seconds the student drives before the teacher takes over.
        episode_length_s: episode length (s); the teacher drives from ``student_seconds`` on.
        max_level: robots start on terrain levels 0..max_level.
        seed: terrain, spawns, commands and noise (the same in every row).
        num_threads: torch threads.
    """

    policy: PolicyPath = field(default_factory=PolicyPath)
    teacher: TeacherConfig = field(default_factory=TeacherConfig)
    robot: str = LEGACY_ROBOT
    num_envs: int = 60
    student_seconds: float = 3.0
    episode_length_s: float = 5.0
    max_level: int = 2
    seed: int = 123
    num_threads: int = 1

    def __post_init__(self) -> None:
        load_sim_robot(self.robot, "robot")  # a bad robot: one line, before anything runs
        self.teacher = self.teacher.on_robot(self.robot, "label_check")
        check_at_least(self, 1, "num_envs", "num_threads")
        if self.max_level < 0:
            raise ValueError(f"max_level={self.max_level} must be >= 0")
        if not 0 < self.student_seconds < self.episode_length_s:
            raise ValueError(f"need 0 < student_seconds < episode_length_s, got "
                             f"{self.student_seconds} and {self.episode_length_s}")


class TakeoverDriver:
    """Teacher and student both act on every observation (the teacher's clock and plan
    advance as when it labels); ``mode`` says whose action is executed at each step.

    Args:
        mode: one of :data:`MODES`.
        teacher: the teacher.
        student: the student's actor.
        switch: the step from which the teacher drives in the takeover modes.
    """

    def __init__(self, mode: str, teacher: Any, student: StudentActor, switch: int) -> None:
        self.mode, self.teacher, self.student, self.switch = mode, teacher, student, switch
        self.t = 0

    def reset(self, ids: np.ndarray) -> None:
        self.teacher.reset(ids)
        self.student.reset(ids)

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        if self.mode == "takeover reset" and self.t == self.switch:
            self.teacher.reset(np.arange(self.student.num_envs))
        a_teacher = self.teacher.act(obs)     # called every step: its clock and plan advance
        a_student = self.student.act(obs)
        drive = self.mode == "teacher" or (self.mode.startswith("takeover")
                                           and self.t >= self.switch)
        self.t += 1
        return a_teacher if drive else a_student


def run_mode(mode: str, policy: Any, cfg: LabelCheckConfig) -> dict[str, Any] | None:
    """One row of ``mode`` (None: skipped): which robots fell (``fell``, each robot's first
    episode only) and their linear-tracking returns per step (``lin``)."""
    dt = load_sim_robot(cfg.robot, "robot").control_dt
    switch = round(cfg.student_seconds / dt)
    steps = round(cfg.episode_length_s / dt)
    env = QuadrupedEnv(EnvConfig(robot=cfg.robot, num_envs=cfg.num_envs, seed=cfg.seed, nthread=1,
                                 episode_length_s=steps * dt + 1.0,
                                 terrain=TerrainConfig(max_init_level=cfg.max_level)))
    env.reset()
    teacher = build_teacher(cfg.teacher, env.cfg.teacher_robot)
    if mode == "takeover follow":
        if not hasattr(teacher, "follow_robot"):
            return None
        teacher.follow_robot = True
    driver = TakeoverDriver(mode, teacher, StudentActor(policy, cfg.num_envs), switch)
    alive, lin = np.ones(cfg.num_envs, dtype=bool), np.zeros(cfg.num_envs)

    def on_step(step: Step) -> None:
        lin[alive] += step_quantities(step)["lin"][alive]
        alive[fell(step.res)] = False    # a fallen robot scores nothing afterwards

    rollout(env, driver, on_step, max_steps=steps, reset_done=False)
    return {"fell": ~alive, "robots": cfg.num_envs, "lin": lin / steps}


def load_student(spec: str) -> Any:
    """The student at a checkpoint directory or hub id (``--policy.path``), in eval mode."""
    policy = load_policy(locate_checkpoint(spec, "--policy.path"))
    policy.eval()
    return policy


def label_check(cfg: LabelCheckConfig, policy: Any = None) -> dict[str, dict[str, Any]]:
    """Every row of the module docstring: {mode: {survival, survival_ci, lin_tracking,
    lin_tracking_ci, robots}}; linear tracking is normalized by the ``teacher`` row.

    Args:
        cfg: what to run.
        policy: the loaded student (default: :func:`load_student` of ``cfg.policy.path``).
    """
    policy = load_student(cfg.policy.path) if policy is None else policy
    check_trained_on(policy.config.robots, load_sim_robot(cfg.robot, "robot").name,
                     f"--policy.path={cfg.policy.path}", "--robot")
    raw = {m: run_mode(m, policy, cfg) for m in MODES}
    ref = raw["teacher"]["lin"]
    rows = {}
    for mode, r in raw.items():
        if r is None:
            continue
        lin, lin_ci = ratio_interval(r["lin"], ref)
        surv, surv_ci = survival(r["fell"])
        rows[mode] = {"robots": r["robots"], "survival": surv, "survival_ci": surv_ci,
                      "lin_tracking": lin, "lin_tracking_ci": lin_ci}
    return rows


def render(rows: dict[str, dict[str, Any]]) -> str:
    """The rows as a markdown table."""
    def fig(v: float | None, ci: tuple[float, float] | None) -> str:
        if v is None:
            return "n/a"
        return f"{v:.2f}" + (f" ({ci[0]:.2f}-{ci[1]:.2f})" if ci else "")

    lines = ["| driver | robots | survival (95 % CI) | lin. tracking vs teacher (95 % CI) |",
             "|---|---|---|---|"]
    for mode, r in rows.items():
        lines.append(f"| {mode} | {r['robots']} | {fig(r['survival'], r['survival_ci'])} | "
                     f"{fig(r['lin_tracking'], r['lin_tracking_ci'])} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    """Run the label check and print its table (``python -m msta.eval.label_check --help``)."""
    cfg = parse_config(LabelCheckConfig, argv, PROG)
    torch.set_num_threads(cfg.num_threads)
    try:
        policy = load_student(cfg.policy.path)
        check_trained_on(policy.config.robots, load_sim_robot(cfg.robot, "robot").name,
                         f"--policy.path={cfg.policy.path}", "--robot")
    except (ValueError, FileNotFoundError) as e:  # CheckpointError is a ValueError
        raise usage_error(f"{PROG}: error: {e}") from None
    print(render(label_check(cfg, policy)))


if __name__ == "__main__":
    main()
