"""``msta-train-teacher``: the paper's RMA teacher, trained by rsl_rl's PPO.

Two resumable stages under ``--output_dir``:

1. ``warmstart/``: imitation of the gait controller (DART by default) by the RMA MLP with
   privileged inputs (``msta.train.teacher.warmstart``), so PPO starts from a walking policy,
   not from noise.
2. ``ppo/``: rsl_rl's ``OnPolicyRunner`` with rsl_rl's PPO on ``RslVecEnv`` (the paper's
   legged_gym rewards and randomization, the terrain curriculum), in chunks of
   ``--ppo.save_interval`` iterations; each chunk ends with rsl_rl's checkpoint
   (``model_<it>.pt``, optimizer included), TensorBoard events, a row of ``curve.json``
   (environment steps, falls per 1000 robot steps and the survival of a full episode at
   that rate, level, tracking) and the exported teacher.

The result, ``teacher/`` (config.json + model.safetensors), is an ``rma`` teacher:
``--teacher.type=rma --teacher.path=<output_dir>/teacher`` works wherever a teacher does.
Re-running the same command after an interruption continues where it stopped.
"""

from __future__ import annotations

from collections.abc import Sequence

from msta.data.cli import parse_config
from msta.data.errors import DirectoryLockedError
from msta.train.teacher.config import PROG, TrainTeacherConfig


def main(argv: Sequence[str] | None = None) -> None:
    cfg = parse_config(TrainTeacherConfig, argv, prog=PROG, aliases={"env.seed": "seed"})
    from msta.train.teacher.run import train_teacher  # lazy: torch after parsing (--help)

    try:
        path = train_teacher(cfg)
    except (OSError, ValueError, DirectoryLockedError) as e:
        raise SystemExit(f"{PROG}: error: {e}") from None
    print(f"teacher: {path} (use --teacher.type=rma --teacher.path={path})")


if __name__ == "__main__":
    main()
