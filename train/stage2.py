"""Stage 2 itself (``msta-correct``'s rounds, described in :mod:`msta.train.online`, which
holds the command line so that ``--help`` answers before torch loads): roll out, label,
append, retrain, save and evaluate, round by round (:func:`correct`)."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import draccus
import numpy as np
import torch

from msta.collect.recorder import LabelledActor, record_rollouts
from msta.collect.sim.env import QuadrupedEnv
from msta.data.budget import check_deadline, deadline_after
from msta.data.features import load_info, sensor_column_to_name
from msta.data.locking import hold_directory
from msta.data.msta_json import check_robot, meta_robot
from msta.data.threads import run_threads
from msta.data.windows import episode_split, load_episode_table
from msta.data.writer import DatasetWriter
from msta.policies.actor import SplitActor, StudentActor, mask_split_actor
from msta.policies.base import StudentPolicy
from msta.policies.factory import load_policy, select_device
from msta.policies.input_spec import InputSpec
from msta.policies.teacher.config import build_teacher, teacher_revision
from msta.policies.weights import weights_revision
from msta.train.config import LoopConfig, training_mask_ratio
from msta.train.correct_config import CorrectConfig
from msta.train.correct_progress import (
    CorrectProgress,
    RoundRecord,
    check_labeller,
    check_output,
    load_progress,
    own_dataset,
    print_table,
    resolve_inputs,
    rollout_levels,
)
from msta.train.loop import fit, load_windows
from msta.train.online_workers import drive_and_label_on_workers
from msta.train.optim import seed_everything
from msta.train.push import dataset_source, push_round
from msta.train.round_eval import RoundEvaluator
from msta.train.state import atomic_json

#: One recorded episode: its frames by column and its provenance.
Episode = tuple[dict[str, np.ndarray], dict[str, Any]]
#: Called with a phase's name and the round when the phase starts.
PhaseHook = Callable[[str, int], None]
#: Turns the loaded starting student into the one the rounds train (msta-finetune).
Prepare = Callable[[StudentPolicy, Path], StudentPolicy]

#: A round checkpoint's record of how it was retrained (beside config.json).
TRAINING_RECORD = "training.json"


# ----- phases ----------------------------------------------------------------------------
def student_actor(policy: StudentPolicy, n: int, spec: InputSpec,
                  mask_ratios: tuple[float, ...] = ()) -> StudentActor | SplitActor:
    return mask_split_actor(policy, n, spec, mask_ratios, name=policy.config.type)


def drive_and_label(cfg: CorrectConfig, policy: StudentPolicy, r: int, revision: str,
             sensors: tuple[str, ...] | None = None) -> tuple[list[Episode], dict[str, float]]:
    """Phase 1-2: the round's student episodes with teacher labels, in memory (the shared
    rollout loop through :func:`msta.collect.recorder.record_rollouts`; the student drives, the
    teacher labels every step and executes with probability beta: ``LabelledActor``).
    ``sensors``: the ones to record (the dataset's; None: the default recorded set)."""
    if cfg.workers:  # on Ray workers, seeded per slot (msta.train.online_workers)
        return drive_and_label_on_workers(cfg, policy, r, revision, sensors)
    teacher = build_teacher(cfg.teacher, cfg.env.teacher_robot)  # fresh: sized per env batch
    if hasattr(teacher, "follow_robot"):
        teacher.follow_robot = cfg.teacher_follows_robot

    seed = cfg.env.seed + 1000 * r
    env = QuadrupedEnv(replace(cfg.env, num_envs=cfg.num_envs, seed=seed,
                               episode_length_s=cfg.episode_length_s))
    beta = cfg.beta * cfg.beta_decay ** (r - 1)
    spec = replace(cfg.rollout, seed=cfg.rollout.seed + r)
    mixed = LabelledActor(student_actor(policy, cfg.num_envs, spec, cfg.rollout_mask_ratios),
                          teacher, beta=beta, seed=cfg.seed + r)
    types = env.cfg.terrain.types
    episodes: list[Episode] = []

    def keep(frames: dict[str, np.ndarray], type_idx: int, level: int) -> None:
        episodes.append((frames, {
            "terrain": types[type_idx], "terrain_level": level, "source": "student",
            "round": r, "policy": policy.config.type, "policy_revision": revision,
            "seed": seed}))

    policy.eval()
    t0 = time.perf_counter()
    horizon = (-(-cfg.episodes_per_round // cfg.num_envs) * env.max_steps
               if cfg.keep_unfinished else None)
    steps = record_rollouts(env, mixed, cfg.episodes_per_round, keep, progress=cfg.progress,
                            horizon=horizon, sensors=sensors)
    dt = time.perf_counter() - t0
    share = mixed.label_share[0] / max(mixed.label_share[1], 1)
    return episodes, {"env_steps": steps, "env_steps_per_s": steps / dt, "beta": beta,
                      "teacher_executed_share": share,
                      "frames": sum(len(f["action"]) for f, _ in episodes)}


def append_episodes(root: Path, episodes: list[Episode], robot: str | None = None) -> int:
    """Phase 3: one writer session, one flush (one commit); returns the new episode count.
    ``robot``: the name of the robot the episodes simulated; a dataset of another robot is
    refused in one line (None: not checked)."""
    frames = sum(len(f["action"]) for f, _ in episodes)
    with DatasetWriter.open(root, flush_every_frames=frames + 1) as w:
        if robot is not None:
            check_robot(meta_robot(w.msta_meta), robot, str(root), "--env.robot")
        for f, prov in episodes:
            w.add_episode(f, prov)
        w.flush()
        return w.num_episodes


def check_tail(root: Path, before: int, expected: int, r: int, revision: str) -> bool:
    """Did a killed run already commit this round's episodes? (:mod:`msta.train.correct_progress`)"""
    table = load_episode_table(root)
    if len(table) == before:
        return False
    tail = table.iloc[before:]
    ok = (len(table) == before + expected and (tail["provenance/source"] == "student").all()
          and (tail["provenance/round"] == r).all()
          and (tail["provenance/policy_revision"] == revision).all())
    if not ok:
        raise RuntimeError(
            f"{root}: {len(table)} episodes, but progress.json recorded {before} before round "
            f"{r} and the round appends {expected} by {revision}; the dataset was modified by "
            "someone else. Restore it or start a new --output_dir.")
    return True


def round_loop(cfg: CorrectConfig, policy: StudentPolicy, r: int) -> LoopConfig:
    """Round ``r``'s retraining settings: the run's loop options with seed ``seed + r`` and
    the stage-2 mask ratio (:func:`msta.train.config.training_mask_ratio`; the student's config
    keeps the ratio stage 1 trained it with)."""
    ratio = training_mask_ratio(cfg.mask_ratio, policy.config.mask_ratio, stage=2)
    return replace(cfg.loop_part(), seed=cfg.seed + r, mask_ratio=ratio)


def retrain(cfg: CorrectConfig, policy: StudentPolicy, root: Path, r: int, out: Path,
            deadline: float | None = None) -> dict[str, float]:
    """Phase 4: :func:`msta.train.loop.fit` on the aggregate, from the current weights."""

    train_eps, val_eps = episode_split(root, cfg.val_fraction, cfg.seed + r)
    train_ds = load_windows(root, policy, train_eps)
    val_ds = load_windows(root, policy, val_eps) if val_eps else None
    weights = None
    if cfg.recent_weight < 1.0:
        rounds = load_episode_table(root).set_index("episode_index")["provenance/round"]
        per_ep = cfg.recent_weight ** (r - rounds.loc[train_ds.episodes].to_numpy())
        weights = np.repeat(per_ep, train_ds.lengths)
    loop = round_loop(cfg, policy, r)
    res = fit(policy, train_ds, val_ds, loop, out / "train" / f"round_{r}", resume=True,
              weights=weights, desc=f"round {r} train", deadline=deadline)
    return {"windows": len(train_ds), "train_samples_per_s": res.samples_per_s,
            "train_loss": res.train.get("loss", float("nan")),
            **{f"val_{k}": v for k, v in res.val.items()}, "mask_ratio": loop.mask_ratio}


def save_round(cfg: CorrectConfig, policy: StudentPolicy, r: int, out: Path) -> Path:
    """``output_dir/round_<r>/``: the student (its config.json keeps its stage-1 mask ratio)
    and ``training.json``, the settings this round retrained it with (mask ratio, steps, lr,
    seed)."""
    ckpt = policy.save_pretrained(out / f"round_{r}")
    loop = {k: v for k, v in draccus.encode(round_loop(cfg, policy, r)).items()
            if k not in ("max_minutes", "progress")}
    atomic_json(ckpt / TRAINING_RECORD, {"stage": 2, "round": r, **loop})
    return ckpt


# ----- the round loop -------------------------------------------------------------------
def correct(cfg: CorrectConfig, on_phase: PhaseHook | None = None,
            prepare: Prepare | None = None) -> CorrectProgress:
    """Run (or resume) stage 2; returns its progress.json record.

    Args:
        cfg: the parsed configuration.
        on_phase: called as ``on_phase(phase, round)`` at ``rolled_out`` (before the
            append), ``committed`` (episodes in the dataset, progress.json not yet updated),
            ``trained`` and ``evaluated``, and as ``on_phase("done", rounds)`` once every
            round is finished; tests raise there to simulate a kill.
        prepare: applied to the student after every load (msta-finetune: fewer inputs and a
            frozen transformer; it must give the same student when applied again to its own
            result). Before round 1 is trained, the prepared starting student is saved as
            ``output_dir/start/``: round 0 evaluates it and round 1 starts from it.

    Once the inputs are checked, output_dir is locked until the run ends
    (:func:`msta.data.locking.hold_directory`): another process on it fails at once.
    """
    deadline = deadline_after(cfg.max_minutes)
    out = Path(cfg.output_dir)
    check_output(cfg, out)
    ckpt, root = resolve_inputs(cfg, out)
    with hold_directory(out, f"another {cfg.PROG} run"):  # one run per output_dir
        return _correct_locked(cfg, out, ckpt, own_dataset(cfg, out, root),
                               on_phase or (lambda phase, r: None), prepare, deadline)


def _correct_locked(cfg: CorrectConfig, out: Path, ckpt: Path, root: Path, hook: PhaseHook,
                    prepare: Prepare | None, deadline: float | None) -> CorrectProgress:
    """:func:`correct` once output_dir is locked."""
    prog = load_progress(out, cfg, root)
    cfg = rollout_levels(cfg, root, prog)
    if (warning := check_labeller(cfg, root)) is not None:
        print(warning)
    if cfg.push_to and prog.dataset_source is None:  # before a hub tag can move
        prog.dataset_source = dataset_source(cfg.dataset, root)
    torch.set_num_threads(run_threads(out, cfg.num_threads, cfg.resume))
    device = select_device(cfg.device)
    seed_everything(cfg.seed)
    revision = teacher_revision(cfg.teacher, cfg.env.teacher_robot)
    if prog.teacher_revision is None:
        prog.teacher_revision = revision
    trained = [r for r, rec in prog.rounds.items() if rec.trained]
    start = out / f"round_{max(trained)}" if trained else ckpt
    if not trained and prepare is not None and (out / "start" / "config.json").is_file():
        # prepared by an earlier call: its processor holds the statistics of that time
        # (round 1's append has changed the dataset's since)
        start = out / "start"
    policy = load_policy(start, device=str(device))
    if prepare is not None:
        policy = prepare(policy, root)
        if not trained:
            ckpt = policy.save_pretrained(out / "start")
    evaluator = (RoundEvaluator(cfg.eval, cfg.teacher, str(device), robot=cfg.env.robot)
                 if cfg.eval.enabled else None)
    if evaluator and not trained and not prog.round(0).evaluated:
        evaluate_start(cfg, policy, ckpt, root, prog, evaluator)
    for r in range(1, cfg.rounds + 1):
        rec = prog.round(r)
        if not rec.evaluated:
            run_round(cfg, policy, root, out, r, prog, hook, evaluator, deadline)
        if cfg.push_to and (rec.pushed or {}).get("repo") != cfg.push_to:
            rec.pushed = push_round(cfg, prog.to_json(), r)
            prog.save()
    hook("done", cfg.rounds)
    return prog


def evaluate_start(cfg: CorrectConfig, policy: StudentPolicy, ckpt: Path, root: Path,
                   prog: CorrectProgress, evaluator: RoundEvaluator) -> None:
    """Round 0: the starting checkpoint's evaluation, and the reference teacher's."""
    prog.rounds[0] = RoundRecord(evaluated=True, checkpoint=str(ckpt),
                                 episodes_after=int(load_info(root)["total_episodes"]),
                                 policy_revision=weights_revision(policy),
                                 eval=evaluator.student(ckpt),
                                 eval_config=evaluator.cfg.resolved())
    prog.teacher_eval = evaluator.teacher()
    prog.save()
    print_table(prog)


def append_round(cfg: CorrectConfig, policy: StudentPolicy, root: Path, r: int,
                 rec: RoundRecord, prog: CorrectProgress, hook: PhaseHook) -> None:
    """Phases 1-3, or the recovery of an append a killed run committed (:mod:`msta.train.correct_progress`)."""
    revision = weights_revision(policy)
    # how many the round appends (recorded before the append; older files: exactly
    # episodes_per_round)
    expected = (cfg.episodes_per_round if rec.episodes_rolled_out is None
                else rec.episodes_rolled_out)
    if rec.episodes_before is not None and check_tail(root, rec.episodes_before, expected, r,
                                                      revision):
        rec.appended, rec.recovered_after_commit = True, True
        rec.episodes_after = rec.episodes_before + expected
        return
    info = load_info(root)
    rec.episodes_before, rec.policy_revision = int(info["total_episodes"]), revision
    prog.save()
    recorded = tuple(sensor_column_to_name(info["features"]).values())
    episodes, stats = drive_and_label(cfg, policy, r, revision, recorded)
    rec.episodes_rolled_out = len(episodes)
    prog.save()
    hook("rolled_out", r)
    total = append_episodes(root, episodes, cfg.env.robot_description.name)
    hook("committed", r)
    rec.appended, rec.episodes_after, rec.rollout = True, total, stats
    print(f"round {r}: appended {len(episodes)} student episodes ({stats['frames']:,} "
          f"frames, {stats['env_steps_per_s']:,.0f} env steps/s) -> {root} ({total})")


def run_round(cfg: CorrectConfig, policy: StudentPolicy, root: Path, out: Path, r: int,
              prog: CorrectProgress, hook: PhaseHook, evaluator: RoundEvaluator | None,
              deadline: float | None = None) -> None:
    """One round's phases, each skipped when progress.json marks it done; past
    ``deadline`` (``--max_minutes``) it stops after the phase that is running."""
    rec = prog.round(r)
    if not rec.appended:
        append_round(cfg, policy, root, r, rec, prog, hook)
        prog.save()
        check_deadline(deadline, f"round {r}: episodes appended")
    if not rec.trained:
        rec.train = retrain(cfg, policy, root, r, out, deadline)
        print(f"round {r}: trained {cfg.steps} steps on {rec.train['windows']:,} windows "
              f"({rec.train['train_samples_per_s']:.0f} samples/s)")
        rec.checkpoint = str(save_round(cfg, policy, r, out))
        rec.trained, rec.trained_revision = True, weights_revision(policy)
        prog.save()
        hook("trained", r)
        check_deadline(deadline, f"round {r}: trained")
    if evaluator is not None:
        rec.eval = evaluator.student(out / f"round_{r}")
        rec.eval_config = evaluator.cfg.resolved()
        prog.teacher_eval = evaluator.teacher()
    rec.evaluated = True
    prog.save()
    hook("evaluated", r)
    print_table(prog)
    if r < cfg.rounds:
        check_deadline(deadline, f"round {r}: done")
