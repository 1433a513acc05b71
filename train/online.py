"""``msta-correct``: stage 2, online correction (TERT / DAgger style).

    msta-correct --policy.path=outputs/train/msta_cpu/final --dataset=outputs/datasets/a1_teacher \\
        --output_dir=outputs/correct/msta_cpu --rounds=3 --episodes_per_round=64 \\
        --teacher.type=gait --steps=500
    msta-correct ... --resume=true        # after a kill: continue at the unfinished round
    msta-correct ... --max_minutes=8      # stop at the next safe point after 8 min (exit 75)

Each round r = 1..R:

1. **roll out** the current student in the batched simulator (one batched forward pass for
   all environments per step; test-time input changes from ``--rollout.*``). With DAgger
   ``beta`` > 0 each environment executes the teacher's action instead with probability
   ``beta * beta_decay**(r-1)`` per step;
2. **label**: the teacher acts on the same observation (privileged inputs included) every
   step; its action is the ``action`` column, the executed one ``executed_action``;
3. **append** the round's episodes in one writer session (provenance source=student,
   round=r, policy=<type>, policy_revision=hash of the weights that drove);
4. **retrain** from the current weights on all episodes (``--recent_weight`` < 1 favours
   recent rounds), with :func:`msta.train.loop.fit` (mask ratio: the paper's 0.5, capped at
   the one the student was trained with, unless ``--mask_ratio`` says otherwise);
5. **save** ``output_dir/round_<r>/`` and **evaluate** it with msta-eval's code
   (:mod:`msta.train.round_eval`: ``msta.eval.evaluator.Evaluator`` on the trials of ``--eval.*``, the
   ``token_removal`` conditions at ``--eval.mask_ratios``): linear-velocity tracking and
   total reward normalized by the teacher's on the same trials, and survival, with 95 %
   intervals; a table is printed per round. ``msta-eval --policies teacher,<round_r>
   --scenarios token_removal`` with the same suite / trials / terrains / levels /
   episode_length_s / seed on the same device type reports the same figures, and so does the
   model card (``--push_to``).

Resume and crash windows (``progress.json``, written after every phase): see
:mod:`msta.train.correct_progress`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from msta.data.budget import TimeLimitReached, stop
from msta.train.cli import USER_ERRORS, parse_cli
from msta.train.correct_config import PROGRESS, CorrectConfig

if TYPE_CHECKING:
    from msta.train.correct_progress import CorrectProgress


def parse_args(argv: Sequence[str] | None = None, cls: type[CorrectConfig] = CorrectConfig,
               prog: str = "msta-correct") -> CorrectConfig:
    """msta-correct's command line (and msta-finetune's, ``cls``): ``--env.num_envs`` /
    ``--env.episode_length_s`` are read as ``--num_envs`` / ``--episode_length_s`` (which set
    them every round)."""
    return parse_cli(cls, argv, prog=prog, aliases={
        "env.num_envs": "num_envs", "env.episode_length_s": "episode_length_s"})


def run_cli(argv: Sequence[str] | None, cls: type[CorrectConfig],
            run: Callable[[Any], CorrectProgress], prog: str) -> None:
    """Parse, ``run`` the rounds, one-line errors; prints where progress and the last
    checkpoint are (msta-correct, msta-finetune)."""
    cfg = parse_args(argv, cls, prog)
    from msta.train.loop import rank0_runs  # lazy: torch after parsing (--help at once)

    try:
        done = rank0_runs(lambda: run(cfg), cfg.batch_size)  # torchrun: docs/scale.md
    except USER_ERRORS as e:  # one line naming the file, no traceback
        raise SystemExit(f"{prog}: error: {e}") from None
    except TimeLimitReached as e:
        stop(prog, e, "the same command with --resume=true")
    print(f"progress: {Path(cfg.output_dir) / PROGRESS}; last checkpoint: "
          f"{done.round(cfg.rounds).checkpoint}")


def _correct(cfg: CorrectConfig) -> CorrectProgress:
    """:func:`msta.train.stage2.correct`, imported once the command line is parsed."""
    from msta.train.stage2 import correct  # lazy: torch after parsing (--help at once)

    return correct(cfg)


def main(argv: Sequence[str] | None = None) -> None:
    run_cli(argv, CorrectConfig, _correct, "msta-correct")


if __name__ == "__main__":
    main()
