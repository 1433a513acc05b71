"""Stage 2's rollouts on Ray workers (msta-correct / msta-finetune ``--workers``).

A round's student episodes are recorded in blocks of ``--num_envs`` slots
(:mod:`msta.collect.ray_record`): slot k of round r draws everything random from its own stream
keyed by (``env.seed + 1000 r``, k) on its own tile; the block's student masks, DAgger coin
flips and teacher are seeded by (round, block). Workers drive with the student (on their CPU)
and label with the teacher; this process gathers the episodes in slot order, and
:func:`msta.train.online.append_episodes` commits them in one writer session, as without workers.
So a round appends the same episodes for any worker count.

How many: with ``keep_unfinished`` (the default) ``ceil(episodes_per_round / num_envs) *
num_envs`` slots each run one episode length of control steps, keeping every episode that
ends and the one still running, cut (the env steps of the single-process round, spread over
more environments: one block per worker); without it, ``episodes_per_round`` slots give their
first episode each (rather than the first to finish, which over-samples falls).
"""

from __future__ import annotations

import copy
import math
import time
from dataclasses import replace
from typing import Any

import numpy as np

from msta.collect.ray_pool import RayOptions, block_seed, check_ray_options, shared_pool
from msta.collect.ray_record import RecordJob, record_on_workers
from msta.collect.recorder import LabelledActor, recorded_sensors
from msta.data.robot import RobotDescription
from msta.policies.actor import mask_split_actor
from msta.policies.base import StudentPolicy
from msta.policies.input_spec import InputSpec
from msta.policies.teacher.config import TeacherConfig, build_teacher


class StudentLabeller:
    """A block's actor factory (picklable): the student drives (test-time inputs of
    ``spec``, mask ratios spread over the block's environments), a fresh teacher labels and
    executes with probability ``beta``.

    Args:
        policy: the student, on the CPU.
        teacher: the labelling teacher's config.
        follow_robot: ``GaitTeacher.follow_robot`` (a teacher without it ignores it).
        spec: the round's student inputs (its seed is mixed with the block's).
        ratios: test-time mask ratios spread over the environments.
        beta: DAgger mixing probability.
        seed: the round's seed of the coin flips.
        robot: the simulated robot the teacher is built for (``EnvConfig.teacher_robot``).
    """

    def __init__(self, policy: StudentPolicy, teacher: TeacherConfig, follow_robot: bool,
                 spec: InputSpec, ratios: tuple[float, ...], beta: float, seed: int,
                 robot: RobotDescription | None = None) -> None:
        self.policy, self.teacher, self.follow_robot = policy, teacher, follow_robot
        self.robot = robot
        self.spec, self.ratios, self.beta, self.seed = spec, ratios, beta, seed

    def __call__(self, block: int, n: int) -> LabelledActor:
        teacher = build_teacher(self.teacher, self.robot)
        if hasattr(teacher, "follow_robot"):
            teacher.follow_robot = self.follow_robot
        spec = replace(self.spec, seed=block_seed(self.spec.seed, block))
        student = mask_split_actor(self.policy, n, spec, self.ratios,
                                   name=self.policy.config.type)
        return LabelledActor(student, teacher, beta=self.beta,
                             seed=block_seed(self.seed, block))


def round_slots(cfg: Any, max_steps: int) -> tuple[int, int | None]:
    """(slots, horizon in control steps or None) of a stage-2 round on workers
    (``max_steps``: an episode's length in control steps)."""
    if cfg.keep_unfinished:
        return math.ceil(cfg.episodes_per_round / cfg.num_envs) * cfg.num_envs, max_steps
    return cfg.episodes_per_round, None


def drive_and_label_on_workers(cfg: Any, policy: StudentPolicy, r: int, revision: str,
                               sensors: tuple[str, ...] | None = None
                               ) -> tuple[list, dict[str, float]]:
    """:func:`msta.train.stage2.drive_and_label` on ``cfg.workers`` Ray workers: the same
    arguments and return (episodes with provenance, rollout figures; the share of steps the
    teacher executed is counted over the recorded frames whose action is the label's)."""
    seed = cfg.env.seed + 1000 * r
    env = replace(cfg.env, num_envs=cfg.num_envs, seed=seed,
                  episode_length_s=cfg.episode_length_s)
    slots, horizon = round_slots(cfg, env.max_episode_steps)
    beta = cfg.beta * cfg.beta_decay ** (r - 1)
    student = policy if policy.device.type == "cpu" else copy.deepcopy(policy).to("cpu")
    student.eval()
    make = StudentLabeller(student, cfg.teacher, cfg.teacher_follows_robot,
                           replace(cfg.rollout, seed=cfg.rollout.seed + r),
                           cfg.rollout_mask_ratios, beta, cfg.seed + r, env.teacher_robot)
    job = RecordJob(env, make, tuple(sensors or recorded_sensors(env.robot_description)),
                    horizon)
    types = env.terrain.types
    episodes: list = []
    shares: list[np.ndarray] = []

    def keep(ep: tuple[dict[str, np.ndarray], int, int]) -> None:
        frames, type_idx, level = ep
        if beta > 0:  # the teacher's share of the executed actions (0 without DAgger mixing)
            shares.append(frames["action"] == frames["executed_action"])
        episodes.append((frames, {
            "terrain": types[type_idx], "terrain_level": level, "source": "student",
            "round": r, "policy": policy.config.type, "policy_revision": revision,
            "seed": seed}))

    t0 = time.perf_counter()
    steps = record_on_workers(shared_pool(cfg.workers, cfg.ray_address), job, slots, 0, keep)
    dt = time.perf_counter() - t0
    executed = np.concatenate(shares).all(axis=1) if beta > 0 and shares else np.zeros(1)
    return episodes, {"env_steps": steps, "env_steps_per_s": steps / dt, "beta": beta,
                      "teacher_executed_share": float(executed.mean()),
                      "frames": sum(len(f["action"]) for f, _ in episodes), "workers": cfg.workers}


__all__ = ["RayOptions", "StudentLabeller", "check_ray_options", "drive_and_label_on_workers",
           "round_slots"]
