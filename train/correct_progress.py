"""``msta-correct``'s run directory: ``progress.json`` as typed records, and the checks made
before a run touches its output directory.

``progress.json`` (written atomically after every phase) is a :class:`CorrectProgress`: the run's
configuration, the dataset it appends to, run-wide decisions (the rollouts' terrain level
cap, the labelling teacher's revision, the reference teacher's figures) and one
:class:`RoundRecord` per round saying which phases are done and what they measured. On disk
the rounds are keyed by their number as a string and a record leaves out the fields still at
their default, so files written before these classes existed read back unchanged.

Resume and crash windows (``progress.json``, written atomically after every phase):
the round's episodes are kept in memory until all are collected, then appended by a single
writer flush whose commit point is the atomic rename of ``meta/info.json``. Before the
append, ``progress.json`` records the dataset's episode count. On resume a round that is
not marked appended is checked against the dataset: the same count means the kill came
before the commit (the rollout is redone, same seeds); the count plus this round's
episodes, with matching provenance at the tail, means the kill came between the commit
and the progress update (the round is marked appended); anything else is an error.
Killed during retraining, the round resumes from its last training checkpoint
(``output_dir/train/round_<r>/``); killed during evaluation, only the evaluation reruns.
``--max_minutes`` stops the same way, but only at those safe points: after a training step
(with a checkpoint), after the append, after the retraining and after each round.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import draccus

from msta.data.hub_eval import HEADLINE_FIGURES
from msta.data.layout import LOCK_NAME
from msta.data.locate import locate_checkpoint, locate_dataset
from msta.data.msta_json import check_robot, dataset_robot
from msta.data.windows import load_episode_table
from msta.eval.metrics import headline
from msta.eval.report import CI_NOTE, identical_groups, identical_line
from msta.eval.report_cells import SHORT_TERRAIN, fmt_cell
from msta.policies.config import check_trained_on
from msta.policies.factory import load_config
from msta.policies.teacher.config import teacher_revision
from msta.train.correct_config import PROGRESS, RESUME_LEGACY, CorrectConfig
from msta.train.state import atomic_json

PROGRESS_FORMAT = "msta-correct/1"


def _known(cls: type, data: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """(the keys that are fields of ``cls``, the rest) of a JSON object."""
    names = {f.name for f in fields(cls)} - {"extra", "path"}
    return ({k: v for k, v in data.items() if k in names},
            {k: v for k, v in data.items() if k not in names})


@dataclass
class RoundRecord:
    """One round of progress.json: which phases are done and what they measured.

    Phase 1-3 (roll out, label, append) set ``episodes_before`` (the dataset's count before
    the append), ``policy_revision`` (the student that drove), ``episodes_rolled_out``,
    ``appended``, ``episodes_after`` and ``rollout`` (speeds, beta, frames);
    ``recovered_after_commit`` marks an append found committed on resume. Phase 4 sets
    ``train`` (windows, speed, losses, the mask ratio it trained at), ``trained``,
    ``checkpoint`` and ``trained_revision``; phase 5 ``eval`` (msta-eval's run records per
    test mask), ``eval_config`` and ``evaluated``; a push ``pushed``. Round 0 is the
    starting checkpoint's evaluation. Keys this version does not know are kept in ``extra``
    and written back.
    """

    episodes_before: int | None = None
    policy_revision: str | None = None
    episodes_rolled_out: int | None = None
    appended: bool = False
    recovered_after_commit: bool = False
    episodes_after: int | None = None
    rollout: dict[str, float] | None = None
    train: dict[str, float] | None = None
    trained: bool = False
    checkpoint: str | None = None
    trained_revision: str | None = None
    eval: dict[str, Any] | None = None
    eval_config: dict[str, Any] | None = None
    evaluated: bool = False
    pushed: dict[str, str] | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> RoundRecord:
        known, extra = _known(cls, data)
        return cls(**known, extra=extra)

    def to_json(self) -> dict[str, Any]:
        """The record as progress.json holds it: fields at their default left out."""
        out = {f.name: getattr(self, f.name) for f in fields(self)
               if f.name != "extra" and getattr(self, f.name) != f.default}
        return {**out, **self.extra}


@dataclass
class CorrectProgress:
    """progress.json of one msta-correct (or msta-finetune) run.

    Args:
        config: the run's configuration, draccus-encoded (compared on resume).
        dataset: the dataset root the rounds append to.
        rounds: the rounds by number (0: the starting checkpoint's evaluation).
        format: the file's format tag.
        rollout_max_init_level: the rollouts' starting terrain level cap, decided once
            (``--levels_from_dataset``).
        teacher_revision: the labelling teacher's revision.
        teacher_eval: the reference teacher's figures on the evaluation trials.
        dataset_source: where the dataset came from (hub repo and revision), for model cards.
        extra: top-level keys this version does not know, written back as read.
        path: where the file lives (not written into it).
    """

    config: dict[str, Any]
    dataset: str
    rounds: dict[int, RoundRecord] = field(default_factory=dict)
    format: str = PROGRESS_FORMAT
    rollout_max_init_level: int | None = None
    teacher_revision: str | None = None
    teacher_eval: dict[str, Any] | None = None
    dataset_source: dict[str, Any] | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    path: Path | None = field(default=None, compare=False)

    def round(self, r: int) -> RoundRecord:
        """Round ``r``'s record, created empty when missing."""
        return self.rounds.setdefault(r, RoundRecord())

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"format": self.format, "config": self.config,
                               "dataset": self.dataset,
                               "rounds": {str(r): self.rounds[r].to_json()
                                          for r in sorted(self.rounds)}}
        for name in ("rollout_max_init_level", "teacher_revision", "dataset_source",
                     "teacher_eval"):
            if getattr(self, name) is not None:
                out[name] = getattr(self, name)
        return {**out, **self.extra}

    @classmethod
    def from_json(cls, data: dict[str, Any], path: Path | None = None) -> CorrectProgress:
        known, extra = _known(cls, data)
        rounds = {int(k): RoundRecord.from_json(v) for k, v in known.pop("rounds").items()}
        return cls(**known, rounds=rounds, extra=extra, path=path)

    def save(self) -> None:
        """Write the file atomically (:func:`msta.train.state.atomic_json`)."""
        if self.path is None:
            raise ValueError("this CorrectProgress has no path to be saved to")
        atomic_json(self.path, self.to_json())


