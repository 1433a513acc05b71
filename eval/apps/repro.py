"""``msta-repro``: the paper's experiments from an empty folder, in one resumable command.

    msta-repro --scale=reference --output_dir=outputs/repro --report_dir=docs/reference
    msta-repro --scale=tiny --output_dir=/tmp/repro          # seconds: the pipeline only
    msta-repro --scale=paper --max_minutes=7                 # one <= 10-minute call at a time

Phases (each skipped when its output exists, so re-running the command after a kill
continues where it stopped; a killed training resumes from its last checkpoint):

1. **dataset**: the teacher (``--teacher.*``, default the shipped PPO teacher rma_ppo) records
   ``collect_episodes`` episodes on terrain levels 0-2 with DART noise (the demo's recipe);
2. **policies**: every policy of ``--policies`` (default the paper's seven: MSTA, MSTA w/
   learnable mask, GRU, RMA-TCN, TERT concat / separate / w/ learnable mask) gets stage 1 and
   stage 2 with the same budgets, each on its own dataset copy (msta-compare's code:
   :func:`msta.eval.apps.compare.train_policy`); MSTA trains at the paper's masks 0.75 / 0.5, and
   the stage-2 rollouts of masked students drive half of the robots at test mask 0.5; at
   reference scale every student gets the demo's budgets and the MSTA students its window
   T = 4 (the others keep the paper's 15);
3. **heatmap**: MSTA students at every (stage-1, stage-2) training mask of the scale's grid
   (a reduced grid at reference scale; the paper's 4 x 4 at paper scale);
4. **evaluation** (msta-eval, the same trials, terrains, levels and seed everywhere):
   Table I (test masks 0 / 25 / 50 %) for every policy; one sensor removed, k dead joint
   encoders and the window T for MSTA (windows around the trained T: 2-8 for T = 4); the heatmap's test masks for the grid; MSTA and
   the GRU at levels 3-4 too;
5. **report**: ``report_dir/report.md`` (every table with the paper's value beside ours,
   the issue's minimums and the paper's qualitative findings checked with the numbers, the
   command, the machine, the revision and the time per phase), each evaluation's
   ``metrics.json``, ``report.md`` and plots under ``report_dir/<evaluation>/``.

Sizes and the estimated time are printed at the start. ``--scale=paper`` uses the paper's
sizes and picks CUDA when present; it is long, and every phase resumes. With
``--max_minutes=N`` a call stops at the first safe point after N minutes (an optimizer step,
saved with a checkpoint; a stage-2 phase; one round of evaluation trials, kept in the
evaluation's ``eval_runs/``) and exits with status 75; the next call of the same command
continues there, so a machine lent for ten minutes a command runs the study as a series of
calls (the teacher dataset and a round's rollouts are not split: keep N a few minutes
below the machine's limit)::

    until msta-repro --scale=paper --max_minutes=7; do [ $? -eq 75 ] || exit 1; done
"""

from __future__ import annotations

import json
import os
import platform
import shlex
import shutil
import subprocess
import sys
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

from msta.data import layout
from msta.data.budget import TimeLimitReached, deadline_after, stop
from msta.data.checks import check_at_least
from msta.data.cli import parse_config
from msta.data.errors import DirectoryLockedError
from msta.data.features import load_info
from msta.data.locking import hold_directory
from msta.data.threads import check_threads
from msta.eval.apps.compare import (
    PAPER_TABLE_I,
    CompareConfig,
    paper_table,
    stage1,
    stage2,
    train_policy,
)
from msta.eval.apps.demo import easy_terrain_dataset
from msta.eval.apps.phases import PhaseLog
from msta.eval.apps.repro_report import write_report
from msta.eval.eval_config import EvalConfig
from msta.policies.msta.configuration_msta import MSTAConfig
from msta.policies.teacher.config import TeacherConfig
from msta.train.config import STAGE2_ROLLOUT_MASK_RATIOS, check_optimizer

PROG = "msta-repro"
#: The paper's seven students (msta-compare names).
PAPER_POLICIES = ("msta", "msta_mask", "gru", "rma_tcn", "tert_concat", "tert_separate",
                  "tert_mask")
