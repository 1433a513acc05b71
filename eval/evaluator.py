"""The evaluation's engine: :class:`Evaluator` runs conditions on one shared simulator and
normalizes every figure by the reference teacher on the same trials.

msta-eval (:mod:`msta.eval.evaluate`) and msta-correct's per-round evaluation
(``msta.train.round_eval``) both use it, so the same checkpoint on the same trials (and device
type) gets the same figures in both. Also here: the rows (:class:`PolicyEntry`), the
evaluation simulator (:func:`make_env`), torch as an evaluation needs it
(:func:`torch_eval_settings`), and the store of finished runs that ``--resume`` reuses
(``output_dir/eval_runs/``: one file per run, or per round of its trials, keyed by a
digest of what the run depends on).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from msta.data.budget import check_deadline
from msta.data.revision import checkpoint_revision, content_revision
from msta.data.robot import LEGACY_ROBOT
from msta.eval.metrics import NotApplicable, TrialResults, aggregate, normalize, run_trials
from msta.eval.scenarios import Condition, TrialConfig
from msta.eval.sensor_faults import (
    detection_summary,
    fault_key,
    fault_record,
    faulty_factory,
    is_fault_run,
)
from msta.eval.trial_env import make_env, trial_robot
from msta.eval.trials_pool import run_trials_on_workers
from msta.policies.actor import StudentActor
from msta.policies.factory import load_policy
from msta.policies.input_spec import InputSpec
from msta.policies.teacher.config import TeacherConfig, build_teacher, teacher_revision

METRICS_VERSION = 2  # 2: trials and 95 % intervals per cell, per-level averages, run inputs


@dataclass
class PolicyEntry:
    """One row of the outputs.

    Args:
        name: row label.
        source: the --policies entry as written.
        kind: "teacher" (fixed inputs, no input changes) or "student".
        path: local checkpoint directory ("" for teachers).
        revision: content hash (checkpoint files) or the teacher's revision.
        obj: the loaded teacher or student.
        train_masks: (stage-1, stage-2) mask ratios for the heatmaps, if known.
    """

    name: str
    source: str
    kind: str
    path: str
    revision: str
    obj: Any = None
    train_masks: tuple[float, float] | None = None

    def describe(self) -> dict[str, Any]:
        d = {k: getattr(self, k) for k in ("name", "source", "kind", "path", "revision")}
        d["train_masks"] = list(self.train_masks) if self.train_masks else None
        if self.kind == "student":
            d["type"] = self.obj.config.type
            d["input_sensors"] = list(self.obj.required_sensors)
        return d


def student_entry(path: Path, name: str, source: str,
                  train_masks: tuple[float, float] | None = None,
                  device: str = "cpu") -> PolicyEntry:
    """A student checkpoint directory as a row.

    Args:
        path: the local checkpoint directory.
        name: row label.
        source: how the user named it (directory or hub id).
        train_masks: (stage-1, stage-2) mask ratios for the heatmaps, if known.
        device: where the student runs (msta-eval's ``--device``, resolved).
    """
    return PolicyEntry(name, source, "student", str(Path(path).resolve()), checkpoint_revision(path),
                       load_policy(path, device=device), train_masks)


def spec_dict(spec: InputSpec) -> dict[str, Any]:
    """JSON-ready InputSpec (metrics.json's ``spec``; files written before the window was
    named ``history`` have the key ``T``, :func:`msta.eval.report.spec_history` reads both)."""
    out = {"history": spec.history, "drop_sensors": list(spec.drop_sensors),
           "dead_joints": list(spec.dead_joints), "mask_ratio": spec.mask_ratio,
           "seed": spec.seed}
    if spec.dummy_tokens:  # only when set: older metrics.json records stay identical
        out["dummy_tokens"] = spec.dummy_tokens
    return out


def _is_null(spec: InputSpec) -> bool:
    return spec.history is None and not spec.drop_sensors and not spec.dead_joints \
        and spec.mask_ratio == 0 and spec.dummy_tokens == 0


def _digest(key: tuple) -> str:
    return content_revision([repr(key)])


#: ``output_dir/eval_runs/``: one finished run (or round of trials) per file (``--resume``).
RUNS = "eval_runs"
#: what TrialConfig.resolved() holds besides its fields (the effective values)
_RESOLVED = ("trials", "terrains", "levels", "episode_length_s", "num_envs")


def trial_fingerprint(cfg: TrialConfig, teacher: TeacherConfig) -> str:
    """What every stored run of an evaluation shares besides its own key (the policy's
    name, checkpoint revision and inputs): the metrics version, the trials (every
    TrialConfig setting that changes a figure) and the reference teacher's revision."""
    names = {f.name for f in fields(TrialConfig)} | set(_RESOLVED)
    trials = {k: v for k, v in TrialConfig.resolved(cfg).items() if k in names}
    if trials["robot"] == LEGACY_ROBOT:  # the A1's runs keep the digests they had before --robot
        del trials["robot"]
    return json.dumps([METRICS_VERSION, trials, teacher_revision(teacher, trial_robot(cfg))],
                      sort_keys=True)


def save_trials(res: TrialResults, path: Path, **extra: np.ndarray) -> None:
    """Write per-trial sums (and ``extra`` arrays) atomically: a kill leaves no half file."""
    tmp = path.with_name(path.stem + ".tmp.npz")
    np.savez(tmp, max_steps=np.int64(res.max_steps), **extra,
             **{f.name: getattr(res, f.name) for f in fields(res) if f.name != "max_steps"})
    tmp.replace(path)


def load_trials(path: Path) -> TrialResults:
    with np.load(path) as z:
        return TrialResults(**{f.name: z[f.name] for f in fields(TrialResults)
                               if f.name != "max_steps"}, max_steps=int(z["max_steps"]))


def _round_path(path: Path, r: int) -> Path:
    return path.with_name(f"{path.stem}.round{r}.npz")


class Evaluator:
    """Runs conditions on one shared evaluation env and caches identical student inputs.

    msta-eval and msta-correct's per-round evaluation both use it: the same checkpoint
    and :class:`TrialConfig` give the same figures in both.

    Args:
        cfg: which trials to run.
        teacher: the reference teacher every return is normalized by.
        progress: show progress bars.
        store: the folder of finished runs to reuse and add to (``output_dir/eval_runs``);
            None keeps nothing.
        deadline: ``time.monotonic()`` limit (``msta.data.budget``); checked between runs
            and rounds of trials, never inside one.
        pool: Ray workers (``msta.collect.ray_pool.RayPool``) that run the rounds of trials
            (:mod:`msta.eval.trials_pool`; the same figures); the fault runs with removal, whose
            detection figures need their actors here, stay in this process. None: all here.
    """

    def __init__(self, cfg: TrialConfig, teacher: TeacherConfig, progress: bool = True,
                 store: Path | None = None, deadline: float | None = None,
                 pool: Any = None) -> None:
        self.cfg, self.teacher, self.progress = cfg, teacher, progress
        self.store, self.deadline, self.pool = store, deadline, pool
        self._ran = False  # a run was made in this process (the deadline stops the next)
        # what the stored runs must share besides their key: the trials and the reference
        self._fingerprint = trial_fingerprint(cfg, teacher) if store is not None else ""
        self.layout = cfg.layout()
        self.env = make_env(cfg, len(self.layout.rounds(cfg.envs)[0]))
        self.reference: dict[str, Any] | None = None
        self.reference_trials: TrialResults | None = None
        self.timing: dict[str, float] = {}
        self._cache: dict[tuple, tuple[TrialResults, dict[str, Any]]] = {}

    def _run(self, label: str, make_actor, key: tuple = (), device: str = "cpu",
             here: bool = False) -> TrialResults:
        """One run over every trial. With a store (``key``: what the actor sees) the run is
        ``store/<digest>.npz`` once finished, and each finished round of trials
        ``<digest>.round<r>.npz`` (its sums and the torch RNG state after it) until then: an
        interrupted run continues at its next round, with the same figures. ``device``: the
        device type the actor computes on; a CUDA run is stored apart from a CPU one (float
        rounding differs), and CPU runs keep the digest they had before CUDA was possible.
        ``here``: run in this process even with a pool."""
        stored = (self._fingerprint, key) if device == "cpu" else (self._fingerprint, key, device)
        path = self.store / f"{_digest(stored)}.npz" \
            if self.store is not None and key else None
        if path is not None and path.is_file():
            return load_trials(path)
        if self._ran:
            check_deadline(self.deadline, f"before {label}")
        # a policy drawing from the global torch RNG (none of msta's: StudentActor passes
        # its own generator) gets the same draws on every run
        torch.manual_seed(self.cfg.seed)
        done: list[TrialResults] = []
        while path is not None and _round_path(path, len(done)).is_file():
            rp = _round_path(path, len(done))
            done.append(load_trials(rp))
            with np.load(rp) as z:
                torch.set_rng_state(torch.from_numpy(z["torch_rng"].copy()))

        def on_round(r: int, rounds: int, res: TrialResults) -> None:
            self._ran = True
            if path is not None:
                save_trials(res, _round_path(path, r),
                            torch_rng=torch.get_rng_state().numpy())
            if r + 1 < rounds:
                check_deadline(self.deadline, f"{label}: after round {r + 1} of {rounds}")

        t0 = time.perf_counter()
        if self.pool is not None and not here:  # a bar over the rounds the workers finish
            bar = tqdm(total=self.layout.trials, initial=sum(len(d.steps) for d in done),
                       desc=f"{label} (Ray)", unit="trial", disable=not self.progress,
                       leave=False)

            def on_round_bar(r: int, rounds: int, part: TrialResults) -> None:
                on_round(r, rounds, part)
                bar.update(min(len(part.steps), bar.total - bar.n))

            try:
                res = run_trials_on_workers(self.pool, self.cfg, make_actor, self.layout,
                                            self.env.max_steps, done, on_round_bar)
            finally:
                bar.close()
        else:
            res = run_trials(self.env, make_actor, self.layout, desc=label,
                             progress=self.progress, done=done, on_round=on_round)
        self.timing[label] = round(time.perf_counter() - t0, 3)
        if path is not None:
            save_trials(res, path)
            for f in path.parent.glob(f"{path.stem}.round*.npz"):
                f.unlink()
        return res

    def run_reference(self) -> dict[str, Any]:
        """Roll the reference teacher over every trial."""
        teacher = build_teacher(self.teacher, self.env.cfg.teacher_robot)
        self.reference_trials = self._run("reference teacher", lambda r, n: teacher,
                                          ("reference",))
        self.reference = aggregate(self.reference_trials, self.layout)
        return self.reference

    def _student_key(self, entry: PolicyEntry, spec: InputSpec) -> tuple:
        actor = StudentActor(entry.obj, 1, spec)
        channels = tuple(sorted((k, tuple(v)) for k, v in actor.channels.items()))
        key = (entry.name, entry.revision, actor.history, actor.sensors, channels, spec.mask_ratio)
        # appended only when set, so the inputs digests of the other conditions do not change
        return key + ((("dummy_tokens", spec.dummy_tokens),) if spec.dummy_tokens else ())

    def condition(self, entry: PolicyEntry, cond: Condition) -> dict[str, Any]:
        """Metrics of one policy under one condition (or n/a with the reason).

        Returns:
            the run record of metrics.json: policy, scenario, condition, value, spec,
            ``inputs`` (a digest of what the policy really sees: equal digests mean equal
            inputs), status, and ``raw`` and ``normalized`` (msta.eval.metrics) or ``reason``.
        """
        if self.reference_trials is None:
            raise RuntimeError("run_reference() first: every figure is normalized by it")
        rec: dict[str, Any] = {"policy": entry.name, "scenario": cond.scenario,
                               "condition": cond.label, "value": cond.value,
                               "spec": spec_dict(cond.spec), **fault_record(cond, self.cfg.seed)}
        label = f"{entry.name} | {cond.key}"
        actors: list = []  # a fault run's actors (detection figures)
        detect = cond.removal in ("oracle", "guard")  # its actors are read afterwards
        try:
            if entry.kind == "teacher":
                if not _is_null(cond.spec) or is_fault_run(cond):
                    raise NotApplicable("the teacher is the privileged reference; test-time "
                                        "sensor changes apply to students only")
                key: tuple = (entry.name, entry.revision)
                make = (lambda r, n: entry.obj)
            else:
                key, make = self._student_run(entry, cond, actors)
            if key not in self._cache:
                res = self._run(label, make, key,
                                entry.obj.device.type if entry.kind == "student" else "cpu",
                                here=detect)
                self._cache[key] = (res, aggregate(res, self.layout))
        except NotApplicable as e:
            return {**rec, "status": "n/a", "reason": str(e)}
        res, raw = self._cache[key]
        if detect:
            rec["detection"] = detection_summary(actors, res.steps, self.env.dt)
        return {**rec, "inputs": _digest(key[2:]), "status": "ok", "raw": raw,
                "normalized": normalize(res, self.reference_trials, self.layout)}

    def _student_run(self, entry: PolicyEntry, cond: Condition, actors: list) -> tuple:
        """(inputs key, actor factory) of a student under ``cond``; a fault run's actors
        are appended to ``actors``."""
        try:
            key = self._student_key(entry, cond.spec) + fault_key(cond, self.cfg.seed)
        except (ValueError, KeyError, NotImplementedError) as e:
            raise NotApplicable(f"{type(e).__name__}: {e}") from e
        if is_fault_run(cond):
            return key, faulty_factory(entry, cond, self.cfg.seed, self.env.dt, actors)
        return key, self._student_factory(entry, cond.spec)

    @staticmethod
    def _student_factory(entry: PolicyEntry, spec: InputSpec):
        def make(r: int, n: int) -> StudentActor:  # a new mask stream per round
            return StudentActor(entry.obj, n, replace(spec, seed=spec.seed * 1_000_003 + r),
                                name=entry.name)
        return make