def load_progress(out: Path, cfg: CorrectConfig, root: Path) -> CorrectProgress:
    """``output_dir/progress.json``: a new one (written at once) for a new run, the saved
    one for ``--resume`` after checking that the fields that define the data agree."""
    path = out / PROGRESS
    encoded = draccus.encode(cfg)
    if not path.exists():  # a new run (check_output has refused a resume without it)
        out.mkdir(parents=True, exist_ok=True)
        prog = CorrectProgress(config=encoded, dataset=str(root), path=path)
        prog.save()
        return prog
    if not cfg.resume:
        raise FileExistsError(f"{path} exists; pass --resume=true to continue that run or "
                              "choose another --output_dir")
    prog = CorrectProgress.from_json(json.loads(path.read_text()), path)
    saved = dict(prog.config)
    if isinstance(saved.get("policy"), str):  # before --policy.path
        saved["policy"] = {"path": saved["policy"]}
    if "T" in (saved.get("rollout") or {}):  # before --rollout.T was named --rollout.history
        saved["rollout"] = {("history" if k == "T" else k): v for k, v in saved["rollout"].items()}
    if isinstance(saved.get("env"), dict) and "robot" not in saved["env"]:
        # before --env.robot: the A1, its control numbers written out; compare those in force
        saved["env"] = {**saved["env"], "robot": "a1"}
        encoded = {**encoded, "env": draccus.encode(cfg.env.resolved())}
    bad = [k for k in cfg.RESUME_FIELDS if saved.get(k, RESUME_LEGACY.get(k)) != encoded.get(k)]
    if bad:
        raise ValueError(f"--resume=true with different {bad} than {path}")
    return prog


