"""msta-eval's run (its command line and description: :mod:`msta.eval.evaluate`): the
policies to evaluate, the plan of conditions, the runs through
:class:`msta.eval.evaluator.Evaluator`, metrics.json, report.md, plots and the video."""

from __future__ import annotations

import json
import time
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from msta.collect.ray_pool import shared_pool
from msta.collect.rollout import film
from msta.collect.sim.render import save_video
from msta.data.budget import deadline_after
from msta.data.locate import locate, reads_as_hub_id
from msta.data.locking import hold_directory
from msta.data.robot import LEGACY_ROBOT
from msta.data.sensors import STUDENT_SENSORS
from msta.eval import report
from msta.eval.eval_config import EvalConfig
from msta.eval.evaluator import METRICS_VERSION, RUNS, Evaluator, PolicyEntry, student_entry
from msta.eval.metrics import start_trials
from msta.eval.scenarios import (
    Condition,
    build_conditions,
    get_suite,
)
from msta.eval.sensor_faults import is_fault_run, load_guard
from msta.eval.trial_env import make_env, torch_eval_settings, trial_robot
from msta.policies.actor import StudentActor
from msta.policies.config import check_trained_on
from msta.policies.teacher.base import teacher_names
from msta.policies.teacher.config import TeacherConfig, build_teacher, teacher_revision


def local_name(path: Path) -> str:
    """A checkpoint folder's name in tables: its own name, or for lerobot-train's
    ``<run>/checkpoints/<step>/pretrained_model`` (``last`` followed) ``<run>@<step>``."""
    path = path.resolve()
    if path.name != "pretrained_model":
        return path.name
    step = path.parent
    if step.parent.name == "checkpoints":
        return f"{step.parent.parent.name}@{step.name}"
    return step.name or path.name


def load_entry(source: str, cfg: EvalConfig) -> PolicyEntry:
    """Resolve one --policies entry (teacher, teacher:<type>, directory or hub id); a
    teacher is built for ``cfg.robot`` (the A1 when empty)."""
    if source == "teacher" or source.startswith("teacher:"):
        return teacher_entry(source, cfg)
    try:  # msta's one path-or-hub rule (msta_data/locate.py)
        path = locate(source, "model", "--policies")
    except FileNotFoundError as e:
        raise FileNotFoundError(f"{e} (teachers: 'teacher' or 'teacher:<type>' with type in "
                                f"{teacher_names()})") from None
    name = source if reads_as_hub_id(source) else local_name(Path(source))
    return student_entry(Path(path), name, source, cfg.matrix_map.get(source),
                         device=str(cfg.torch_device))


def teacher_entry(source: str, cfg: EvalConfig) -> PolicyEntry:
    """The --policies entry ``teacher`` (``--teacher.*``) or ``teacher:<type>``, built for
    the robot of ``cfg`` (:func:`msta.eval.trial_env.trial_robot`).

    Args:
        source: the entry's text.
        cfg: the evaluation's configuration.
    """
    robot = trial_robot(cfg)
    if source == "teacher":
        return PolicyEntry("teacher", source, "teacher", cfg.teacher.path,
                           teacher_revision(cfg.teacher, robot), build_teacher(cfg.teacher, robot))
    tcfg = TeacherConfig(type=source.split(":", 1)[1])
    return PolicyEntry(tcfg.type, source, "teacher", "", teacher_revision(tcfg, robot),
                       build_teacher(tcfg, robot))


def load_entries(cfg: EvalConfig) -> list[PolicyEntry]:
    """Every --policies entry, names made unique."""
    entries, seen = [], {}
    for src in cfg.policy_list:
        e = load_entry(src, cfg)
        seen[e.name] = seen.get(e.name, 0) + 1
        if seen[e.name] > 1:
            e.name = f"{e.name}#{seen[e.name]}"
        entries.append(e)
    return entries


def eval_robot(cfg: EvalConfig, entries: list[PolicyEntry]) -> str:
    """The robot msta-eval simulates: ``--robot``, refusing in one line a checkpoint trained
    on another; empty: the one robot the student checkpoints were trained on (the A1 for
    teachers alone; checkpoints that name several robots are refused in one line)."""
    students = [e for e in entries if e.kind == "student"]
    if cfg.robot:
        for e in students:
            check_trained_on(e.obj.config.robots, cfg.robot_name, f"--policies entry {e.source}",
                             "--robot")
        return cfg.robot
    named = sorted({r for e in students for r in e.obj.config.robots})
    if len(named) > 1:
        trained = "; ".join(f"{e.source}: {', '.join(e.obj.config.robots)}" for e in students)
        raise ValueError(f"the checkpoints were trained on robots {named} ({trained}): pick "
                         "the simulated robot with --robot (each checkpoint must have been "
                         "trained on it)")
    return named[0] if named else LEGACY_ROBOT


def plan(cfg: EvalConfig, entries: list[PolicyEntry]) -> list[tuple[PolicyEntry, Condition]]:
    """Every (policy, condition) pair, policies in --policies order."""
    suite = get_suite(cfg.suite)
    values = {"sensor_faults": tuple(cfg.fault_list), "history": cfg.window_list}
    out = []
    for e in entries:
        sensors = e.obj.required_sensors if e.kind == "student" else STUDENT_SENSORS
        conds = build_conditions(cfg.scenario_list, suite, sensors, cfg.seed, values)
        # the guard is read only for guard rows (a damaged one cannot stop the others)
        guarded = (e.kind == "student" and any(c.removal == "guard" for c in conds)
                   and load_guard(e.path, 1) is not None)
        out += [(e, c) for c in conds
                if (c.removal != "guard" or guarded)  # no guard saved: no guard rows
                and (e.kind == "student" or not is_fault_run(c))]  # the teacher: fault-free
    return out


