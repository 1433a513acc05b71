"""``msta-eval``: the paper's experiments on any checkpoints, as one command.

    msta-eval --policies teacher,CKPT_A,user/ckpt_b@v1 --suite quick --output_dir outputs/eval
    msta-eval --policies teacher,CKPT --suite paper --trials 500 --terrains stairs_up,discrete
    msta-eval --policies teacher,A,B,C,D --scenarios mask_matrix --matrix A=0.75:0.5,B=0.5:0.5,...
    msta-eval --policies teacher,CKPT --scenarios sensor_faults --faults stuck:0:encoder:2

``--policies`` entries: ``teacher`` (the reference teacher of ``--teacher.type``, rolled out
again as a row), ``teacher:<type>`` (another registered teacher as a fixed-input row, e.g.
``teacher:zero`` holds the default pose), a checkpoint directory, or a hub id
``user/name[@revision]`` (pulled by msta's one path-or-hub rule, ``msta.data.locate``).

Writes into ``--output_dir``: ``metrics.json`` (every number with its trial count and 95 %
interval per cell, the configuration, each policy's source and revision), ``report.md``
(Table I layout and one table per scenario, trials per cell, intervals, a warning for a
student whose figures do not change with its inputs), PNG plots for scenarios 2-5,
``timing.json``, and optionally a video (``--video``). See docs/eval.md for the metric
definitions; the runs themselves are :class:`msta.eval.evaluator.Evaluator`'s.
"""

from __future__ import annotations

import json
import os
import sys
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from msta.collect.faults import FaultSpec, split_faults
from msta.collect.ray_pool import RayOptions, check_ray_options, shared_pool
from msta.collect.rollout import film
from msta.collect.sim.render import save_video
from msta.data.budget import TimeLimitReached, deadline_after, stop
from msta.data.cli import parse_config
from msta.data.errors import DirectoryLockedError
from msta.data.locate import locate, reads_as_hub_id
from msta.data.locking import hold_directory
from msta.data.sensors import STUDENT_SENSORS
from msta.eval import report
from msta.eval.evaluator import METRICS_VERSION, RUNS, Evaluator, PolicyEntry, student_entry
from msta.eval.metrics import start_trials
from msta.eval.scenarios import (
    Condition,
    TrialConfig,
    build_conditions,
    get_scenario,
    get_suite,
    split_csv,
)
from msta.eval.sensor_faults import is_fault_run, load_guard
from msta.eval.trial_env import make_env, torch_eval_settings
from msta.policies.actor import StudentActor
from msta.policies.factory import select_device
from msta.policies.teacher.base import teacher_names
from msta.policies.teacher.config import TeacherConfig, build_teacher, teacher_revision


@dataclass
class EvalConfig(TrialConfig, RayOptions):
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
    faults: str = ""
    """the sensor_faults scenario's faults, comma-separated one-string forms
    ``TYPE:VALUE:TARGET[/rate=R][/onset=A-B]`` (e.g. ``stuck:0:encoder:2,bias:3:ang_vel``);
    empty = the default sweep (docs/faults.md)."""
    windows: str = ""
    """the history scenario's windows T, comma-separated (e.g. ``2,3,4,5,8`` for a student
    trained at T = 4); empty = the suite's (paper: 3,5,7,10,15,20)."""
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
        self.fault_list = [str(FaultSpec.parse(f)) for f in split_faults(self.faults)]
        if self.fault_list and "sensor_faults" not in self.scenario_list:
            raise ValueError("--faults needs --scenarios to include sensor_faults")
        self.window_list = _parse_windows(self.windows)
        if self.window_list and "history" not in self.scenario_list:
            raise ValueError("--windows needs --scenarios to include history")
        check_ray_options(self.workers, self.ray_address)
        if self.workers and self.device not in ("auto", "cpu"):
            raise ValueError(f"--workers runs the students on the workers' CPUs; "
                             f"--device={self.device} needs --workers=0")
        # resolved once (a bad or unavailable device fails here, in one line)
        self.torch_device = select_device("cpu" if self.workers else self.device)

    def resolved(self) -> dict[str, Any]:
        """The effective configuration as stored in metrics.json (``out`` left out)."""
        d = super().resolved()
        for k in ("workers", "ray_address"):  # where the trials ran changes no figure
            d.pop(k)
        d.update(device=self.torch_device.type,  # what ran, not "auto"
                 scenarios=self.scenario_list, policies=self.policy_list,
                 matrix={k: list(v) for k, v in self.matrix_map.items()})
        if self.fault_list:  # only when set: other metrics.json files stay as they were
            d["faults"] = self.fault_list
        else:
            d.pop("faults")
        if self.window_list:  # likewise
            d["windows"] = list(self.window_list)
        else:
            d.pop("windows")
        return d


def _parse_windows(text: str) -> tuple[int, ...]:
    """``--windows`` as sorted, distinct window lengths (each a whole number >= 1)."""
    out = set()
    for item in split_csv(text):
        if not item.isdigit() or int(item) < 1:
            raise ValueError(f"--windows: {item!r} is not a window length (a whole number >= 1)")
        out.add(int(item))
    return tuple(sorted(out))


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
                                f"{teacher_names()})") from None
    name = source if reads_as_hub_id(source) else local_name(Path(source))
    return student_entry(Path(path), name, source, cfg.matrix_map.get(source),
                         device=str(cfg.torch_device))

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
    started = time.time()
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
    plots = sorted(p.name for p in out.glob("*.png") if p.stat().st_mtime >= started - 1)
    print(f"\nmsta-eval: wrote {out / 'metrics.json'}, {out / 'report.md'}"
          + (f" and the plots {', '.join(plots)} in {out}/" if plots else
             " (no plots: they draw the sensor_removal, dead_joints, history, dummy_tokens and "
             "mask_matrix scenarios)"))


if __name__ == "__main__":
    main()
