"""``msta-compare``: train MSTA and every baseline on one dataset with the same budgets, then
evaluate them together and print the paper's Table I.

    msta-compare --collect_episodes=48 --output_dir=outputs/compare --preset=cpu \\
        --stage1_steps=800 --stage2_rounds=1 --episodes_per_round=16 --stage2_steps=300
    msta-compare --dataset=outputs/datasets/a1_teacher --policies=msta,gru --output_dir=...

For every policy of ``--policies`` (names: :data:`VARIANTS`, or any registered policy type):

1. **stage 1** (``msta.train.stage1.train``) on the shared teacher dataset, ``--stage1_steps``;
2. **stage 2** (``msta.train.stage2.correct``) on the policy's **own copy** of the dataset
   (``shutil.copytree`` before the first round), ``--stage2_rounds`` rounds of
   ``--episodes_per_round`` student episodes and ``--stage2_steps`` steps: every policy
   appends its own correction episodes, and the shared dataset is never written;
3. the final checkpoint is copied to ``output_dir/checkpoints/<policy>`` (the table's row
   name); rerun, a policy with a final checkpoint is skipped and a killed stage resumes.

Then one ``msta-eval`` run (``msta.eval.evaluate``) over the teacher and all final checkpoints on
the same trials writes ``output_dir/eval/`` and the table is printed and saved as
``output_dir/comparison.md``. See docs/baselines_comparison.md.
"""

from __future__ import annotations

import functools
import json
import shlex
import shutil
import sys
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import draccus

from msta.collect.record import CollectConfig, collect
from msta.data import layout
from msta.data.budget import TimeLimitReached, deadline_after, stop
from msta.data.checks import check_at_least
from msta.data.cli import parse_config
from msta.data.errors import DirectoryLockedError
from msta.data.features import load_info
from msta.data.figures import fmt as _fmt
from msta.data.locking import hold_directory
from msta.data.threads import check_threads
from msta.eval.apps.phases import PhaseLog
from msta.eval.eval_config import EvalConfig
from msta.eval.report import table_one
from msta.policies.checkpoint import PolicyPath
from msta.policies.config import PolicyConfig
from msta.policies.registry import register_builtin_configs, registered_policies
from msta.policies.teacher.config import TeacherConfig
from msta.train.config import STAGE2_MASK_RATIO, check_optimizer, training_mask_ratio
from msta.train.correct_config import CorrectConfig, RoundEvalConfig
from msta.train.train_config import TrainConfig

#: Comparison name -> (registered policy type, config overrides). Other registered policy
#: types are accepted by name with no overrides.
VARIANTS: dict[str, tuple[str, dict[str, Any]]] = {
    # the paper's "MSTA w/ learnable mask" (the mask token replaces one scalar's token)
    "msta_mask": ("msta", {"learnable_mask": True, "tokens": "scalar"}),
    # MSTA with the paper's tokens, one per scalar reading, at the same preset
    "msta_scalar": ("msta", {"tokens": "scalar"}),
}
#: The paper's Table I averages (normalized total reward at test masks 0 / 25 / 50 %).
PAPER_TABLE_I: dict[str, tuple[float | None, ...]] = {
    "msta": (0.97, 0.95, 0.94), "gru": (0.94, 0.92, 0.79), "tert_mask": (0.87, 0.90, 0.83),
    "msta_mask": (0.30, 0.80, 0.82), "rma_tcn": (0.98, None, None),
    "tert_concat": (1.01, None, None), "tert_separate": (1.00, None, None)}
#: Fields that must match output_dir/compare_config.json when a run is continued.
RUN_FIELDS = ("dataset", "collect_episodes", "collect_episode_length_s", "collect_num_envs",
              "preset", "teacher", "stage1_steps", "stage2_rounds", "stage2_steps",
              "episodes_per_round", "stage2_episode_length_s", "stage2_num_envs",
              "stage2_mask_ratio", "stage2_rollout_mask_ratios", "optimizer", "batch_size", "seed",
              "msta_history", "msta_mask_ratio")


