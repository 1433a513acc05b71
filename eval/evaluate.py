"""``msta-eval``: the paper's experiments on any checkpoints, as one command.

    msta-eval --policies teacher,CKPT_A,user/ckpt_b@v1 --suite quick --output_dir outputs/eval
    msta-eval --policies teacher,CKPT --suite paper --trials 500 --terrains stairs_up,discrete
    msta-eval --policies teacher,A,B,C,D --scenarios mask_matrix --matrix A=0.75:0.5,B=0.5:0.5,...

``--policies`` entries: ``teacher`` (the reference teacher of ``--teacher.type``, rolled out
again as a row), ``teacher:<type>`` (another registered teacher as a fixed-input row, e.g.
``teacher:zero`` holds the default pose), a checkpoint directory, or a hub id
``user/name[@revision]`` (pulled by msta's one path-or-hub rule, ``msta_data.locate``).

Writes into ``--output_dir``: ``metrics.json`` (every number with its trial count and 95 %
interval per cell, the configuration, each policy's source and revision), ``report.md``
(Table I layout and one table per scenario, trials per cell, intervals, a warning for a
student whose figures do not change with its inputs), PNG
plots for scenarios 2-5, ``timing.json``, and optionally a video (``--video``). See
docs/eval.md for the metric definitions.
"""

from __future__ import annotations

import json
import os
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

import policies.teacher.gait  # noqa: F401  (registers "gait", the default teacher)
from collect.rollout import film
from collect.sim.commands import CommandConfig
from collect.sim.env import EnvConfig, NoiseConfig, QuadrupedEnv
from collect.sim.randomization import RandomizationConfig
from collect.sim.terrain import TerrainConfig
from eval import report
from eval.metrics import (
    NotApplicable,
    TrialResults,
    aggregate,
    normalize,
    run_trials,
    start_trials,
)
from eval.scenarios import (
    Condition,
    TrialConfig,
    build_conditions,
    get_scenario,
    get_suite,
    split_csv,
)
from msta_data.budget import TimeLimitReached, check_deadline, deadline_after, stop
from msta_data.cli import parse_config
from msta_data.errors import DirectoryLockedError
from msta_data.locate import locate, reads_as_hub_id
from msta_data.locking import hold_directory
from msta_data.revision import content_revision, file_parts
from msta_data.sensors import STUDENT_SENSORS
from policies.actor import InputSpec, StudentActor
from policies.factory import load_policy, select_device
from policies.teacher.base import TEACHERS
from policies.teacher.config import TeacherConfig, build_teacher, teacher_revision

METRICS_VERSION = 2  # 2: trials and 95 % intervals per cell, per-level averages, run inputs


@dataclass
class EvalConfig(TrialConfig):
    """``msta-eval``: the paper's experiments on any checkpoints (docs/eval.md)."""

    policies: str = "teacher"
    """comma-separated entries: teacher, teacher:<type>, checkpoint dirs, hub ids
    user/name[@revision]."""
    output_dir: str = "outputs/eval"
    """output directory."""
    scenarios: str = ""
    """comma-separated scenario names; empty = the suite's."""
    matrix: str = ""
    """checkpoint -> train mask ratios for the heatmaps: ``CKPT=a1:a2,...`` (CKPT as
    written in --policies)."""
    teacher: TeacherConfig = field(default_factory=TeacherConfig)
    """the reference teacher (``--teacher.type=gait``)."""
    video: str = ""
    """``POLICY:TERRAIN[:LEVEL]`` renders a short MP4 of that policy (needs EGL)."""
    video_s: float = 4.0
    """video length (s)."""
    progress: bool = True
    """show progress bars."""
    resume: bool = False
    """reuse what an interrupted msta-eval finished in ``output_dir/eval_runs/`` (a file per
    policy x inputs, or per round of its trials; used only when the trials, the reference
    teacher, the checkpoint and its inputs are the same); false clears eval_runs/ first."""
    max_minutes: float = 0.0
    """stop after this many minutes, at the end of the round of trials in progress, and
    exit with status 75; the same command with --resume=true continues. 0 = no limit."""
    device: str = "auto"
    """where the students run: auto (CUDA when available, else CPU), cpu, cuda, cuda:1...
    The simulator and the teachers stay on the CPU. Figures on CUDA are not bit-identical
    to the CPU's (float rounding), so a stored run is reused only on the same device type."""

    def __post_init__(self) -> None:
        super().__post_init__()
        suite = get_suite(self.suite)
        self.policy_list = split_csv(self.policies)
        if not self.policy_list:
            raise ValueError("--policies is empty")
        self.scenario_list = split_csv(self.scenarios) or list(suite.scenarios)
        for s in self.scenario_list:
            get_scenario(s)
        self.matrix_map = _parse_matrix(self.matrix, self.policy_list)
        # resolved once (a bad or unavailable device fails here, in one line)
        self.torch_device = select_device(self.device)

    def resolved(self) -> dict[str, Any]:
        """The effective configuration as stored in metrics.json (``out`` left out)."""
        d = super().resolved()
        d.update(device=self.torch_device.type,  # what ran, not "auto"
                 scenarios=self.scenario_list, policies=self.policy_list,
                 matrix={k: list(v) for k, v in self.matrix_map.items()})
        return d