def check_output(cfg: CorrectConfig, out: Path) -> None:
    """Before output_dir is created or locked: a new run needs it empty, a resume needs
    its progress.json."""
    if cfg.resume and not (out / PROGRESS).exists():
        raise FileNotFoundError(f"--resume=true but {out / PROGRESS} does not exist (nothing "
                                "to resume; drop --resume to start)")
    if not cfg.resume and out.exists() and any(p.name != LOCK_NAME for p in out.iterdir()):
        raise FileExistsError(f"{out} is not empty; pass --resume=true to continue that run or "
                              "choose another --output_dir")


def resolve_inputs(cfg: CorrectConfig, out: Path) -> tuple[Path, Path]:
    """(checkpoint directory, dataset root), both checked before output_dir is touched; a
    hub dataset is appended to through a copy in output_dir (:func:`own_dataset`). The
    dataset's robot, the checkpoint's and ``--env.robot``'s must agree (one line naming both
    robots and the option otherwise); a checkpoint of several robots is refused in one line."""
    ckpt = locate_checkpoint(cfg.policy.path, "--policy.path")  # msta's one path-or-hub-id rule
    config = load_config(ckpt)  # fails early, naming the directory, before output_dir is touched
    local = out / "dataset"
    # a hub dataset copied by an earlier run, else the one --dataset names
    root = local if local.is_dir() else locate_dataset(cfg.dataset, "--dataset")
    robot = cfg.env.robot_description.name
    check_robot(dataset_robot(root), robot, f"--dataset={cfg.dataset}", "--env.robot")
    check_trained_on(config.robots, robot, f"--policy.path={cfg.policy.path}", "--env.robot")
    if len(config.robots) > 1:  # its rounds would retrain it on one robot's episodes alone
        raise ValueError(f"--policy.path={cfg.policy.path} was trained on robots "
                         f"{', '.join(config.robots)}; msta-correct retrains on {robot}'s "
                         "episodes alone, so its rounds would not be a student of them all: "
                         "correct each robot's own student, then train one of them all "
                         "with msta-train --more_datasets")
    return ckpt, root


def own_dataset(cfg: CorrectConfig, out: Path, root: Path) -> Path:
    """The local dataset root to append to: a dataset pulled from the hub is copied into
    ``output_dir/dataset`` first (called with output_dir locked)."""
    local = out / "dataset"
    if root == local or Path(cfg.dataset).expanduser().is_dir():
        return root
    shutil.copytree(root, local)
    return local


def rollout_levels(cfg: CorrectConfig, root: Path, prog: CorrectProgress) -> CorrectConfig:
    """``cfg`` with the rollouts' ``max_init_level`` capped at the highest terrain level of the
    dataset's teacher episodes (``--levels_from_dataset``); the cap is decided once and kept
    in progress.json, so a resumed run rolls out where the first one did."""
    if not cfg.levels_from_dataset:
        return cfg
    if prog.rollout_max_init_level is None:
        table = load_episode_table(root)
        teacher = table[table["provenance/source"] != "student"]["provenance/terrain_level"]
        level = cfg.env.terrain.max_init_level
        if len(teacher) and int(teacher.max()) >= 0:
            level = min(level, int(teacher.max()))
        prog.rollout_max_init_level = level
        prog.save()
        if level < cfg.env.terrain.max_init_level:
            print(f"stage-2 rollouts start at terrain levels 0-{level}, the levels of the "
                  f"dataset's teacher episodes (--levels_from_dataset=false: 0-"
                  f"{cfg.env.terrain.max_init_level})")
    terrain = replace(cfg.env.terrain, max_init_level=int(prog.rollout_max_init_level))
    return replace(cfg, env=replace(cfg.env, terrain=terrain))