#: Added to them where the scale's preset gives msta sensor tokens: MSTA with the paper's
#: scalar tokens at the same preset, side by side.
SCALAR_MSTA = "msta_scalar"


@dataclass(frozen=True)
class Scale:
    """Budgets of one scale (every policy gets the same)."""

    collect_episodes: int
    collect_episode_length_s: float
    preset: str
    stage1_steps: int
    stage2_rounds: int
    episodes_per_round: int
    stage2_steps: int
    stage2_episode_length_s: float
    batch_size: int
    trials: int
    levels: str
    terrains: str
    eval_episode_length_s: float
    heatmap_stage1: tuple[float, ...]
    heatmap_stage2: tuple[float, ...]
    heatmap_rounds: int
    #: window T of the MSTA students (0: the preset's, the paper's 15); the others keep 15
    msta_history: int
    #: windows T of the MSTA window sweep (finding (b): T // 2 against T, longer ones unseen)
    windows: tuple[int, ...]
    #: estimated wall-clock on 2 CPU cores (reference: from the demo's measured phases)
    minutes: float


SCALES: dict[str, Scale] = {
    # the pipeline in seconds (tests)
    "tiny": Scale(3, 0.4, "tiny", 3, 1, 2, 2, 0.3, 8, 2, "0", "flat", 1.0, (0.75,),
                  (0.0, 0.5), 1, 4, (2, 3, 4, 5, 8), 1.0),
    # 2 CPU cores, <= 2.5 h: the demo's recipe for every policy (288 DART episodes, stage 1
    # 4,000 steps, seven rounds of 1,300 steps; MSTA at the demo's T = 4, which walks better
    # than T = 15 in less training time: docs/reference/README.md); the estimate adds up
    # the phases of the reference run timed on idle cores, heatmap included
    "reference": Scale(288, 10.0, "cpu", 4000, 7, 32, 1300, 10.0, 64, 100, "0,1,2", "", 5.0,
                       (0.5, 0.75), (0.0, 0.5), 1, 4, (2, 3, 4, 5, 8), 55.0),
    # the paper's sizes (a GPU machine): 5000 trials over every level, the full 4 x 4 grid
    "paper": Scale(4000, 20.0, "paper", 20000, 5, 256, 4000, 20.0, 256, 5000, "", "", 0.0,
                   (0.0, 0.25, 0.5, 0.75), (0.0, 0.25, 0.5, 0.75), 5, 0,
                   (3, 5, 7, 10, 15, 20), 1440.0),
}
#: Fields that must match output_dir/repro_config.json when a run is continued.
RUN_FIELDS = ("scale", "policies", "teacher", "optimizer", "seed")
#: The harder levels the main students (and the teacher) are also evaluated at.
HARD_LEVELS = "3,4"