def _parse_matrix(text: str, policies: list[str]) -> dict[str, tuple[float, float]]:
    out = {}
    for item in split_csv(text):
        key, sep, ratios = item.rpartition("=")
        parts = ratios.split(":")
        try:
            a1, a2 = (float(p) for p in parts)
        except ValueError:
            raise ValueError(f"--matrix entry {item!r} must look like CKPT=0.75:0.5") from None
        if not sep or key not in policies:
            raise ValueError(f"--matrix entry {item!r}: {key!r} is not one of --policies "
                             f"{policies}")
        out[key] = (a1, a2)
    return out


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


def dir_revision(path: Path) -> str:
    """Short sha256 over a checkpoint directory's file names and bytes."""
    return content_revision(file_parts(path))


def load_entry(source: str, cfg: EvalConfig) -> PolicyEntry:
    """Resolve one --policies entry (teacher, teacher:<type>, directory or hub id)."""
    if source == "teacher":
        return PolicyEntry("teacher", source, "teacher", cfg.teacher.path,
                           teacher_revision(cfg.teacher), build_teacher(cfg.teacher))
    if source.startswith("teacher:"):
        tcfg = TeacherConfig(type=source.split(":", 1)[1])
        return PolicyEntry(tcfg.type, source, "teacher", "", teacher_revision(tcfg),
                           build_teacher(tcfg))
    try:  # msta's one path-or-hub rule (msta_data/locate.py)
        path = locate(source, "model", "--policies")
    except FileNotFoundError as e:
        raise FileNotFoundError(f"{e} (teachers: 'teacher' or 'teacher:<type>' with type in "
                                f"{sorted(TEACHERS)})") from None
    name = source if reads_as_hub_id(source) else Path(source).resolve().name
    return student_entry(Path(path), name, source, cfg.matrix_map.get(source),
                         device=str(cfg.torch_device))


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
    return PolicyEntry(name, source, "student", str(Path(path).resolve()), dir_revision(path),
                       load_policy(path, device=device), train_masks)


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


def make_env(cfg: TrialConfig, num_envs: int) -> QuadrupedEnv:
    """The evaluation simulator: tiles pinned (curriculum off), only the evaluated terrain
    columns built; :func:`eval.metrics.start_trials` gives every trial its random stream."""
    return QuadrupedEnv(EnvConfig(
        num_envs=num_envs, seed=cfg.seed, episode_length_s=cfg.episode, nthread=cfg.nthread,
        terrain=TerrainConfig(types=tuple(cfg.terrain_list), curriculum=False),
        commands=CommandConfig(use_heading=cfg.heading_commands),
        noise=NoiseConfig(enabled=cfg.noise),
        randomization=RandomizationConfig(enabled=cfg.randomization)))


def spec_dict(spec: InputSpec) -> dict[str, Any]:
    """JSON-ready InputSpec (metrics.json's ``spec``; files written before the window was
    named ``history`` have the key ``T``, :func:`eval.report.spec_history` reads both)."""
    out = {"history": spec.history, "drop_sensors": list(spec.drop_sensors),
           "dead_joints": list(spec.dead_joints), "mask_ratio": spec.mask_ratio,
           "seed": spec.seed}
    if spec.dummy_tokens:  # only when set: older metrics.json records stay identical
        out["dummy_tokens"] = spec.dummy_tokens
    return out


def _is_null(spec: InputSpec) -> bool:
    return spec.history is None and not spec.drop_sensors and not spec.dead_joints \
        and spec.mask_ratio == 0 and spec.dummy_tokens == 0