@dataclass
class CompareConfig:
    """Args:
        dataset: teacher dataset root (with ``collect_episodes`` > 0: where to record it;
            default ``output_dir/teacher_dataset``).
        collect_episodes: record (or extend up to) this many teacher episodes first (0: use
            ``dataset`` as it is).
        collect_episode_length_s: episode length of the recorded teacher episodes (s).
        collect_num_envs: environments simulated together while recording.
        policies: comma-separated names: msta_mask (MSTA w/ learnable mask) or any
            registered policy type (msta, gru, rma_tcn, tert_concat, tert_separate, tert_mask,
            mlp, ...); empty = msta, msta_mask and every registered baseline.
        preset: policy preset for every policy (paper, cpu, tiny).
        msta_history: window T of the MSTA students (msta, msta_mask; 0: the preset's,
            15); the other policies keep their preset's T.
        msta_mask_ratio: stage-1 training mask ratio of the MSTA students (msta, msta_mask;
            0: the preset's, the paper's 0.75, as in the demo).
        teacher: the teacher that records, labels stage 2 and is the eval reference.
        stage1_steps: optimizer steps of stage 1 (every policy).
        stage2_rounds: correction rounds (0: no stage 2).
        stage2_steps: optimizer steps per correction round.
        episodes_per_round: student episodes appended per round.
        stage2_episode_length_s: time limit of the student episodes (s).
        stage2_num_envs: environments rolled out together in stage 2 (0: episodes_per_round,
            at most 32).
        stage2_mask_ratio: training mask ratio in stage 2 for policies trained with masking
            (config ``mask_ratio`` > 0; the paper: 0.5); the others keep 0.
        stage2_rollout_mask_ratios: test-time token-removal ratios the stage-2 rollouts of policies
            trained with masking drive at, spread over each round's robots (msta-correct's
            ``rollout_mask_ratios``; the demo's 0, 0.5: the rounds then label the states a
            masked student reaches); empty, and for the others: unmasked.
        optimizer: ``adamw``, or ``muon`` (Muon on transformer block matrices, AdamW on the
            rest; a student without transformer blocks gets AdamW alone), both stages.
        batch_size: windows per optimizer step (both stages).
        output_dir: output directory (per-policy runs, checkpoints/, eval/, comparison.md).
        seed: seeds training, rollouts and evaluation.
        eval_suite: msta-eval suite (quick, paper).
        eval_scenarios: msta-eval scenarios (token_removal = Table I).
        trials: evaluation trials per (policy, condition); 0 = the suite's.
        eval_terrains: comma-separated terrains; empty = the suite's.
        eval_episode_length_s: evaluation episode length (s); 0 = the suite's.
        num_threads: torch threads for training (0: the cores other work leaves free, msta.data.threads).
        progress: progress bars.
        max_minutes: stop after this many minutes at the next safe point (a training step
            with its checkpoint, a stage-2 phase, a round of evaluation trials) and exit with status
            75; the same command continues there. 0 = no limit.
    """

    dataset: str = ""
    collect_episodes: int = 0
    collect_episode_length_s: float = 10.0
    collect_num_envs: int = 16
    policies: str = ""
    preset: str = "cpu"
    msta_history: int = 0
    msta_mask_ratio: float = 0.0
    teacher: TeacherConfig = field(default_factory=TeacherConfig)
    stage1_steps: int = 800
    stage2_rounds: int = 1
    stage2_steps: int = 300
    episodes_per_round: int = 16
    stage2_episode_length_s: float = 10.0
    stage2_num_envs: int = 0
    stage2_mask_ratio: float = STAGE2_MASK_RATIO
    stage2_rollout_mask_ratios: tuple[float, ...] = ()
    optimizer: str = "adamw"
    batch_size: int = 64
    output_dir: str = "outputs/compare"
    seed: int = 0
    eval_suite: str = "quick"
    eval_scenarios: str = "token_removal"
    trials: int = 0
    eval_terrains: str = ""
    eval_episode_length_s: float = 0.0
    num_threads: int = 0
    progress: bool = True
    max_minutes: float = 0.0

    def __post_init__(self) -> None:
        check_threads(self.num_threads)
        given = self.given_policies()
        if self.policies and not given:
            raise ValueError("--policies is empty")
        if len(set(given)) != len(given):
            raise ValueError(f"--policies {self.policies!r} has duplicates")
        check_at_least(self, 1, "stage1_steps", "batch_size", "episodes_per_round",
                       "collect_num_envs")
        check_at_least(self, 0, "msta_history", "stage2_rounds", "stage2_steps", "collect_episodes",
                       "stage2_num_envs", "trials", "num_threads", "max_minutes")
        if not 0.0 <= self.msta_mask_ratio < 1.0:
            raise ValueError(f"msta_mask_ratio={self.msta_mask_ratio} must be in [0, 1)")
        for name in given:
            self.policy(name)  # unknown names / presets fail before any work
        if not 0.0 <= self.stage2_mask_ratio < 1.0:
            raise ValueError(f"stage2_mask_ratio={self.stage2_mask_ratio} must be in [0, 1)")
        self.stage2_rollout_mask_ratios = tuple(float(r) for r in self.stage2_rollout_mask_ratios)
        bad = [r for r in self.stage2_rollout_mask_ratios if not 0.0 <= r < 1.0]
        if bad:
            raise ValueError(f"stage2_rollout_mask_ratios: {bad[0]} must be in [0, 1)")
        check_optimizer(self.optimizer)
        if not self.dataset and not self.collect_episodes:
            raise ValueError("give --dataset=ROOT (a teacher dataset) or --collect_episodes=N")

    def given_policies(self) -> list[str]:
        """The names ``--policies`` gives, in order (empty: the default list)."""
        return [p.strip() for p in self.policies.split(",") if p.strip()]

    @functools.cached_property
    def policy_list(self) -> list[str]:
        """The students compared: ``--policies``, or MSTA, its learnable-mask variant and
        every registered baseline (their models imported to read the registry)."""
        return self.given_policies() or ["msta", "msta_mask", *registered_policies("baseline")]

    def policy(self, name: str) -> Any:
        """The config ``name`` trains with: its preset's, at ``msta_history`` and
        ``msta_mask_ratio`` for MSTA."""
        config = policy_config(name, self.preset)
        if config.type != "msta":
            return config
        given = {"history": self.msta_history, "mask_ratio": self.msta_mask_ratio}
        return replace(config, **{k: v for k, v in given.items() if v})

    @property
    def dataset_root(self) -> Path:
        return Path(self.dataset or Path(self.output_dir) / "teacher_dataset")


