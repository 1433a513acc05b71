"""``msta-train``: stage 1, offline behaviour cloning of the teacher's labels.

    msta-train --dataset=outputs/datasets/a1_teacher --policy.preset=cpu \\
        --output_dir=outputs/train/msta_cpu --steps=3000 --batch_size=64
    msta-train ... --resume=true          # continue exactly where a killed run stopped
    msta-train ... --max_minutes=8        # stop after 8 min with a checkpoint (exit 75)
    torchrun --standalone --nproc_per_node=2 --no-python msta-train ...  # docs/scale.md

Output directory::

    train_config.json                 the parsed configuration
    metrics.csv, tensorboard/         train and validation metrics
    checkpoints/<step>/pretrained_model/   config.json, model.safetensors, processor.json
    checkpoints/<step>/training_state/     optimizer, scheduler, RNG, sampler (no pickle)
    checkpoints/last -> <step>
    final/                            the final policy (``<PolicyClass>.from_pretrained``)

The run is :func:`msta.train.stage1.train`, its loop :func:`msta.train.loop.fit`; stage 2 (``train/online.py``) runs it
every round.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

from msta.data.budget import TimeLimitReached, stop
from msta.train.cli import USER_ERRORS, parse_cli
from msta.train.train_config import TrainConfig


def main(argv: Sequence[str] | None = None) -> None:
    args = list(sys.argv[1:] if argv is None else argv)
    cfg = parse_cli(TrainConfig, args, prog="msta-train")
    # inputs named on the command line must all be recorded; the default ones the dataset
    # lacks are left out (msta.train.stage1.dataset_inputs)
    given = any(a.partition("=")[0] == "--policy.input_sensors" for a in args)
    from msta.train.loop import rank0_runs  # lazy: torch after parsing (--help at once)
    from msta.train.stage1 import train  # lazy: torch after parsing (--help at once)

    try:  # under torchrun, rank 0 runs it and the others train with it (docs/scale.md)
        rank0_runs(lambda: train(cfg, inputs_given=given), cfg.batch_size)
    except USER_ERRORS as e:
        raise SystemExit(f"msta-train: error: {e}") from None
    except TimeLimitReached as e:
        stop("msta-train", e, "the same command with --resume=true")


if __name__ == "__main__":
    main()
