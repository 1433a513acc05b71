"""msta-train-teacher's settings: the warm start (:class:`WarmStartConfig`), rsl_rl's PPO
(:class:`msta.train.ppo_config.PPOConfig`) and the simulator, in :class:`TrainTeacherConfig`
(no torch: the command parses before it loads)."""

from __future__ import annotations

from dataclasses import dataclass, field

from msta.collect.sim.env_config import EnvConfig
from msta.data.checks import check_at_least, check_number
from msta.data.threads import check_threads
from msta.train.ppo_config import PPOConfig


@dataclass
class WarmStartConfig:
    """Args:
        iterations: imitation iterations (0 skips the warm start: PPO starts from noise).
        steps: control steps per iteration (every robot; 50 per simulated second).
        beta_decay: beta_k = max(beta_min, beta_decay ** k), the share of steps the gait
            controller drives in iteration k (k = 0: all of them).
        beta_min: floor of beta_k. The gait controller runs its own clock; a robot driven
            mostly by the network drifts out of phase with it and the labels contradict
            the robot's own gait, so the controller keeps driving part of the time.
        action_noise: std (action units) of Gaussian noise added to every executed action
            (DART): the robot visits states off the controller's own path while the labels
            stay the controller's clean actions.
        fit_steps: gradient steps per iteration (random mini-batches of the buffer). The
            MLP needs ~40 passes over 90k samples to explain 93 % of the controller's action
            variance on held-out robots (MSE 0.094 against a variance of 1.38).
        batch_size: samples per gradient step.
        lr: Adam learning rate.
        buffer_size: newest samples kept for fitting.
    """

    iterations: int = 10
    steps: int = 250
    beta_decay: float = 1.0
    beta_min: float = 0.0
    action_noise: float = 0.3
    fit_steps: int = 1000
    batch_size: int = 2048
    lr: float = 1e-3
    buffer_size: int = 600_000

    def __post_init__(self) -> None:
        check_at_least(self, 0, "iterations")
        check_at_least(self, 1, "steps", "fit_steps", "batch_size", "buffer_size")
        for name in ("beta_decay", "beta_min"):
            check_number(name, getattr(self, name), 0, 1)
        check_number("action_noise", self.action_noise, 0)
        check_number("lr", self.lr, 0, above=True)


#: The command's name in its messages.
PROG = "msta-train-teacher"


def _default_env() -> EnvConfig:
    return EnvConfig(num_envs=256, episode_length_s=20.0, nthread=0)


@dataclass
class TrainTeacherConfig:
    """Args:
        output_dir: where warmstart/, ppo/ (rsl_rl checkpoints, TensorBoard), curve.json and
            teacher/ (the exported rma checkpoint) go; re-running resumes.
        seed: seeds torch, the warm start and the simulator (env.seed follows it).
        device: torch device for PPO: auto (CUDA when present), cpu, cuda.
        num_threads: torch threads (0: the cores other work leaves free, msta.data.threads).
        init_from: an existing ``rma`` teacher checkpoint (a directory with config.json and
            model.safetensors, e.g. policies/teacher/checkpoints/rma_dart, the shipped warm
            start) that PPO starts from instead of running the warm start; empty: run the
            warm start (warmstart.iterations) as configured.
        warmstart: the warm start: imitation of the gait controller (DART by default).
        ppo: rsl_rl PPO settings.
        env: the simulator (robots, terrains and curriculum, rewards, randomization);
            env.nthread 0 uses every core for physics.
    """

    output_dir: str = "outputs/teacher"
    seed: int = 0
    device: str = "auto"
    num_threads: int = 0
    init_from: str = ""
    warmstart: WarmStartConfig = field(default_factory=WarmStartConfig)
    ppo: PPOConfig = field(default_factory=PPOConfig)
    env: EnvConfig = field(default_factory=_default_env)

    def __post_init__(self) -> None:
        check_threads(self.num_threads)
        check_at_least(self, 0, "num_threads")
        self.env.seed = self.seed