def policy_config(name: str, preset: str) -> Any:
    """The config of comparison entry ``name`` (:data:`VARIANTS`) at ``preset``.

    Args:
        name: a :data:`VARIANTS` key or a registered policy type.
        preset: preset name of that policy type.
    """
    ptype, overrides = VARIANTS.get(name, (name, {}))
    register_builtin_configs()  # the shipped types without their models (no torch)
    if ptype not in PolicyConfig.get_known_choices() and ptype not in registered_policies():
        known = sorted(set(VARIANTS) | set(registered_policies()))
        raise ValueError(f"unknown policy {name!r}; known: {known}")
    cls = PolicyConfig.get_choice_class(ptype)
    try:
        return cls.from_preset(preset, **overrides)
    except KeyError as e:
        raise ValueError(f"policy {name!r}: {e.args[0]}") from None


# ----- phases ----------------------------------------------------------------------------
def check_run_config(cfg: CompareConfig, out: Path) -> None:
    """Write ``compare_config.json``, or check that a continued run has the same budgets."""
    encoded = draccus.encode(cfg)
    path = out / "compare_config.json"
    if path.exists():
        saved = json.loads(path.read_text())
        saved.setdefault("stage2_rollout_mask_ratios", saved.pop("stage2_rollout_masks", None))
        saved.setdefault("msta_history", 0)  # written before the option: the preset's T
        saved.setdefault("msta_mask_ratio", 0.0)  # likewise: the preset's mask
        bad = [k for k in RUN_FIELDS if saved.get(k) != encoded.get(k)]
        if bad:
            raise ValueError(f"{out} holds a comparison with different {bad} "
                             f"(see {path}); choose another --output_dir")
    else:
        out.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(encoded, indent=1) + "\n")


