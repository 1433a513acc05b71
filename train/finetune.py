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
from typing import TYPE_CHECKING

from msta.train import online
from msta.train.finetune_config import FinetuneConfig

if TYPE_CHECKING:
    from msta.train.correct_progress import CorrectProgress


def parse_args(argv: Sequence[str] | None = None) -> FinetuneConfig:
    """msta-finetune's command line (msta-correct's, plus --sensors, --history, --trainable)."""
    return online.parse_args(argv, FinetuneConfig, "msta-finetune")


def _finetune(cfg: FinetuneConfig) -> CorrectProgress:
    """:func:`msta.train.finetune_run.finetune`, imported once the command line is parsed."""
    from msta.train.finetune_run import finetune  # lazy: torch after parsing (--help at once)

    return finetune(cfg)


def main(argv: Sequence[str] | None = None) -> None:
    online.run_cli(argv, FinetuneConfig, _finetune, "msta-finetune")


if __name__ == "__main__":
    main()
