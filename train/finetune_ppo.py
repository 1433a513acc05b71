"""``msta-finetune-ppo``: the minimized-observation fine-tune by PPO from the student's own
reward (the paper's Fig. 6 third arm), through rsl_rl's PPO.

    msta-finetune-ppo --policy.path=outputs/demo/stage2/round_5 \\
        --output_dir=outputs/finetune_ppo/msta --ppo.iterations=40
    msta-finetune-ppo ... --sensors=all --history=15 --trainable=embeddings+head

msta-finetune (:mod:`msta.train.finetune`) fine-tunes the same parameters by supervised online
correction with the teacher; this command uses no teacher and no dataset:

1. the starting checkpoint is restricted to ``--sensors`` and window ``--history`` exactly
   as msta-finetune does (:meth:`~msta.policies.msta.modeling_msta.MSTAPolicy.with_inputs`) and
   saved as ``output_dir/start/`` (direct deployment, before any fine-tuning);
2. rsl_rl's ``OnPolicyRunner`` runs PPO on :class:`StudentVecEnv`, msta's batched simulator
   with the legged_gym rewards, where the actor (:class:`MSTAActor`) is the student itself:
   its action is the mean of rsl_rl's Gaussian, every parameter outside ``--trainable`` is
   frozen (the transformer blocks always), and it reads the window of its own sensors
   (padding before the episode start as in the datasets). The critic is rsl_rl's MLP on
   the teacher's inputs (privileged and proprioceptive; asymmetric actor-critic: the
   critic is dropped after training). The first ``--ppo.critic_warmup`` iterations train
   only the critic, so a random value function does not steer the first updates;
3. every ``--ppo.save_interval`` iterations: rsl_rl's checkpoint (``ppo/model_<it>.pt``,
   optimizer included), a row of ``curve.json`` (env steps, falls per 1000 robot steps and
   the survival of a full episode at that rate, linear tracking per step, the policy's
   action noise) and the student ``output_dir/student/`` (config.json, model.safetensors,
   processor.json, and ``finetune.json`` naming the method, the source and the trained
   parameters). Re-running the same command resumes from the newest checkpoint.

``student/`` is a plain MSTA checkpoint on the kept inputs: msta-eval and msta-export run
it as they run msta-finetune's rounds (``msta-eval --policies teacher,<output_dir>/start,
<output_dir>/student --scenarios token_removal``).
"""

from __future__ import annotations

from collections.abc import Sequence

from msta.data.cli import parse_config
from msta.data.errors import DirectoryLockedError
from msta.train.finetune_ppo_config import PROG, FinetunePPOConfig


def main(argv: Sequence[str] | None = None) -> None:
    cfg = parse_config(FinetunePPOConfig, argv, prog=PROG, aliases={"env.seed": "seed"})
    from msta.train.finetune_ppo_run import finetune_ppo  # lazy: torch after parsing (--help)

    try:
        path = finetune_ppo(cfg)
    except (OSError, ValueError, DirectoryLockedError) as e:
        raise SystemExit(f"{PROG}: error: {e}") from None
    print(f"student: {path} (msta-eval --policies teacher,{path} --scenarios token_removal)")


if __name__ == "__main__":
    main()
