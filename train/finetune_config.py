"""msta-finetune's settings (:class:`FinetuneConfig`: msta-correct's plus the fine-tuned
student's sensors, window and trainable groups) and their checks, read by its command line
(:mod:`msta.train.finetune`) and its run (:mod:`msta.train.finetune_run`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import ClassVar

from msta.data import sensors as registry
from msta.data.checks import check_at_least
from msta.policies.input_spec import MINIMIZED_HISTORY, MINIMIZED_SENSORS
from msta.train.correct_config import RESUME_FIELDS, CorrectConfig

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
