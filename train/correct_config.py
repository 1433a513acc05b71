"""msta-correct's settings (:class:`CorrectConfig`), read by the stage-2 loop
(:mod:`msta.train.online`), its progress file and resume checks
(:mod:`msta.train.correct_progress`) and the apps that run stage 2.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

from msta.collect.ray_pool import RayOptions, check_ray_options
from msta.collect.sim.env_config import EnvConfig, check_sizes
from msta.data.checks import check_at_least
from msta.data.threads import check_threads
from msta.eval.scenarios import TrialConfig
from msta.policies.checkpoint import PolicyPath
from msta.policies.input_spec import InputSpec
from msta.policies.teacher.config import TeacherConfig
from msta.train.config import LoopConfig
from msta.train.push import check_push_to

#: The run directory's record of every round's phases (:mod:`msta.train.correct_progress`).
PROGRESS = "progress.json"
#: Fields that must match progress.json when resuming (they define the data).
RESUME_FIELDS = ("policy", "dataset", "teacher", "episodes_per_round", "num_envs",
                 "episode_length_s", "env", "beta", "beta_decay", "rollout", "seed",
                 "levels_from_dataset", "teacher_follows_robot", "keep_unfinished",
                 "rollout_mask_ratios")
#: Values of RESUME_FIELDS in progress.json files written before the field existed.
RESUME_LEGACY = {"levels_from_dataset": False, "teacher_follows_robot": False,
                 "keep_unfinished": False, "rollout_mask_ratios": []}


@dataclass
class RoundEvalConfig(TrialConfig):
    """The per-round evaluation: msta-eval's ``token_removal`` conditions at ``mask_ratios``
    on msta-eval's trials (``msta.eval.evaluator.Evaluator``: the same trial layout, per-trial
    random streams, metrics, normalization by the teacher and 95-percent intervals). Round r's
    figures are those of ``msta-eval --policies teacher,OUTPUT_DIR/round_<r>
    --scenarios token_removal`` with the same suite, trials, terrains, levels, episode_length_s,
    seed and device type; the model card shows them too. The trials simulate the rounds'
    robot (``--env.robot``; ``--eval.robot`` may only be left empty or name that robot). The
    defaults (the quick suite: 5 trials, one 3 s episode per paper terrain at level 1) keep a
    round's evaluation to a few seconds of simulation; raise --eval.trials (and --eval.levels)
    for tighter intervals.
    """

    enabled: bool = True
    """evaluate the starting checkpoint (round 0) and every round (false: no per-round table
    and no figures on the model card)."""
    mask_ratios: tuple[float, ...] = (0.0, 0.5)
    """test-time token-removal ratios evaluated for the student (0.5 = msta-eval's
    "mask 50" condition)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        self.mask_ratios = tuple(float(m) for m in self.mask_ratios)
        if not self.mask_ratios or not all(0.0 <= m < 1.0 for m in self.mask_ratios):
            raise ValueError(f"eval.mask_ratios={self.mask_ratios} must be values in [0, 1)")


