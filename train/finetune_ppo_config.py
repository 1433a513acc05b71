"""msta-finetune-ppo's settings (:class:`FinetunePPOConfig`, its PPO budget
:class:`StudentPPOConfig`), read by its command line (:mod:`msta.train.finetune_ppo`) and its
run (:mod:`msta.train.finetune_ppo_run`); no torch."""

from __future__ import annotations

from dataclasses import dataclass, field

from msta.collect.sim.env_config import EnvConfig
from msta.data import sensors as registry
from msta.data.checks import check_at_least
from msta.data.threads import check_threads
from msta.policies.checkpoint import PolicyPath
from msta.policies.input_spec import MINIMIZED_HISTORY, MINIMIZED_SENSORS
from msta.train.finetune_config import sensor_names, trainable_modules
from msta.train.ppo_config import PPOConfig

#: The command's name in its messages.
PROG = "msta-finetune-ppo"


@dataclass
class StudentPPOConfig(PPOConfig):
    """rsl_rl PPO settings for fine-tuning a student (msta-train-teacher's, with a smaller
    default budget: this runs the transformer every step of every robot).

    Args:
        iterations: PPO iterations in all; a resumed run stops at this total.
        num_steps_per_env: rollout steps per robot per iteration.
        learning_rate: Adam learning rate at the start (then adapted to desired_kl).
        init_std: initial action noise std (radians of desired joint position).
        critic_warmup: first iterations that train only the critic (the actor frozen).
        num_learning_epochs: passes over each rollout.
        num_mini_batches: mini-batches per pass.
        save_interval: iterations per chunk (a checkpoint, a curve row, a student each).
    """

    iterations: int = 40
    num_steps_per_env: int = 24
    learning_rate: float = 1e-4
    init_std: float = 0.1
    critic_warmup: int = 10
    num_learning_epochs: int = 4
    num_mini_batches: int = 4
    save_interval: int = 5


def _default_env() -> EnvConfig:
    cfg = EnvConfig(num_envs=64, episode_length_s=20.0, nthread=0)
    cfg.terrain.max_init_level = 2  # the levels the demo's students are trained on
    return cfg


@dataclass
class FinetunePPOConfig:
    """Args:
        policy: the starting MSTA student: ``--policy.path=<checkpoint directory or hub id>``
            (e.g. a msta-correct round).
        sensors: the fine-tuned student's inputs, as msta-finetune's: a comma list of
            registry names, ``minimized`` (command, joint_pos, gravity, last_action) or
            ``all``. A sensor the checkpoint lacks is added with fresh weights and needs
            ``--dataset`` for its statistics.
        history: the fine-tuned student's window T (the paper's deployment: 7).
        trainable: parameter groups trained (msta-finetune's: ``embeddings``, ``readout``,
            ``head``, joined by ``+``); the transformer blocks are never trained.
        dataset: a local dataset root whose statistics normalize added sensors (only read
            when ``sensors`` names one the checkpoint lacks).
        dummy_tokens: random dummy tokens appended to the student's tokens in every step of
            the fine-tune (the paper's stress test: 256), fresh each step and never trained;
            the fine-tuned student is then evaluated with them by msta-eval's
            ``dummy_tokens`` scenario. 0: none.
        output_dir: start/, student/, ppo/ (rsl_rl checkpoints, TensorBoard), curve.json
            and finetune_ppo.json; re-running resumes.
        seed: seeds torch and the simulator (env.seed follows it).
        device: torch device: auto (CUDA when present), cpu, cuda.
        num_threads: torch threads (0: the cores other work leaves free, msta.data.threads).
        ppo: rsl_rl PPO settings.
        env: the simulator (robots, terrains and curriculum, rewards, randomization); the
            default starts robots at levels 0-2 with the curriculum on.
    """

    policy: PolicyPath = field(default_factory=PolicyPath)
    sensors: str = ",".join(MINIMIZED_SENSORS)
    history: int = MINIMIZED_HISTORY
    trainable: str = "embeddings"
    dataset: str = ""
    dummy_tokens: int = 0
    output_dir: str = "outputs/finetune_ppo/msta"
    seed: int = 0
    device: str = "auto"
    num_threads: int = 0
    ppo: StudentPPOConfig = field(default_factory=StudentPPOConfig)
    env: EnvConfig = field(default_factory=_default_env)

    def __post_init__(self) -> None:
        check_threads(self.num_threads)
        check_at_least(self, 1, "history")
        check_at_least(self, 0, "num_threads", "dummy_tokens")
        sensor_names(self.sensors, registry.STUDENT_SENSORS)
        trainable_modules(self.trainable)
        if not self.policy.path:
            raise ValueError("policy.path is required: the MSTA student to fine-tune")
        self.env.seed = self.seed
