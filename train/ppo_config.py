"""rsl_rl PPO settings (:class:`PPOConfig`), shared by msta-train-teacher and
msta-finetune-ppo; the PPO loop around rsl_rl is :mod:`msta.train.ppo`."""

from __future__ import annotations

from dataclasses import dataclass

from msta.data.checks import check_at_least, check_number

#: The longest rollout per robot and PPO iteration (200 s at 50 Hz; rsl_rl recipes use 24-48
#: steps): rsl_rl allocates the whole rollout of every robot before the first step.
MAX_STEPS_PER_ENV = 10_000


@dataclass
class PPOConfig:
    """rsl_rl PPO settings (legged_gym's defaults unless noted).

    Args:
        iterations: PPO iterations in all (each: num_steps_per_env steps of every robot,
            then the update); a resumed run stops at this total.
        num_steps_per_env: rollout steps per robot per iteration.
        learning_rate: Adam learning rate at the start (then adapted to desired_kl).
            legged_gym's 1e-3 suits a policy starting from noise; on the warm-started one
            the first update moved the mean far past the KL target (the schedule cut the
            rate to 1e-5 at once) and the share of episodes ending in a fall rose from 0.39
            to 0.81 within 10 iterations.
        desired_kl: target KL of the adaptive learning-rate schedule.
        entropy_coef: entropy bonus.
        init_std: initial action noise std (action units); small after a warm start, so
            exploration does not undo the walking policy.
        critic_warmup: first iterations that train only the critic (the actor frozen), so
            a random value function does not drive the first policy updates.
        num_learning_epochs: passes over each rollout.
        num_mini_batches: mini-batches per pass.
        clip_param: PPO ratio clip.
        gamma: discount.
        lam: GAE lambda.
        save_interval: iterations per chunk (a checkpoint, a curve row, an export each).
        snapshot_interval: every this many iterations the exported policy is also kept as
            ``snapshots/iter_<n>/`` (a checkpoint like the run's product), so the run's
            progress can be evaluated afterwards and its best checkpoint chosen; 0 keeps
            none. Taken at the end of the chunk that reaches or passes each multiple, and
            named by that chunk's last iteration.
    """

    iterations: int = 300
    num_steps_per_env: int = 48
    learning_rate: float = 1e-4
    desired_kl: float = 0.01
    entropy_coef: float = 0.01
    init_std: float = 0.2
    critic_warmup: int = 10
    num_learning_epochs: int = 5
    num_mini_batches: int = 4
    clip_param: float = 0.2
    gamma: float = 0.99
    lam: float = 0.95
    save_interval: int = 10
    snapshot_interval: int = 100

    def __post_init__(self) -> None:
        check_at_least(self, 0, "iterations", "critic_warmup", "snapshot_interval")
        check_at_least(self, 1, "num_learning_epochs", "num_mini_batches", "save_interval")
        check_at_least(self, 1, "num_steps_per_env", maximum=MAX_STEPS_PER_ENV,
                       why="rsl_rl stores each iteration's whole rollout")
        for name in ("learning_rate", "desired_kl", "init_std", "clip_param"):
            check_number(f"ppo.{name}", getattr(self, name), 0, above=True)
        check_number("ppo.entropy_coef", self.entropy_coef, 0)
        check_number("ppo.gamma", self.gamma, 0, 1)
        check_number("ppo.lam", self.lam, 0, 1)

    def runner_cfg(self, actor: dict, obs_groups: dict[str, list[str]]) -> dict:
        """rsl_rl ``OnPolicyRunner`` train_cfg: these PPO settings, legged_gym's critic and
        the caller's ``actor`` (rsl_rl's actor config: the RMA teacher's, msta-train-teacher;
        the student's, msta-finetune-ppo) reading ``obs_groups``."""
        return {
            "num_steps_per_env": self.num_steps_per_env, "save_interval": self.save_interval,
            "obs_groups": obs_groups,
            "actor": actor,
            "critic": {"class_name": "MLPModel", "hidden_dims": [512, 256, 128],
                       "activation": "elu", "obs_normalization": True},
            "algorithm": {"class_name": "PPO", "learning_rate": self.learning_rate,
                          "desired_kl": self.desired_kl, "entropy_coef": self.entropy_coef,
                          "num_learning_epochs": self.num_learning_epochs,
                          "num_mini_batches": self.num_mini_batches,
                          "clip_param": self.clip_param, "gamma": self.gamma, "lam": self.lam,
                          "schedule": "adaptive", "max_grad_norm": 1.0,
                          "value_loss_coef": 1.0, "use_clipped_value_loss": True},
        }
