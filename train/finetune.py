"""``msta-finetune``: an MSTA student on a minimized observation, only its token
embeddings trained (the paper's deployment: {command, q, g, a_{t-1}} at T = 7 after
fine-tuning the token projections of the frozen transformer).

    msta-finetune --policy.path=outputs/correct/msta_cpu/round_4 \\
        --dataset=outputs/datasets/a1_teacher --output_dir=outputs/finetune/msta_cpu \\
        --rounds=2 --episodes_per_round=64 --steps=500 --teacher.type=gait
    msta-finetune ... --sensors=joint_pos,gravity,command --history=10 --trainable=embeddings+head
    msta-finetune ... --sensors=command,joint_pos,gravity,last_action,height_map

This is msta-correct (:mod:`msta.train.online`, the same rounds, options, resume and per-round
table) on a prepared student:

1. the starting checkpoint is restricted to ``--sensors`` and window ``--history``
   (:meth:`~msta.policies.msta.modeling_msta.MSTAPolicy.with_inputs`: the kept sensors' value
   tables and sensor embeddings are copied, the others dropped; config.json and
   processor.json then name only the kept inputs). A named sensor the checkpoint lacks
   (e.g. the ``height_map`` extension in the third example) is added with fresh weights
   and the dataset's statistics: the paper's new sensor tokens. It is saved as
   ``output_dir/start/``,
   which round 0 evaluates: the minimized observation before any fine-tuning;
2. every parameter outside ``--trainable`` is frozen (``requires_grad`` False; the optimizer,
   :func:`msta.train.optim.parameter_groups`, receives only the trainable ones). The transformer
   blocks are always frozen;
3. each round the student drives on the minimized inputs, the teacher labels every step
   (the dataset records every column, as msta-correct does), the round retrains on
   windows of the kept sensors and T, and ``round_<r>/`` is saved and evaluated.

Every checkpoint here (``start/``, ``round_<r>/``) is a plain MSTA checkpoint whose
config.json names the kept inputs (``input_sensors``) and T (``history``), so
``load_policy``, msta-eval and msta-export (``--sensors=all``) run it on exactly that
observation; ``finetune.json`` beside it records the source checkpoint, the trained groups
and the trained parameters. progress.json holds the whole configuration.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

from msta.data import layout
from msta.data import sensors as registry
from msta.data.checks import check_at_least
from msta.data.features import load_info
from msta.data.locate import locate_checkpoint
from msta.data.stats import load_stats
from msta.policies.base import StudentPolicy
from msta.policies.export import MINIMIZED_HISTORY, MINIMIZED_SENSORS
from msta.policies.factory import load_config
from msta.policies.msta import MSTAPolicy
from msta.train import online
from msta.train.correct_config import RESUME_FIELDS, CorrectConfig
from msta.train.correct_progress import CorrectProgress
from msta.train.stage2 import PhaseHook, correct
from msta.train.state import atomic_json

RECORD = "finetune.json"
RECORD_FORMAT = "msta-finetune/1"
#: ``--trainable`` group -> the MSTATransformer parameters / submodules it trains. The
#: transformer blocks belong to no group: they stay frozen (msta-correct trains them).
TRAINABLE_GROUPS: dict[str, tuple[str, ...]] = {
    "embeddings": ("bin_embed", "encoders", "sensor_embed", "mask_token"),
    "readout": ("state_token", "extra_state_tokens"),
    "head": ("ln_f", "head"),
}


@dataclass
class FinetuneConfig(CorrectConfig):
    """Args:
        sensors: the fine-tuned student's inputs: a comma list of registry sensor names
            (the checkpoint's keep its order; one it lacks, e.g. the ``height_map``
            extension, is added after them with fresh weights and the dataset's statistics,
            and the dataset must record it: ``msta-collect --extra_sensors=height_map``),
            ``minimized`` (the paper's command, joint_pos, gravity, last_action, as
            msta-export's --sensors) or ``all`` (every input of the checkpoint).
        history: the fine-tuned student's window T (the paper's deployment: 7). Rollouts,
            retraining, evaluation and export use it (its config.json ``history``).
        trainable: parameter groups trained, joined by ``+``; everything else is frozen.
            ``embeddings``: the token projections (the value tables ``bin_embed``, the
            encoders of MLP-encoded sensors ``encoders.*``, the sensor-type embeddings
            ``sensor_embed.*`` and, in the learnable-mask ablation, ``mask_token``);
            ``readout``: the readout tokens (``state_token``, ``extra_state_tokens``:
            queries of the transformer, not projections of the observation, so not in
            ``embeddings``); ``head``: ``ln_f`` and the action head.
            The transformer blocks are never trained.
        output_dir: the prepared start (``start/``), round checkpoints (each with
            finetune.json), training runs and progress.json.
    """

    sensors: str = ",".join(MINIMIZED_SENSORS)
    history: int = MINIMIZED_HISTORY
    trainable: str = "embeddings"
    output_dir: str = "outputs/finetune/msta"

    RESUME_FIELDS: ClassVar[tuple[str, ...]] = (*RESUME_FIELDS, "sensors", "history",
                                                "trainable")
    PROG: ClassVar[str] = "msta-finetune"

    def __post_init__(self) -> None:
        super().__post_init__()
        check_at_least(self, 1, "history")
        sensor_names(self.sensors, registry.STUDENT_SENSORS)  # one-line errors at parse time
        trainable_modules(self.trainable)


def sensor_names(spec: str, inputs: Sequence[str]) -> tuple[str, ...]:
    """``--sensors`` -> the student's inputs: the checkpoint's that are named, in its
    order (``inputs``), then the named ones it lacks (added with fresh weights, e.g. the
    ``height_map`` extension), in the given order.

    Args:
        spec: ``all``, ``minimized`` or a comma list of registry names.
        inputs: the checkpoint's input sensors.
    """
    if spec.strip() == "all":
        return tuple(inputs)
    names = MINIMIZED_SENSORS if spec.strip() == "minimized" else tuple(
        s.strip() for s in spec.split(",") if s.strip())
    if not names:
        raise ValueError("sensors is empty; give a comma list of sensor names, 'minimized' or "
                         "'all'")
    for name in names:
        if name not in registry.SENSORS:
            raise ValueError(f"unknown sensor {name!r} in sensors; student sensors: "
                             f"{', '.join(registry.STUDENT_SENSORS)}")
        if not registry.get(name).is_student_input:
            raise ValueError(f"sensor {name!r} is privileged (teacher only), not a student "
                             "input")
    if len(set(names)) != len(names):
        raise ValueError(f"sensors has duplicates: {spec}")
    return (*(n for n in inputs if n in names), *(n for n in names if n not in inputs))


def trainable_modules(spec: str) -> tuple[str, ...]:
    """``--trainable`` (``embeddings+head``) -> the MSTATransformer parameter / submodule
    names it trains."""
    groups = [g.strip() for g in spec.split("+") if g.strip()]
    if not groups:
        raise ValueError(f"trainable is empty; join groups from {', '.join(TRAINABLE_GROUPS)} "
                         "with '+' (e.g. embeddings+head)")
    if bad := [g for g in groups if g not in TRAINABLE_GROUPS]:
        raise ValueError(f"unknown trainable group {bad[0]!r}; groups: "
                         f"{', '.join(TRAINABLE_GROUPS)} (joined with '+')")
    return tuple(m for g in groups for m in TRAINABLE_GROUPS[g])


def module_of(name: str) -> str:
    """``model.sensor_embed.joint_pos`` -> ``sensor_embed`` (MSTAPolicy parameter names)."""
    return name.removeprefix("model.").split(".")[0]


def freeze(policy: StudentPolicy, modules: Sequence[str]) -> list[str]:
    """``requires_grad`` False on every parameter outside ``modules``; returns the names of
    the trainable ones (an error when there are none)."""
    names = []
    for name, p in policy.named_parameters():
        p.requires_grad_(module_of(name) in modules)
        if p.requires_grad:
            names.append(name)
    if not names:
        raise ValueError(f"trainable={modules} selects no parameter of this student")
    return names


def check_source(cfg: FinetuneConfig) -> tuple[Path, tuple[str, ...]]:
    """(starting checkpoint, the fine-tuned student's inputs): the one-line errors about the
    checkpoint come before output_dir is touched."""
    ckpt = locate_checkpoint(cfg.policy.path, "--policy.path")
    config = load_config(ckpt)
    if config.type != "msta":  # the baselines have no transformer to freeze
        raise ValueError(f"{ckpt} holds a {config.type!r} student; msta-finetune trains the "
                         "token embeddings of a frozen MSTA transformer, which the baselines "
                         "do not have (msta-correct retrains any student whole)")
    kept = sensor_names(cfg.sensors, config.input_sensors)
    if layout.is_dataset_root(Path(cfg.dataset)):  # a hub id is checked once it is pulled
        check_recorded(Path(cfg.dataset), [s for s in kept if s not in config.input_sensors])
    return ckpt, kept


def check_recorded(root: Path, added: Sequence[str]) -> None:
    """An added sensor must be a column of the dataset the rounds retrain on."""
    have = load_info(root)["features"]
    for name in added:
        if registry.get(name).column not in have:
            raise ValueError(f"the dataset {root} does not record {name!r}, which the student "
                             f"would read; record one that does (msta-collect "
                             f"--extra_sensors={name})")


class Preparation:
    """msta-correct's ``prepare`` hook: restrict the student's inputs, freeze it, and record
    what was done in every checkpoint of ``output_dir``.

    Args:
        cfg: the configuration.
        source: the starting checkpoint.
        sensors: the fine-tuned student's inputs (kept ones, then added ones).
    """

    def __init__(self, cfg: FinetuneConfig, source: Path, sensors: tuple[str, ...]) -> None:
        self.cfg, self.source, self.sensors = cfg, source, sensors
        self.added = [s for s in sensors if s not in load_config(source).input_sensors]
        self.record: dict[str, Any] | None = None

    def __call__(self, policy: StudentPolicy, root: Path) -> StudentPolicy:
        if not isinstance(policy, MSTAPolicy):
            raise TypeError(f"a {policy.config.type!r} student cannot be fine-tuned here "
                             "(MSTA only)")
        new = [s for s in self.sensors if s not in policy.config.input_sensors]  # none on resume
        check_recorded(root, new)
        student = policy.with_inputs(self.sensors, self.cfg.history,
                                     load_stats(root) if new else None)
        names = freeze(student, trainable_modules(self.cfg.trainable))
        params = dict(student.named_parameters())
        n = sum(params[k].numel() for k in names)
        total = sum(p.numel() for p in params.values())
        self.record = {"format": RECORD_FORMAT, "source": str(self.source),
                       "input_sensors": list(self.sensors), "added_sensors": self.added,
                       "history": self.cfg.history,
                       "trainable": self.cfg.trainable, "trained_parameters": names,
                       "trained_numel": n, "total_numel": total}
        print(f"msta-finetune: {self.source} on {', '.join(self.sensors)} at T = "
              f"{self.cfg.history}; training {self.cfg.trainable} ({n:,} of {total:,} "
              f"parameters: {', '.join(sorted({module_of(k) for k in names}))}), the "
              "transformer blocks frozen")
        return student

    def write(self, out: Path) -> None:
        """``finetune.json`` into every checkpoint in ``out`` (idempotent)."""
        if self.record is None:
            return
        for d in (out / "start", *sorted(out.glob("round_*"))):
            if (d / "model.safetensors").is_file():
                atomic_json(d / RECORD, self.record)


def finetune(cfg: FinetuneConfig, on_phase: PhaseHook | None = None) -> CorrectProgress:
    """Run (or resume) msta-finetune; returns its progress.json record.

    Args:
        cfg: the parsed configuration.
        on_phase: as :func:`msta.train.online.correct`'s (after finetune.json is written).
    """
    source, kept = check_source(cfg)
    prep, out = Preparation(cfg, source, kept), Path(cfg.output_dir)

    def hook(phase: str, r: int) -> None:
        prep.write(out)  # every phase: a checkpoint saved before a kill gets its record too
        if on_phase is not None:
            on_phase(phase, r)

    return correct(cfg, on_phase=hook, prepare=prep)  # "done": the last write, still locked


def parse_args(argv: Sequence[str] | None = None) -> FinetuneConfig:
    """msta-finetune's command line (msta-correct's, plus --sensors, --history, --trainable)."""
    return online.parse_args(argv, FinetuneConfig, "msta-finetune")


def main(argv: Sequence[str] | None = None) -> None:
    online.run_cli(argv, FinetuneConfig, finetune, "msta-finetune")


if __name__ == "__main__":
    main()
