"""Are a teacher's labels sound on the states a student drives into? (stage 2's premise)

    python -m eval.label_check --policy outputs/demo/stage1/final --robots 60 \\
        --student_s 3 --total_s 5

The student drives every robot for ``--student_s`` seconds while the teacher sees every
observation (as it does when it labels in msta-correct); then the teacher takes over and
drives to ``--total_s``. If its labels on the student's states are sound, the takeover
keeps the robots up about as well as a teacher restarted at that moment. Rows:

* ``teacher``: the teacher alone (the reference of the tracking ratio);
* ``student``: the student alone;
* ``takeover shadow``: the teacher as it records its own data (its plan assumes it drove);
* ``takeover follow``: the teacher following the robot (``follow_robot``, msta-correct's
  default labelling; teachers without that attribute skip the row);
* ``takeover reset``: the teacher restarted at the takeover.

Every row runs on the same robots, terrains (levels 0 to ``--max_level``), commands and
seeds. Survival has a 95 % Wilson interval; linear tracking (the per-step return over the
whole episode, a fallen robot scoring 0 from its fall on) is divided by the teacher's on the
same robots, with a 95 % delta-method interval over the paired robots (eval/intervals.py).
"""

from __future__ import annotations

import argparse
import os
from typing import Any

import numpy as np
import torch

from collect.sim.env import EnvConfig, QuadrupedEnv
from collect.sim.terrain import TerrainConfig
from eval.intervals import ratio_interval, wilson_interval
from policies.actor import StudentActor
from policies.factory import load_policy
from policies.teacher.config import TeacherConfig, build_teacher

MODES = ("teacher", "student", "takeover shadow", "takeover follow", "takeover reset")


def run_mode(mode: str, policy: Any, teacher_cfg: TeacherConfig, robots: int,
             switch: int, steps: int, max_level: int, seed: int) -> dict[str, Any] | None:
    """One row: survival and per-robot linear-tracking return of ``mode`` (None: skipped)."""
    env = QuadrupedEnv(EnvConfig(num_envs=robots, seed=seed, nthread=1,
                                 episode_length_s=steps * 0.02 + 1.0,
                                 terrain=TerrainConfig(max_init_level=max_level)))
    obs = env.reset()
    teacher = build_teacher(teacher_cfg)
    if mode == "takeover follow":
        if not hasattr(teacher, "follow_robot"):
            return None
        teacher.follow_robot = True
    student = StudentActor(policy, robots)
    alive, lin = np.ones(robots, dtype=bool), np.zeros(robots)
    everyone = np.arange(robots)
    for t in range(steps):
        if mode == "takeover reset" and t == switch:
            teacher.reset(everyone)
        a_teacher = teacher.act(obs)          # called every step: its clock and plan advance
        a_student = student.act(obs)
        drive = mode == "teacher" or (mode.startswith("takeover") and t >= switch)
        res = env.step(a_teacher if drive else a_student)
        lin[alive] += res.metrics["lin_vel_tracking"][alive]
        alive &= ~res.terminated              # a fallen robot scores nothing afterwards
        obs = res.obs
    return {"survived": int(alive.sum()), "robots": robots, "lin": lin / steps}


def label_check(policy_path: str, teacher_cfg: TeacherConfig | None = None, robots: int = 60,
                student_s: float = 3.0, total_s: float = 5.0, max_level: int = 2,
                seed: int = 123) -> dict[str, dict[str, Any]]:
    """Every row of the module docstring: {mode: {survival, survival_ci, lin_tracking,
    lin_tracking_ci, robots}}; linear tracking is normalized by the ``teacher`` row."""
    if not 0 < student_s < total_s:
        raise ValueError(f"need 0 < student_s < total_s, got {student_s} and {total_s}")
    policy = load_policy(policy_path)
    policy.eval()
    teacher_cfg = teacher_cfg or TeacherConfig()
    switch, steps = round(student_s / 0.02), round(total_s / 0.02)
    raw = {m: run_mode(m, policy, teacher_cfg, robots, switch, steps, max_level, seed)
           for m in MODES}
    ref = raw["teacher"]["lin"]
    rows = {}
    for mode, r in raw.items():
        if r is None:
            continue
        lin, lin_ci = ratio_interval(r["lin"], ref)
        rows[mode] = {"robots": r["robots"], "survival": r["survived"] / r["robots"],
                      "survival_ci": wilson_interval(r["survived"] / r["robots"], r["robots"]),
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
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--policy", required=True, help="student checkpoint directory")
    p.add_argument("--teacher", default="gait", help="registered teacher type")
    p.add_argument("--teacher_path", default="", help="teacher checkpoint (rma) or spec")
    p.add_argument("--robots", type=int, default=60, help="robots per row")
    p.add_argument("--student_s", type=float, default=3.0, help="seconds the student drives")
    p.add_argument("--total_s", type=float, default=5.0, help="episode length (s)")
    p.add_argument("--max_level", type=int, default=2, help="terrain levels 0..max_level")
    p.add_argument("--seed", type=int, default=123, help="terrain, spawns, commands, noise")
    p.add_argument("--threads", type=int, default=1, help="torch threads")
    args = p.parse_args(argv)
    if args.robots < 1:
        p.error("--robots must be >= 1")
    if not os.path.isdir(args.policy):
        p.error(f"--policy {args.policy!r} is not a checkpoint directory")
    torch.set_num_threads(args.threads)
    try:
        rows = label_check(args.policy, TeacherConfig(type=args.teacher, path=args.teacher_path),
                           args.robots, args.student_s, args.total_s, args.max_level, args.seed)
    except ValueError as e:
        p.error(str(e))
    print(render(rows))


if __name__ == "__main__":
    main()
