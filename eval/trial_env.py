"""What a process needs to play rounds of evaluation trials, in msta-eval's process or on a Ray
worker (:mod:`msta.eval.trials_pool`): the evaluation simulator (:func:`make_env`) and torch
set up for evaluation (:func:`torch_eval_settings`).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import torch

from msta.collect.sim.commands import CommandConfig
from msta.collect.sim.env import QuadrupedEnv
from msta.collect.sim.env_config import EnvConfig, NoiseConfig, load_sim_robot
from msta.collect.sim.randomization import RandomizationConfig
from msta.collect.sim.terrain import TerrainConfig
from msta.data.robot import LEGACY_ROBOT, RobotDescription
from msta.eval.scenarios import TrialConfig


def make_env(cfg: TrialConfig, num_envs: int) -> QuadrupedEnv:
    """The evaluation simulator of ``cfg.robot`` (the A1 when empty): tiles pinned (curriculum
    off), only the evaluated terrain columns built; :func:`msta.eval.metrics.start_trials`
    gives every trial its random stream."""
    return QuadrupedEnv(EnvConfig(
        robot=cfg.robot or LEGACY_ROBOT, num_envs=num_envs, seed=cfg.seed,
        episode_length_s=cfg.episode, nthread=cfg.nthread,
        terrain=TerrainConfig(types=tuple(cfg.terrain_list), curriculum=False),
        commands=CommandConfig(use_heading=cfg.heading_commands),
        noise=NoiseConfig(enabled=cfg.noise),
        randomization=RandomizationConfig(enabled=cfg.randomization)))


def trial_robot(cfg: TrialConfig) -> RobotDescription:
    """The description of the robot :func:`make_env` simulates (``cfg.robot``, the A1 when
    empty): what the evaluation's teachers are built for (its control numbers are the
    robot's own).

    Args:
        cfg: the trials' settings.
    """
    return load_sim_robot(cfg.robot or LEGACY_ROBOT, "robot")


@contextmanager
def torch_eval_settings(threads: int, cuda: bool = False) -> Iterator[None]:
    """torch as an evaluation needs it (``threads`` threads, deterministic algorithms), and
    afterwards as it was, global RNG state included (evaluation seeds it per run).

    ``cuda``: students run on CUDA. TF32 is off (full fp32 matrix products and convolutions)
    and deterministic algorithms only warn where an op has none: cuBLAS is deterministic
    only with ``CUBLAS_WORKSPACE_CONFIG`` set before its first use (msta-eval sets it at
    start; a process that trained on the GPU first, msta-correct or msta-repro, has passed
    that point)."""
    tf32 = (torch.backends.cuda.matmul.allow_tf32, torch.backends.cudnn.allow_tf32)
    before = (torch.get_num_threads(), torch.are_deterministic_algorithms_enabled(),
              torch.is_deterministic_algorithms_warn_only_enabled(), torch.get_rng_state())
    torch.set_num_threads(threads)
    torch.use_deterministic_algorithms(True, warn_only=cuda)
    if cuda:
        torch.backends.cuda.matmul.allow_tf32 = torch.backends.cudnn.allow_tf32 = False
    try:
        yield
    finally:
        torch.set_num_threads(before[0])
        torch.use_deterministic_algorithms(before[1], warn_only=before[2])
        torch.set_rng_state(before[3])
        torch.backends.cuda.matmul.allow_tf32, torch.backends.cudnn.allow_tf32 = tf32