def evaluate(cfg: EvalConfig, entries: list[PolicyEntry] | None = None) -> dict[str, Any]:
    """Run the configured suite and write metrics.json, report.md and the plots.

    Args:
        cfg: the evaluation configuration.
        entries: already loaded policies (default: load ``cfg.policies``).
    Returns:
        the content of metrics.json.

    output_dir is locked once the policies are loaded, until the files are written:
    another process on it fails at once, naming this one's pid.
    """
    deadline = deadline_after(cfg.max_minutes)
    cfg.torch_device  # noqa: B018 - a bad or unavailable --device fails first, in one line
    entries = entries if entries is not None else load_entries(cfg)
    robot = eval_robot(cfg, entries)
    if robot != cfg.robot:  # the checkpoints' robot: a copy of cfg that names it
        built_for = cfg.robot or LEGACY_ROBOT  # what load_entries built the teachers for
        cfg = replace(cfg, robot=robot)
        for i, e in enumerate(entries):  # the teachers, built again for another robot only
            if e.kind == "teacher" and robot != built_for:
                entries[i] = replace(teacher_entry(e.source, cfg), name=e.name)
    with hold_directory(cfg.output_dir, "another msta-eval run") as out:
        return _evaluate_locked(cfg, entries, out, deadline)


def _evaluate_locked(cfg: EvalConfig, entries: list[PolicyEntry], out: Path,
                     deadline: float | None) -> dict[str, Any]:
    """:func:`evaluate` once output_dir is locked."""
    store = out / RUNS
    if not cfg.resume and store.is_dir():
        for f in store.glob("*.npz"):
            f.unlink()
    store.mkdir(parents=True, exist_ok=True)
    pool = shared_pool(cfg.workers, cfg.ray_address) if cfg.workers else None
    ev = Evaluator(cfg, cfg.teacher, cfg.progress, store, deadline, pool)
    pairs = plan(cfg, entries)
    t0 = time.perf_counter()
    cuda = any(e.kind == "student" and e.obj.device.type == "cuda" for e in entries)
    with torch_eval_settings(cfg.num_threads, cuda=cuda):
        ev.run_reference()
        runs = [ev.condition(e, c) for e, c in tqdm(pairs, desc="msta-eval", unit="run",
                                                     disable=not cfg.progress)]
    metrics = {
        "msta_eval_version": METRICS_VERSION,
        "config": cfg.resolved(),
        "reference": {"teacher": asdict(cfg.teacher),
                      "revision": teacher_revision(cfg.teacher, trial_robot(cfg)),
                      **ev.reference},
        "policies": [e.describe() for e in entries],
        "terrains": cfg.terrain_list,
        "levels": cfg.level_list,
        "runs": runs,
    }
    (out / "metrics.json").write_text(json.dumps(metrics, indent=1) + "\n")
    ev.timing["total"] = round(time.perf_counter() - t0, 3)
    (out / "timing.json").write_text(json.dumps(ev.timing, indent=1) + "\n")
    report.write_report(metrics, out)
    for line in report.identical_warnings(metrics):
        print(f"msta-eval: warning: {line}", flush=True)
    if cfg.video:
        save_policy_video(cfg, entries, out)
    return metrics


def save_policy_video(cfg: EvalConfig, entries: list[PolicyEntry], out: Path) -> Path:
    """Render ``cfg.video`` = ``POLICY:TERRAIN[:LEVEL]`` (one robot, ``cfg.video_s``) to MP4."""
    parts = cfg.video.rsplit(":", 2) if cfg.video.count(":") >= 2 else cfg.video.rsplit(":", 1)
    if len(parts) < 2:
        raise ValueError(f"--video {cfg.video!r} must look like POLICY:TERRAIN[:LEVEL]")
    name, terrain = parts[0], parts[1]
    level = int(parts[2]) if len(parts) > 2 else cfg.level_list[0]
    by_name = {e.name: e for e in entries} | {e.source: e for e in entries}
    if name not in by_name:
        raise ValueError(f"--video policy {name!r} is not one of {sorted(by_name)}")
    if terrain not in cfg.terrain_list:
        raise ValueError(f"--video terrain {terrain!r} is not evaluated ({cfg.terrain_list})")
    entry = by_name[name]
    env = make_env(replace(cfg, episode_length_s=max(cfg.video_s, cfg.episode)), 1)
    start_trials(env, np.array([0]), np.array([cfg.terrain_list.index(terrain)]),
                 np.array([level]))
    # teachers keep per-env state sized at first use: build a fresh one for one robot
    actor = load_entry(entry.source, cfg).obj if entry.kind == "teacher" \
        else StudentActor(entry.obj, 1)
    every = 5  # 10 frames per second of simulated time (software GL renders slowly)
    frames = film(env, actor, round(cfg.video_s / env.dt), every=every)
    path = out / f"video_{entry.name.replace('/', '_')}_{terrain}_L{level}.mp4"
    return save_video(frames, path, fps=round(1 / (every * env.dt)))