@dataclass
class ReproConfig:
    """Args:
        scale: tiny (the pipeline in seconds), reference (2 CPU cores, <= 2.5 h), paper
            (the paper's sizes; CUDA when present).
        output_dir: every phase's outputs; re-running the command resumes there.
        report_dir: where report.md and the evaluations' metrics and plots go (default
            ``output_dir/report``; the committed reference run: docs/reference).
        policies: comma-separated msta-compare names; empty = the paper's seven (msta,
            msta_mask, gru, rma_tcn, tert_concat, tert_separate, tert_mask) and msta_scalar
            (MSTA with the paper's scalar tokens where the preset's msta has sensor tokens).
            The MSTA experiments (sensors, joints, window, heatmap) need msta in the list.
        teacher: records the dataset, labels stage 2 and is the evaluation's reference
            (default: the shipped PPO-trained RMA MLP, rma_ppo, the demo's teacher).
        optimizer: every student's optimizer, both stages (msta-compare's ``--optimizer``:
            adamw, or muon on transformer block matrices with AdamW on the rest).
        heatmap: train and evaluate the train-mask heatmap's MSTA students (false: skip
            them; the report says finding (a) was not measured). A finished study re-run
            with false writes its report from the evaluations it has.
        seed: seeds recording, training, rollouts and evaluation.
        num_threads: torch threads for training (0: the cores other work leaves free, msta.data.threads).
        progress: progress bars.
        max_minutes: stop after this many minutes at the next safe point (an optimizer step
            with its checkpoint, a stage-2 phase, a round of evaluation trials) and exit with status
            75; the same command continues there, so a machine lent for 10 minutes a
            command runs the study as a series of calls (e.g. ``--max_minutes=7``). 0 = no
            limit.
    """

    scale: str = "reference"
    output_dir: str = "outputs/repro"
    report_dir: str = ""
    policies: str = ""
    teacher: TeacherConfig = field(default_factory=TeacherConfig)
    optimizer: str = "adamw"
    heatmap: bool = True
    seed: int = 0
    num_threads: int = 0
    progress: bool = True
    max_minutes: float = 0.0

    def __post_init__(self) -> None:
        check_threads(self.num_threads)
        if self.scale not in SCALES:
            raise ValueError(f"unknown scale {self.scale!r}; scales: {', '.join(SCALES)}")
        check_optimizer(self.optimizer)
        check_at_least(self, 0, "num_threads", "max_minutes")
        self.policy_list = [p.strip() for p in self.policies.split(",") if p.strip()] \
            or self.default_policies()
        compare_config(self, Path(self.output_dir))  # unknown names fail here

    def default_policies(self) -> list[str]:
        """The paper's seven, and msta_scalar where the preset's msta has sensor tokens."""
        tokens = MSTAConfig.PRESETS[self.sizes.preset].get("tokens", MSTAConfig.tokens)
        return [*PAPER_POLICIES, *([SCALAR_MSTA] if tokens == "sensor" else [])]

    @property
    def sizes(self) -> Scale:
        return SCALES[self.scale]

    @property
    def msta_window(self) -> int:
        """The window T the study's MSTA students train at."""
        return compare_config(self, Path(self.output_dir)).policy("msta").history

    @property
    def report_path(self) -> Path:
        return Path(self.report_dir or Path(self.output_dir) / "report")


def compare_config(cfg: ReproConfig, root: Path) -> CompareConfig:
    """msta-compare's budgets for this scale (its training functions do the work)."""
    s = cfg.sizes
    return CompareConfig(
        dataset=str(root), policies=",".join(cfg.policy_list), preset=s.preset,
        msta_history=s.msta_history,
        teacher=cfg.teacher, stage1_steps=s.stage1_steps, stage2_rounds=s.stage2_rounds,
        stage2_steps=s.stage2_steps, episodes_per_round=s.episodes_per_round,
        stage2_episode_length_s=s.stage2_episode_length_s,
        stage2_num_envs=min(s.episodes_per_round, 32), batch_size=s.batch_size,
        stage2_rollout_mask_ratios=STAGE2_ROLLOUT_MASK_RATIOS, optimizer=cfg.optimizer,
        output_dir=str(Path(cfg.output_dir) / "compare"), seed=cfg.seed,
        num_threads=cfg.num_threads, progress=cfg.progress)


def check_run(cfg: ReproConfig, out: Path) -> None:
    """Write ``repro_config.json``, or check that a continued run is the same study."""
    path = out / "repro_config.json"
    now = json.loads(json.dumps(asdict(cfg)))
    if path.is_file():
        saved = json.loads(path.read_text())
        bad = [k for k in RUN_FIELDS if saved.get(k) != now.get(k)]
        if bad:
            raise ValueError(f"{out} holds a study with different {bad} (see {path}); "
                             "choose another --output_dir")
        return
    out.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(now, indent=1) + "\n")


