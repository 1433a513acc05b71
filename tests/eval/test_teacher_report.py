"""The teacher report: episodes per tile through the shared rollout loop and metrics."""

from __future__ import annotations

import numpy as np
import pytest

import policies.teacher.config  # noqa: F401  (registers "zero")
from collect.rollout import rollout, step_quantities
from collect.sim.env import EnvConfig, QuadrupedEnv
from collect.sim.terrain import TerrainConfig
from eval import teacher_report as tr


def tiny(**kw) -> tr.ReportConfig:
    base = {"teacher": "zero", "episodes": 3, "envs_per_tile": 2, "types": ("flat",),
            "levels": (0, 3), "episode_length_s": 0.3, "nthread": 1, "columns": 1}
    base.update(kw)
    return tr.ReportConfig(**base)


def test_every_tile_counts_its_episodes_and_figures():
    cfg = tiny()
    stats = tr.evaluate(cfg, progress=False)
    assert set(stats) == {("flat", 0), ("flat", 3)}
    for row in stats.values():
        assert row["episodes"] == 4        # 2 envs x ceil(3 / 2) episodes, none cut short
        assert row["survival"] == 1.0      # standing still for 0.3 s does not fall
        assert row["lin_err"] > 0 and row["ang_err"] >= 0
        assert 0 < row["lin_reward"] <= tr.env_scale("lin")
    md = tr.render_markdown(stats, cfg, "cmd", 1.0, None)
    assert "| 3 | 4 | 100.0% |" in md and tr.highest_level(stats, "flat", cfg.levels) == 3


def test_errors_are_the_per_step_means_of_the_shared_quantities():
    """One episode per environment: the tile's |v err| is the mean of step_quantities'
    vel_err over every step of its environments (the same figure msta-eval sums)."""
    cfg = tiny(episodes=1, envs_per_tile=1, levels=(2,))
    row = tr.evaluate(cfg, progress=False)[("flat", 2)]
    env = QuadrupedEnv(EnvConfig(num_envs=1, seed=cfg.seed, episode_length_s=cfg.episode_length_s,
                                 nthread=1, terrain=TerrainConfig(types=("flat",),
                                                                  columns_per_type=1,
                                                                  curriculum=False)))
    env.reset(type_idx=np.zeros(1, dtype=np.int64), level=np.array([2]))
    errs = []
    rollout(env, tr.make_teacher("zero"),
            lambda s: errs.append(step_quantities(s)["vel_err"][0]) or bool(s.res.done[0]))
    assert row["lin_err"] == pytest.approx(np.mean(errs), rel=1e-12)