@contextmanager
def torch_eval_settings(threads: int, cuda: bool = False) -> Iterator[None]:
    """torch as an evaluation needs it (``threads`` threads, deterministic algorithms), and
    afterwards as it was, global RNG state included (evaluation seeds it per run).

    ``cuda``: students run on CUDA. TF32 is off (full fp32 matrix products and convolutions)
    and deterministic algorithms only warn where an op has none: cuBLAS is deterministic
    only with ``CUBLAS_WORKSPACE_CONFIG`` set before its first use (msta-eval sets it at
    start; a process that trained on the GPU first, msta-correct or msta-repro, has passed
    that point)."""
    tf32 = (torch.backends.cuda.matmul.allow_tf32, torch.backends.cudnn.allow_tf32)
    before = (torch.get_num_threads(), torch.are_deterministic_algorithms_enabled(),
              torch.is_deterministic_algorithms_warn_only_enabled(), torch.get_rng_state())
    torch.set_num_threads(threads)
    torch.use_deterministic_algorithms(True, warn_only=cuda)
    if cuda:
        torch.backends.cuda.matmul.allow_tf32 = torch.backends.cudnn.allow_tf32 = False
    try:
        yield
    finally:
        torch.set_num_threads(before[0])
        torch.use_deterministic_algorithms(before[1], warn_only=before[2])
        torch.set_rng_state(before[3])
        torch.backends.cuda.matmul.allow_tf32, torch.backends.cudnn.allow_tf32 = tf32


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
    return json.dumps([METRICS_VERSION, trials, teacher_revision(teacher)], sort_keys=True)


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
    """

    def __init__(self, cfg: TrialConfig, teacher: TeacherConfig, progress: bool = True,
                 store: Path | None = None, deadline: float | None = None) -> None:
        self.cfg, self.teacher, self.progress = cfg, teacher, progress
        self.store, self.deadline = store, deadline
        self._ran = False  # a run was made in this process (the deadline stops the next)
        # what the stored runs must share besides their key: the trials and the reference
        self._fingerprint = trial_fingerprint(cfg, teacher) if store is not None else ""
        self.layout = cfg.layout()
        self.env = make_env(cfg, len(self.layout.rounds(cfg.envs)[0]))
        self.reference: dict[str, Any] | None = None
        self.reference_trials: TrialResults | None = None
        self.timing: dict[str, float] = {}
        self._cache: dict[tuple, tuple[TrialResults, dict[str, Any]]] = {}

    def _run(self, label: str, make_actor, key: tuple = (), device: str = "cpu") -> TrialResults:
        """One run over every trial. With a store (``key``: what the actor sees) the run is
        ``store/<digest>.npz`` once finished, and each finished round of trials
        ``<digest>.round<r>.npz`` (its sums and the torch RNG state after it) until then: an
        interrupted run continues at its next round, with the same figures. ``device``: the
        device type the actor computes on; a CUDA run is stored apart from a CPU one (float
        rounding differs), and CPU runs keep the digest they had before CUDA was possible."""
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
        teacher = build_teacher(self.teacher)
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
            inputs), status, and ``raw`` and ``normalized`` (eval.metrics) or ``reason``.
        """
        if self.reference_trials is None:
            raise RuntimeError("run_reference() first: every figure is normalized by it")
        rec: dict[str, Any] = {"policy": entry.name, "scenario": cond.scenario,
                               "condition": cond.label, "value": cond.value,
                               "spec": spec_dict(cond.spec)}
        label = f"{entry.name} | {cond.key}"
        try:
            if entry.kind == "teacher":
                if not _is_null(cond.spec):
                    raise NotApplicable("the teacher is the privileged reference; test-time "
                                        "sensor changes apply to students only")
                key: tuple = (entry.name, entry.revision)
                make = (lambda r, n: entry.obj)
            else:
                try:
                    key = self._student_key(entry, cond.spec)
                except (ValueError, KeyError, NotImplementedError) as e:
                    raise NotApplicable(f"{type(e).__name__}: {e}") from e
                make = self._student_factory(entry, cond.spec)
            if key not in self._cache:
                res = self._run(label, make, key,
                                entry.obj.device.type if entry.kind == "student" else "cpu")
                self._cache[key] = (res, aggregate(res, self.layout))
        except NotApplicable as e:
            return {**rec, "status": "n/a", "reason": str(e)}
        res, raw = self._cache[key]
        return {**rec, "inputs": _digest(key[2:]), "status": "ok", "raw": raw,
                "normalized": normalize(res, self.reference_trials, self.layout)}

    @staticmethod
    def _student_factory(entry: PolicyEntry, spec: InputSpec):
        def make(r: int, n: int) -> StudentActor:  # a new mask stream per round
            return StudentActor(entry.obj, n, replace(spec, seed=spec.seed * 1_000_003 + r),
                                name=entry.name)
        return make


def plan(cfg: EvalConfig, entries: list[PolicyEntry]) -> list[tuple[PolicyEntry, Condition]]:
    """Every (policy, condition) pair, policies in --policies order."""
    suite = get_suite(cfg.suite)
    out = []
    for e in entries:
        sensors = e.obj.required_sensors if e.kind == "student" else STUDENT_SENSORS
        out += [(e, c) for c in build_conditions(cfg.scenario_list, suite, sensors, cfg.seed)]
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
    entries = entries if entries is not None else load_entries(cfg)
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
    ev = Evaluator(cfg, cfg.teacher, cfg.progress, store, deadline)
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
                      "revision": teacher_revision(cfg.teacher), **ev.reference},
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
    from collect.sim.render import save_video

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


def main(argv: list[str] | None = None) -> None:
    """Console entry point (``msta-eval``)."""
    # deterministic cuBLAS (students on CUDA): only read before CUDA's first matrix product
    os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")
    cfg = parse_config(EvalConfig, argv, "msta-eval")  # bad flags: one line, exit 2
    try:
        metrics = evaluate(cfg)
    except TimeLimitReached as e:
        stop("msta-eval", e, "the same command with --resume=true")
    except (KeyError, ValueError, FileNotFoundError, NotADirectoryError,
            DirectoryLockedError) as e:
        msg = e.args[0] if isinstance(e, KeyError) and e.args else e
        print(f"msta-eval: error: {msg}", file=sys.stderr)
        raise SystemExit(2) from None
    out = Path(cfg.output_dir)
    print(report.table_one(metrics, "total"))
    print(f"\nmsta-eval: wrote {out / 'metrics.json'}, {out / 'report.md'} and the plots in {out}/")


if __name__ == "__main__":
    main()