def ensure_dataset(cfg: CompareConfig, prog: PhaseLog) -> Path:
    """The teacher dataset, recorded (or extended) first when ``collect_episodes`` > 0."""
    root = cfg.dataset_root
    have = load_info(root)["total_episodes"] if layout.is_dataset_root(root) else 0
    if cfg.collect_episodes and have < cfg.collect_episodes:  # recorded, or extended

        t = prog.start("collect", f"{cfg.collect_episodes} {cfg.teacher.label} episodes of "
                       f"{cfg.collect_episode_length_s:g} s -> {root}")
        collect(CollectConfig(teacher=cfg.teacher, episodes=cfg.collect_episodes,
                              num_envs=cfg.collect_num_envs, root=str(root), resume=True,
                              seed=cfg.seed, episode_length_s=cfg.collect_episode_length_s,
                              progress=cfg.progress))
        prog.done("collect", t)
    check_dataset(root)
    return root


def check_dataset(root: Path) -> None:
    """Raise, naming the path, unless ``root`` holds a dataset."""
    if not layout.is_dataset_root(root):
        raise FileNotFoundError(f"--dataset {str(root)!r}: {layout.info_path(root)} "
                                "missing (not a dataset; use --collect_episodes=N to record one)")


def stage1(cfg: CompareConfig, name: str, root: Path, run: Path, prog: PhaseLog,
           config: Any = None) -> Path:
    """Stage 1 of one policy (resumed when killed); returns its final checkpoint.

    Args:
        config: the policy config to train (default: ``cfg.policy(name)``;
            msta-repro's mask heatmap passes other training masks).
    """
    out = run / "stage1"
    final = out / "final"
    if (final / "config.json").is_file():
        return final
    resume = (out / "checkpoints" / "last").exists()
    if not resume and out.exists():  # killed before the first checkpoint: start over
        shutil.rmtree(out)
    t = prog.start(f"{name} stage 1", f"{cfg.stage1_steps} steps, batch {cfg.batch_size}"
                   f"{' (resumed)' if resume else ''}")
    from msta.train.stage1 import train  # lazy: torch after parsing (--help at once)

    train(TrainConfig(
        dataset=str(root), policy=config or cfg.policy(name), output_dir=str(out),
        resume=resume, steps=cfg.stage1_steps, batch_size=cfg.batch_size, seed=cfg.seed,
        optimizer=cfg.optimizer, save_every=max(100, cfg.stage1_steps // 4),
        eval_every=cfg.stage1_steps, num_threads=cfg.num_threads, progress=cfg.progress,
        max_minutes=prog.minutes_left()))
    prog.done(f"{name} stage 1", t)
    return final


def copy_dataset(root: Path, dest: Path) -> Path:
    """The policy's own copy of the teacher dataset (atomic: copied, then renamed), without
    the lock and what a resume set aside (``.msta-quarantine/``, left with the original)."""
    if dest.is_dir():
        return dest
    tmp = dest.with_name(dest.name + ".tmp")
    if tmp.exists():
        shutil.rmtree(tmp)
    shutil.copytree(root, tmp, ignore=shutil.ignore_patterns(*layout.LOCAL_ONLY_FILES,
                                                             layout.QUARANTINE_DIR))
    tmp.rename(dest)
    return dest


def stage2(cfg: CompareConfig, name: str, start: Path, root: Path, run: Path,
           prog: PhaseLog, mask: float | None = None) -> Path:
    """Stage 2 of one policy on its own dataset copy; returns the last round's checkpoint.

    Args:
        mask: the retraining mask ratio (default: ``cfg.stage2_mask_ratio`` for a policy
            trained with masking, else 0); given, the student is taken for a token-masking
            one and rolls out at ``cfg.stage2_rollout_mask_ratios``.
    """
    out = run / "stage2"
    last = out / f"round_{cfg.stage2_rounds}"
    if (last / "config.json").is_file():
        return last
    own = copy_dataset(root, run / "dataset")
    resume = (out / "progress.json").exists()
    masked = True  # an explicit mask: a token-masking student (msta-repro's heatmap)
    if mask is None:
        stage1 = cfg.policy(name).mask_ratio
        masked = stage1 > 0
        mask = training_mask_ratio(cfg.stage2_mask_ratio if masked else None, stage1, stage=2)
    envs = cfg.stage2_num_envs or min(cfg.episodes_per_round, 32)
    t = prog.start(f"{name} stage 2", f"{cfg.stage2_rounds} round(s) x {cfg.episodes_per_round}"
                   f" episodes + {cfg.stage2_steps} steps, mask {mask:g}, dataset copy {own}"
                   f"{' (resumed)' if resume else ''}")
    from msta.train.stage2 import correct  # lazy: torch after parsing (--help at once)

    correct(CorrectConfig(
        policy=PolicyPath(str(start)), dataset=str(own), output_dir=str(out),
        rounds=cfg.stage2_rounds,
        episodes_per_round=cfg.episodes_per_round, num_envs=envs,
        episode_length_s=cfg.stage2_episode_length_s, teacher=cfg.teacher, steps=cfg.stage2_steps,
        batch_size=cfg.batch_size, mask_ratio=mask, seed=cfg.seed, optimizer=cfg.optimizer,
        warmup_steps=min(20, cfg.stage2_steps // 5),  # the demo's: a round starts trained
        rollout_mask_ratios=cfg.stage2_rollout_mask_ratios if masked else (),
        save_every=max(100, cfg.stage2_steps // 2), eval_every=cfg.stage2_steps,
        eval=RoundEvalConfig(enabled=False), resume=resume, num_threads=cfg.num_threads,
        progress=cfg.progress, max_minutes=prog.minutes_left()))
    prog.done(f"{name} stage 2", t)
    return last


def train_policy(cfg: CompareConfig, name: str, root: Path, prog: PhaseLog) -> Path:
    """Both stages of one policy; the result is copied to ``out/checkpoints/<name>``."""
    out = Path(cfg.output_dir)
    ckpt = out / "checkpoints" / name
    if (ckpt / "config.json").is_file():
        print(f"[msta-compare] {name}: final checkpoint {ckpt} exists, skipped", flush=True)
        return ckpt
    run = out / "runs" / name
    final = stage1(cfg, name, root, run, prog)
    if cfg.stage2_rounds:
        final = stage2(cfg, name, final, root, run, prog)
    tmp = ckpt.with_name(name + ".tmp")
    if tmp.exists():
        shutil.rmtree(tmp)
    shutil.copytree(final, tmp)
    tmp.rename(ckpt)
    return ckpt


def run_eval(cfg: CompareConfig, ckpts: list[Path], prog: PhaseLog) -> dict[str, Any]:
    """One msta-eval run over the teacher and every final checkpoint (same trials)."""
    ecfg = EvalConfig(policies=",".join(["teacher", *map(str, ckpts)]), suite=cfg.eval_suite,
                      output_dir=str(Path(cfg.output_dir) / "eval"), trials=cfg.trials,
                      terrains=cfg.eval_terrains, scenarios=cfg.eval_scenarios,
                      episode_length_s=cfg.eval_episode_length_s, seed=cfg.seed, teacher=cfg.teacher,
                      progress=cfg.progress, resume=True)
    t = prog.start("eval", f"suite {cfg.eval_suite}, scenarios {cfg.eval_scenarios}, "
                   f"{ecfg.num_trials} trials of {ecfg.episode:g} s, {len(ckpts)} policies "
                   "+ teacher")
    ecfg.max_minutes = prog.minutes_left()
    from msta.eval.evaluation import evaluate  # lazy: torch after parsing (--help at once)

    metrics = evaluate(ecfg)
    prog.done("eval", t)
    return metrics


# ----- report ----------------------------------------------------------------------------
def _average(metrics: dict[str, Any], policy: str, metric: str = "total") -> list[float | None]:
    """Normalized terrain-average of ``policy`` per test mask (token_removal), None if n/a."""
    vals = []
    for r in metrics["runs"]:
        if r["policy"] == policy and r["scenario"] == "token_removal":
            ok = r["status"] == "ok"
            vals.append(r["normalized"]["per_terrain"]["average"][metric] if ok else None)
    return vals


def paper_table(metrics: dict[str, Any]) -> str:
    """Average normalized total reward per test mask, beside the paper's Table I."""
    rows = ["| policy | ours 0 % | ours 25 % | ours 50 % | paper 0 % | paper 25 % | paper 50 % |",
            "|---|---|---|---|---|---|---|"]
    for p in metrics["policies"]:
        if p["kind"] != "student":
            continue
        ours = _average(metrics, p["name"])
        paper = PAPER_TABLE_I.get(p["name"], (None,) * 3)
        rows.append(f"| {p['name']} | " + " | ".join(_fmt(v) for v in ours) + " | "
                    + " | ".join("-" if v is None else f"{v:.2f}" for v in paper) + " |")
    return "\n".join(rows)


def comparison_markdown(cfg: CompareConfig, metrics: dict[str, Any], command: str,
                        timing: dict[str, float]) -> str:
    """``output_dir/comparison.md``: the command, the budgets, Table I (three returns), timings."""
    ec = metrics["config"]
    setup = (
        f"Teacher `{cfg.teacher.label}`; dataset `{cfg.dataset_root}`; preset `{cfg.preset}`; "
        f"stage 1 {cfg.stage1_steps} steps; stage 2 {cfg.stage2_rounds} round(s) x "
        f"{cfg.episodes_per_round} episodes of {cfg.stage2_episode_length_s:g} s + {cfg.stage2_steps} "
        f"steps (mask {cfg.stage2_mask_ratio:g} for masked-trained policies); batch "
        f"{cfg.batch_size}; seed {cfg.seed}. Evaluation: suite `{cfg.eval_suite}`, "
        f"{ec['trials']} trials of {ec['episode_length_s']:g} s per (policy, test mask), terrains "
        f"{', '.join(ec['terrains'])}, levels {ec['levels']}.")
    lines = [
        "# MSTA vs baselines (msta-compare)", "", "```bash", command, "```", "", setup, "",
        "## Average normalized total reward vs the paper's Table I", "", paper_table(metrics), ""]
    for metric in ("total", "lin_tracking", "ang_tracking"):
        lines += [table_one(metrics, metric), ""]
    lines += ["## Time per phase (s)", "", "| phase | s |", "|---|---|"]
    lines += [f"| {k} | {v:.0f} |" for k, v in timing.items()]
    return "\n".join(lines) + "\n"


def compare(cfg: CompareConfig, command: str = "") -> dict[str, Any]:
    """Train every policy (both stages, same budgets), evaluate them together, report.

    Args:
        cfg: the parsed configuration.
        command: the command line recorded in ``comparison.md``.
    Returns:
        the content of ``out/eval/metrics.json``.
    """
    out = Path(cfg.output_dir)
    if not cfg.collect_episodes:
        check_dataset(cfg.dataset_root)  # before anything is written
    with hold_directory(out, "another msta-compare run"):  # one run per output_dir
        check_run_config(cfg, out)
        prog = PhaseLog(out, deadline=deadline_after(cfg.max_minutes))
        try:
            root = ensure_dataset(cfg, prog)
            ckpts = []
            for i, name in enumerate(cfg.policy_list, 1):
                print(f"[msta-compare] policy {i}/{len(cfg.policy_list)}: {name}", flush=True)
                ckpts.append(train_policy(cfg, name, root, prog))
            metrics = run_eval(cfg, ckpts, prog)
        except TimeLimitReached:
            prog.stopped()
            raise
        md = comparison_markdown(cfg, metrics, command or "msta-compare", prog.timing)
        (out / "comparison.md").write_text(md)
        print("\n" + paper_table(metrics) + "\n\n" + table_one(metrics, "total"))
        print(f"\nmsta-compare: wrote {out / 'comparison.md'} and {out / 'eval'}/", flush=True)
        return metrics


def main(argv: list[str] | None = None) -> None:
    """Console entry point (``msta-compare``); bad flags and inputs exit with one line."""
    args = sys.argv[1:] if argv is None else argv
    cfg = parse_config(CompareConfig, args, "msta-compare")  # bad flags: one line, exit 2
    try:  # under torchrun, rank 0 compares and the other ranks train with it (docs/scale.md)
        from msta.train.loop import rank0_runs  # lazy: torch after parsing (--help at once)

        rank0_runs(lambda: compare(cfg, shlex.join(["msta-compare", *args])), cfg.batch_size)
    except TimeLimitReached as e:
        stop("msta-compare", e)
    except (ValueError, FileNotFoundError, DirectoryLockedError) as e:
        print(f"msta-compare: error: {e}", file=sys.stderr)
        raise SystemExit(2) from None


if __name__ == "__main__":
    main()