@dataclass
class CorrectConfig(LoopConfig, RayOptions):
    """Args:
        steps: optimizer steps of each round's retraining.
        lr: peak learning rate of each round's retraining.
        mask_ratio: retraining token-removal ratio; null = 0.5 capped at the ratio the
            student was trained with (:func:`msta.train.config.training_mask_ratio`: a student
            trained without masking keeps 0). Each round checkpoint's training.json records
            it; its config.json keeps the student's stage-1 ratio.
        policy: the starting student: ``--policy.path=<checkpoint directory or hub id>``
            (stage 1's ``final/``; in Python a plain path is accepted too).
        dataset: dataset root to append to (a hub id is pulled and copied into output_dir).
        output_dir: round checkpoints, training runs and progress.json.
        rounds: correction rounds (raise it on ``--resume`` to run more).
        episodes_per_round: student episodes per round: with ``keep_unfinished`` the round
            runs ``ceil(episodes_per_round / num_envs)`` episode lengths of control steps
            and appends every episode in them (at least this many); otherwise exactly this
            many, the first to finish.
        num_envs: environments rolled out together.
        episode_length_s: time limit of the student episodes (s).
        keep_unfinished: keep every simulated frame of a round: the episodes still running
            when the round's steps are up are appended too, cut there (like a time limit).
            false: the first ``episodes_per_round`` episodes to finish (this over-samples
            short episodes, falls, and drops the steps of the unfinished ones).
        env: simulator options of the rollouts (its seed is shifted by the round).
        teacher: the labelling teacher (``--teacher.type``, ``--teacher.path``).
        beta: DAgger mixing: probability that an environment executes the teacher's action
            in a step; 0 = the student alone drives, so its data holds the states it reaches.
        beta_decay: beta of round r is ``beta * beta_decay**(r-1)``.
        rollout: student inputs during rollouts (mask_ratio, drop_sensors, dead_joints, history).
        rollout_mask_ratios: test-time token-removal ratios the rounds' student drives at,
            spread over the environments (environment i at ratio ``i % len``), e.g.
            ``[0,0.5]``: half drive with every token, half with half of them removed, so the
            rounds also hold (and the teacher labels) the states a masked student reaches;
            empty = every environment at ``rollout.mask_ratio``.
        levels_from_dataset: cap the rollouts' starting terrain level
            (``env.terrain.max_init_level``) at the highest level of the dataset's teacher
            episodes, so stage 2 corrects the student on the ground stage 1 taught it;
            false = ``env.terrain`` as given.
        teacher_follows_robot: a teacher with a plan of its own (the gait teacher's foot
            plan) keeps that plan near the robot's measured stance feet while it labels
            (``GaitTeacher.follow_robot``) instead of assuming its plan was executed;
            false = the teacher as it records its own data.
        recent_weight: sampling weight of an episode from round k in round r is
            ``recent_weight**(r-k)`` (teacher data is round 0); 1 = uniform over all frames.
        val_fraction: share of episodes held out for the validation loss (by episode).
        eval: the per-round evaluation.
        resume: continue the run in output_dir.
        device: auto (CUDA when available), cpu, cuda, ...: training, rollouts and the
            per-round evaluation.
        num_threads: torch threads (0: the cores other work leaves free, msta.data.threads).
        push_to: hub model repo ``user/name``: push each ``round_<r>`` with tag
            ``stage2-r<r>`` and a model card after its evaluation; empty = no push.
        push_private: create that repo as private.

    Why these defaults, with the runs that chose them: docs/results/2026-12-04-stage2-settings.md.
    """

    steps: int = 1000
    lr: float = 1e-3
    mask_ratio: float | None = None
    policy: PolicyPath = field(default_factory=PolicyPath)
    dataset: str = ""
    output_dir: str = "outputs/correct/msta"
    rounds: int = 4
    episodes_per_round: int = 64
    num_envs: int = 32
    episode_length_s: float = 10.0
    keep_unfinished: bool = True
    env: EnvConfig = field(default_factory=EnvConfig)
    teacher: TeacherConfig = field(default_factory=TeacherConfig)
    beta: float = 0.0
    beta_decay: float = 1.0
    rollout: InputSpec = field(default_factory=InputSpec)
    rollout_mask_ratios: tuple[float, ...] = ()
    levels_from_dataset: bool = True
    teacher_follows_robot: bool = True
    recent_weight: float = 1.0
    val_fraction: float = 0.05
    eval: RoundEvalConfig = field(default_factory=RoundEvalConfig)
    resume: bool = False
    device: str = "auto"
    num_threads: int = 0
    push_to: str = ""
    push_private: bool = False

    #: Fields that must match progress.json when resuming (a subclass may add its own).
    RESUME_FIELDS: ClassVar[tuple[str, ...]] = RESUME_FIELDS
    #: The command, as named in the lock error another run on the same output_dir gets.
    PROG: ClassVar[str] = "msta-correct"

    def __post_init__(self) -> None:
        check_threads(self.num_threads)
        super().__post_init__()
        if isinstance(self.policy, str | Path):  # the Python API may pass the path itself
            self.policy = PolicyPath(str(self.policy))
        check_push_to(self.push_to)
        check_ray_options(self.workers, self.ray_address)
        check_at_least(self, 1, "rounds", "episodes_per_round")
        check_sizes(self.num_envs, self.episode_length_s)
        if not 0.0 <= self.beta <= 1.0 or not 0.0 <= self.beta_decay <= 1.0:
            raise ValueError(f"beta={self.beta} and beta_decay={self.beta_decay} must be in [0, 1]")
        if not 0.0 < self.recent_weight <= 1.0:
            raise ValueError(f"recent_weight={self.recent_weight} must be in (0, 1]")
        if not 0.0 <= self.val_fraction < 1.0:
            raise ValueError(f"val_fraction={self.val_fraction} must be in [0, 1)")
        robot = self.env.robot_description.name
        self.teacher = self.teacher.on_robot(self.env.robot, "msta-correct", "--env.robot")
        if self.eval.robot and self.eval.robot_name != robot:
            raise ValueError(f"eval.robot={self.eval.robot} simulates robot "
                             f"{self.eval.robot_name!r}, the rounds robot {robot!r} "
                             "(--env.robot): the per-round evaluation runs on the rounds' "
                             "robot; leave --eval.robot empty")
        self.rollout_mask_ratios = tuple(float(r) for r in self.rollout_mask_ratios)
        bad = [r for r in self.rollout_mask_ratios if not 0.0 <= r < 1.0]
        if bad:
            raise ValueError(f"rollout_mask_ratios: {bad[0]} must be in [0, 1)")
