"""msta-eval's trials on Ray workers (``--workers``): one round of trials per block.

A round of trials (``msta.eval.metrics.TrialLayout.rounds``) is already independent of every other:
a fresh actor, every trial on its own tile with its own random stream. A worker runs a round
exactly as :func:`msta.eval.metrics.run_trials` does in one process (same simulator, same torch
settings, :func:`msta.eval.trial_env.torch_eval_settings`), and this process puts the rounds
together in order, storing each finished round as the single-process run does, so the figures
are those of ``--workers=0`` for any worker count, and ``--resume`` reuses rounds across them.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields, replace

import numpy as np
import torch
from tqdm import tqdm

from msta.collect.ray_pool import RayPool, cached
from msta.collect.sim.env import QuadrupedEnv
from msta.eval.metrics import ActorFactory, TrialLayout, TrialResults, play_round
from msta.eval.scenarios import TrialConfig
from msta.eval.trial_env import make_env, torch_eval_settings


def trial_config(cfg: TrialConfig) -> TrialConfig:
    """The plain :class:`TrialConfig` part of ``cfg`` (msta-eval's or msta-correct's config
    holds policies and paths the workers do not need)."""
    return TrialConfig(**{f.name: getattr(cfg, f.name) for f in fields(TrialConfig)})


@dataclass
class TrialsJob:
    """A pool job (:class:`msta.collect.ray_pool.Job`): rounds of one run's trials.

    Args:
        cfg: the trials (:func:`msta.eval.trial_env.make_env` builds the simulator from it).
        make_actor: (round, num_envs) -> a fresh actor, as for ``run_trials``.
        layout: the trials and their tiles.
    """

    cfg: TrialConfig
    make_actor: ActorFactory
    layout: TrialLayout

    def setup(self) -> QuadrupedEnv:
        # one MuJoCo thread: a worker is one CPU (the thread count changes no figure); one
        # simulator per worker for every run on the same trials, as Evaluator keeps one
        cfg, n = replace(self.cfg, nthread=1), len(self.layout.rounds(self.cfg.envs)[0])
        return cached(repr((cfg, n)), lambda: make_env(cfg, n))

    def run(self, env: QuadrupedEnv, r: int) -> TrialResults:
        """The sums of round ``r``'s trials."""

        ids = self.layout.rounds(env.num_envs)[r]
        out = TrialResults.zeros(int(ids[-1]) + 1, env.max_steps)
        with torch_eval_settings(self.cfg.num_threads):
            torch.manual_seed(self.cfg.seed)
            play_round(env, self.make_actor, self.layout, r, ids, out, tqdm(disable=True))
        return out.take(ids)


def run_trials_on_workers(pool: RayPool, cfg: TrialConfig, make_actor: ActorFactory,
                          layout: TrialLayout, max_steps: int,
                          done: Sequence[TrialResults] = (),
                          on_round: Callable[[int, int, TrialResults], None] | None = None
                          ) -> TrialResults:
    """:func:`msta.eval.metrics.run_trials` with the rounds on ``pool``'s workers: the same
    arguments (``max_steps``: the simulator's episode length in control steps) and the same
    results; ``on_round`` is called here, in round order."""
    rounds = layout.rounds(cfg.envs)
    out = TrialResults.zeros(len(rounds) * len(rounds[0]), max_steps)
    for r, part in enumerate(done):
        out.put(rounds[r], part)
    todo = list(range(len(done), len(rounds)))

    def commit(i: int, part: TrialResults) -> None:
        out.put(rounds[todo[i]], part)
        if on_round is not None:
            on_round(todo[i], len(rounds), part)

    pool.map(TrialsJob(trial_config(cfg), make_actor, layout), todo, commit)
    return out.take(np.arange(layout.trials))