def print_sizes(cfg: ReproConfig) -> None:
    from msta.policies.factory import select_device  # lazy: torch after parsing (--help at once)

    s = cfg.sizes
    grid = len(s.heatmap_stage1) * len(s.heatmap_stage2) if cfg.heatmap else 0
    print(f"[{PROG}] scale {cfg.scale}: teacher {cfg.teacher.label}; dataset "
          f"{s.collect_episodes} episodes of {s.collect_episode_length_s:g} s (levels 0-2, DART "
          f"noise 0.5); {len(cfg.policy_list)} policies ({', '.join(cfg.policy_list)}), preset "
          f"{s.preset} (MSTA at T = {cfg.msta_window}): stage 1 {s.stage1_steps} steps x "
          f"{s.batch_size}, stage 2 "
          f"{s.stage2_rounds} rounds x {s.episodes_per_round} episodes + {s.stage2_steps} "
          f"steps; heatmap {grid} MSTA students ({s.heatmap_rounds} rounds each); "
          f"evaluation {s.trials or 'suite'} "
          f"trials per condition, levels {s.levels or 'all'}; estimated "
          f"{s.minutes:.0f} min on 2 CPU cores; this machine: {os.cpu_count()} CPU cores, "
          f"students train and are evaluated on {select_device('auto')}", flush=True)


def ensure_dataset(cfg: ReproConfig, prog: PhaseLog) -> Path:
    root = Path(cfg.output_dir) / "teacher_dataset"
    s = cfg.sizes
    have = load_info(root)["total_episodes"] if layout.is_dataset_root(root) else 0
    if have < s.collect_episodes:  # recorded, or extended after a kill
        t = prog.start("dataset", f"{s.collect_episodes} {cfg.teacher.label} episodes")
        easy_terrain_dataset(root, s.collect_episodes, s.collect_episode_length_s,
                             "repro/a1_teacher", cfg.teacher, action_noise=0.5)
        prog.done("dataset", t)
    return root


def heatmap_students(cfg: ReproConfig, ccfg: CompareConfig, root: Path,
                     prog: PhaseLog) -> dict[Path, tuple[float, float]]:
    """One MSTA student per (stage-1, stage-2) training mask of the grid."""
    s, base = cfg.sizes, Path(cfg.output_dir) / "heatmap"
    hcfg = replace(ccfg, stage2_rounds=s.heatmap_rounds)
    out: dict[Path, tuple[float, float]] = {}
    main = ccfg.policy("msta")
    for m1 in s.heatmap_stage1:
        pol = replace(main, mask_ratio=m1)
        start = None
        shared = Path(ccfg.output_dir) / "runs" / "msta" / "stage1" / "final"
        if m1 == main.mask_ratio and (shared / "config.json").is_file():
            start = shared  # the study's own MSTA stage 1 (same config and budget)
        for m2 in s.heatmap_stage2:
            name = f"s1_{m1:g}_s2_{m2:g}"
            ckpt = base / "checkpoints" / name
            if not (ckpt / "config.json").is_file():
                start = start or stage1(hcfg, f"msta s1 {m1:g}", root, base / f"s1_{m1:g}",
                                        prog, config=pol)
                last = stage2(hcfg, f"msta s1 {m1:g} s2 {m2:g}", start, root, base / name,
                              prog, mask=m2)
                shutil.copytree(last, ckpt.with_name(name + ".tmp"), dirs_exist_ok=True)
                ckpt.with_name(name + ".tmp").rename(ckpt)
            out[ckpt] = (m1, m2)
    return out


def run_eval(cfg: ReproConfig, name: str, policies: list[Path], scenarios: str,
             prog: PhaseLog, matrix: str = "", levels: str = "",
             windows: tuple[int, ...] = ()) -> dict[str, Any]:
    """One msta-eval run (skipped when its metrics.json exists); ``levels``: other terrain
    levels than the scale's; ``windows``: the history scenario's."""
    out = Path(cfg.output_dir) / "eval" / name
    done = out / "metrics.json"
    if done.is_file():
        return json.loads(done.read_text())
    s = cfg.sizes
    ecfg = EvalConfig(policies=",".join(["teacher", *map(str, policies)]),
                      suite="quick" if cfg.scale == "tiny" else "paper", trials=s.trials,
                      terrains=s.terrains, levels=levels or s.levels,
                      episode_length_s=s.eval_episode_length_s, scenarios=scenarios,
                      matrix=matrix, windows=",".join(map(str, windows)), seed=cfg.seed,
                      teacher=cfg.teacher,
                      output_dir=str(out), progress=cfg.progress, resume=True,
                      nthread=0)  # MuJoCo threads: one per core of the machine
    t = prog.start(f"eval {name}", f"{scenarios}: {len(policies)} students + teacher")
    ecfg.max_minutes = prog.minutes_left()
    from msta.eval.evaluation import evaluate  # lazy: torch after parsing (--help at once)

    metrics = evaluate(ecfg)
    prog.done(f"eval {name}", t)
    return metrics