def check_labeller(cfg: CorrectConfig, root: Path) -> str | None:
    """A warning when the labelling teacher (``--teacher``) is not the teacher that recorded
    the dataset's teacher episodes (their ``provenance/policy_revision``): stage 2 would then
    correct the student towards another policy than the one it imitated. None when they
    agree or the dataset records no teacher revision."""
    table = load_episode_table(root)
    if "provenance/policy_revision" not in table:
        return None
    recorded = sorted({str(v) for v in table[table["provenance/source"] == "teacher"][
        "provenance/policy_revision"] if v})
    labeller = teacher_revision(cfg.teacher, cfg.env.teacher_robot)
    if not recorded or labeller in recorded:
        return None
    return (f"msta-correct: warning: the labels come from {labeller} (--teacher.type="
            f"{cfg.teacher.type}), but the dataset's teacher episodes were recorded by "
            f"{', '.join(recorded)}: the student will be corrected towards another policy than "
            "the one it imitated (give the recording teacher with --teacher.type/--teacher.path)")


def print_table(prog: CorrectProgress) -> None:
    """Per-round table: speeds, then per test mask the trials and msta-eval's figures
    (terrain average with 95 % intervals, and per terrain): linear-velocity tracking and
    total reward normalized by the teacher on the same trials, and survival
    (:func:`msta.eval.metrics.headline`, the model card's figures too)."""
    lines = ["| round | episodes | env steps/s | train samples/s | val loss | test mask | trials "
             "| lin. tracking vs teacher | survival | total vs teacher | per terrain: lin. "
             "tracking vs teacher / survival |", "|" + "---|" * 11]
    warnings = []
    for k in sorted(prog.rounds):
        rec = prog.rounds[k]
        ro, tr = rec.rollout or {}, rec.train or {}
        after = "-" if rec.episodes_after is None else rec.episodes_after
        head = (f"| {k} | {after} | "
                f"{_fmt(ro.get('env_steps_per_s'), '.0f')} | "
                f"{_fmt(tr.get('train_samples_per_s'), '.0f')} | "
                f"{_fmt(tr.get('val_loss'), '.4f')}")
        runs = rec.eval or {}
        for m, run in runs.items():
            if run.get("status") != "ok":
                reason = run.get("reason", "evaluated by an older msta-correct")
                lines.append(f"{head} | {float(m):.0%} | n/a: {reason} | | | | |")
                continue
            cells = headline(run)
            avg = [fmt_cell(cells["average"], name) for name, _, _ in HEADLINE_FIGURES]
            terr = " ".join(
                f"{SHORT_TERRAIN.get(t, t)} {_fmt(row['lin_tracking_vs_teacher'], '.2f')}"
                f"/{row['survival']:.2f}" for t, row in cells.items() if t != "average")
            lines.append(f"{head} | {float(m):.0%} | {cells['average']['trials']} | "
                         + " | ".join(avg) + f" | {terr} |")
        warnings += [identical_line(f"round {k}", "test masks", labels)
                     for labels in identical_groups(list(runs.values()))]
        if not runs:
            lines.append(f"{head} | - | - | - | - | - | - |")
    ref = prog.teacher_eval
    if ref:
        c, a = ref["config"], ref["per_terrain"]["average"]
        print(f"evaluation (msta-eval's trials): {c['trials']} trials of {c['episode_length_s']:g} s "
              f"over {', '.join(c['terrains'])} at levels {c['levels']}, seed {c['seed']}; "
              f"teacher on them: lin. tracking {a['lin_tracking']:.3f}/step, survival "
              f"{a['survival']:.2f}, total {a['total']:.3f}/step")
    print("\n".join(lines), flush=True)
    if ref:
        print(CI_NOTE)
    for w in warnings:
        print(f"msta-correct: warning: {w}", flush=True)


def _fmt(value: float | None, spec: str) -> str:
    return "-" if value is None else format(value, spec)