def repro(cfg: ReproConfig, command: str = PROG) -> Path:
    """Run (or continue) the study; returns report.md's path. output_dir is locked for the
    run: another process on it fails at once, naming this one's pid."""
    with hold_directory(cfg.output_dir, f"another {PROG} run") as out:
        check_run(cfg, out)
        print_sizes(cfg)
        prog = PhaseLog(out, PROG, deadline_after(cfg.max_minutes))
        try:
            return _study(cfg, command, out, prog)
        except TimeLimitReached:
            prog.stopped()
            raise


def _study(cfg: ReproConfig, command: str, out: Path, prog: PhaseLog) -> Path:
    """:func:`repro`'s phases."""
    root = ensure_dataset(cfg, prog)
    ccfg = compare_config(cfg, root)
    ckpts = {name: train_policy(ccfg, name, root, prog) for name in ccfg.policy_list}
    evals = {"table1": run_eval(cfg, "table1", list(ckpts.values()), "token_removal", prog)}
    hard = [ckpts[n] for n in ("msta", SCALAR_MSTA, "gru") if n in ckpts]
    if hard:
        evals["levels34"] = run_eval(cfg, "levels34", hard, "token_removal", prog,
                                     levels=HARD_LEVELS)
    if "msta" in ckpts:
        evals["msta"] = run_eval(cfg, "msta", [ckpts["msta"]],
                                 "sensor_removal,dead_joints,history", prog,
                                 windows=cfg.sizes.windows)
    if "msta" in ckpts and cfg.heatmap:
        grid = heatmap_students(cfg, ccfg, root, prog)
        matrix = ",".join(f"{p}={a:g}:{b:g}" for p, (a, b) in grid.items())
        evals["heatmap"] = run_eval(cfg, "heatmap", list(grid), "mask_matrix", prog, matrix)
    report = cfg.report_path
    report.mkdir(parents=True, exist_ok=True)
    for name in evals:
        src, dest = out / "eval" / name, report / name
        dest.mkdir(exist_ok=True)
        for f in src.iterdir():
            if f.suffix in (".json", ".md", ".png"):
                shutil.copy2(f, dest / f.name)
    path = write_report(cfg, evals, command, prog.timing, machine(), report)
    print(f"[{PROG}] wrote {path}", flush=True)
    return path


def machine() -> str:
    """The machine and revision the study ran on (for the report)."""
    try:
        rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], check=False,
                             capture_output=True, text=True, cwd=Path(__file__).parent,
                             timeout=10).stdout.strip()
    except OSError:
        rev = ""
    cpu = platform.processor() or platform.machine()
    return (f"{platform.node() or 'unknown host'}: {os.cpu_count()} cores ({cpu}), Python "
            f"{platform.python_version()}, revision {rev or 'unknown'}")


def main(argv: list[str] | None = None) -> None:
    args = sys.argv[1:] if argv is None else argv
    cfg = parse_config(ReproConfig, args, PROG)
    try:
        repro(cfg, " ".join([PROG, *map(shlex.quote, args)]))
    except TimeLimitReached as e:
        stop(PROG, e)
    except (ValueError, FileNotFoundError, DirectoryLockedError) as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        raise SystemExit(2) from None


__all__ = ["PAPER_POLICIES", "PAPER_TABLE_I", "SCALES", "ReproConfig", "main", "paper_table",
           "repro"]

if __name__ == "__main__":
    main()
