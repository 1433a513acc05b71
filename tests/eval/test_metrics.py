"""Per-trial random streams (QuadrupedEnv.reset(streams=...)), trial layout and metric aggregation."""

from __future__ import annotations

import numpy as np
import pytest

from msta.collect.sim.commands import CommandConfig
from msta.collect.sim.env import QuadrupedEnv
from msta.collect.sim.env_config import EnvConfig
from msta.collect.sim.terrain import TerrainConfig
from msta.eval.intervals import wilson_interval
from msta.eval.metrics import TrialLayout, aggregate, normalize, run_trials, start_trials, survival
from msta.policies.teacher.config import ZeroTeacher

TYPES = ("flat", "smooth_slope")


def make_env(n: int, seconds: float = 2.0) -> QuadrupedEnv:
    return QuadrupedEnv(EnvConfig(num_envs=n, seed=5, episode_length_s=seconds,
                             terrain=TerrainConfig(types=TYPES, curriculum=False),
                             commands=CommandConfig(resample_s=0.2)))


def roll(env: QuadrupedEnv, wild_env0: bool, steps: int = 60):
    """Observations of env 1 and commands of every env per step; env 0 may flail."""
    start_trials(env, np.arange(3), np.array([0, 1, 0]), np.array([0, 2, 3]))
    obs1, cmds, done0 = [], [], False
    for t in range(steps):
        a = np.zeros((3, 12))
        if wild_env0:
            a[0] = 8.0 * np.sign(np.sin(0.7 * t + np.arange(12)))
        res = env.step(a)
        done0 |= bool(res.done[0])
        obs1.append(np.concatenate([res.obs[k][1] for k in sorted(res.obs)]))
        cmds.append((env.commands.command[1:, :2].copy(), env.commands.heading[1:].copy()))
    return np.array(obs1), cmds, done0


def test_trials_do_not_see_other_environments():
    """Env 0 falling and resetting must not change what env 1 and 2 observe or are told."""
    env = make_env(3)
    calm_obs, calm_cmds, calm_done = roll(env, wild_env0=False)
    wild_obs, wild_cmds, wild_done = roll(env, wild_env0=True)
    assert wild_done and not calm_done, "precondition: the flailing robot must fall"
    np.testing.assert_array_equal(calm_obs, wild_obs)  # noise, commands, pushes, physics
    for (c1, h1), (c2, h2) in zip(calm_cmds, wild_cmds):
        np.testing.assert_array_equal(c1, c2)
        np.testing.assert_array_equal(h1, h2)
    assert len({tuple(c.ravel()) for c, _ in calm_cmds}) > 3  # commands were resampled


def test_results_do_not_depend_on_batch_layout():
    layout = TrialLayout(TYPES, (0, 4), trials=4)
    zero = ZeroTeacher()
    a = run_trials(make_env(4, 1.0), lambda r, n: zero, layout, progress=False)
    b = run_trials(make_env(2, 1.0), lambda r, n: zero, layout, progress=False)
    for field in ("lin", "ang", "total", "steps", "fell", "vel_err", "yaw_err"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    assert a.steps.min() > 0 and a.lin.max() > 0


def test_layout_rounds_and_tiles():
    lay = TrialLayout(("a", "b", "c"), (1, 5), trials=7)
    np.testing.assert_array_equal(lay.terrain_of(np.arange(7)), [0, 1, 2, 0, 1, 2, 0])
    np.testing.assert_array_equal(lay.level_of(np.arange(7)), [1, 1, 1, 5, 5, 5, 1])
    rounds = lay.rounds(3)
    assert [len(r) for r in rounds] == [3, 3, 3] and rounds[-1][-1] == 8
    with pytest.raises(ValueError, match="trials=0"):
        TrialLayout(("a",), (0,), 0)


def test_streams_refuse_the_curriculum_and_a_wrong_shape():
    env = QuadrupedEnv(EnvConfig(num_envs=2, terrain=TerrainConfig(curriculum=True)))
    with pytest.raises(ValueError, match="curriculum"):
        env.reset(streams=np.arange(2))
    with pytest.raises(ValueError, match="streams has shape"):
        make_env(2).reset(streams=np.arange(3))


def test_a_trial_is_the_same_in_any_batch_position():
    """Trial 7's first observations are the same alone and as env 1 of a batch of three."""
    alone, batch = make_env(1), make_env(3)
    a = start_trials(alone, np.array([7]), np.array([1]), np.array([2]))
    b = start_trials(batch, np.array([3, 7, 9]), np.array([0, 1, 0]), np.array([0, 2, 4]))
    for k in a:
        np.testing.assert_array_equal(a[k][0], b[k][1], err_msg=k)
    c = start_trials(alone, np.array([8]), np.array([1]), np.array([2]))
    assert not np.array_equal(a["joint_pos"], c["joint_pos"])  # another trial, other draws


def test_aggregate_and_normalize_by_hand():
    from msta.eval.metrics import TrialResults

    lay = TrialLayout(("a", "b"), (0,), trials=4)   # trials 0, 2 on a; 1, 3 on b
    r = TrialResults.zeros(4, max_steps=10)
    r.lin[:] = [1.0, 2.0, 3.0, 4.0]
    r.total[:] = [2.0, 0.0, 2.0, 0.0]
    r.steps[:] = [10, 5, 10, 10]
    r.fell[:] = [False, True, False, False]
    r.vel_err[:] = [1.0, 1.0, 2.0, 2.0]
    agg = aggregate(r, lay)
    assert agg["per_terrain"]["a"]["lin_tracking"] == pytest.approx(0.2)
    assert agg["per_terrain"]["b"]["survival"] == 0.5
    assert agg["per_terrain"]["b"]["vel_err"] == pytest.approx(3.0 / 15)
    assert agg["per_terrain"]["average"]["lin_tracking"] == pytest.approx(0.25)
    assert agg["per_level"]["average"]["0"]["lin_tracking"] == pytest.approx(0.25)
    # trial counts and intervals per cell: lin on a = (0.1, 0.3): mean 0.2, s = 0.1414
    assert [agg["per_terrain"][k]["trials"] for k in ("a", "b", "average")] == [2, 2, 4]
    lo, hi = agg["per_terrain"]["a"]["ci"]["lin_tracking"]
    assert (hi - lo) / 2 == pytest.approx(12.7062 * 0.1414214 / 2 ** 0.5, rel=1e-4)
    s_lo, s_hi = agg["per_terrain"]["b"]["ci"]["survival"]          # Wilson, 1 of 2
    assert 0 < s_lo < 0.5 < s_hi < 1
    half = TrialResults(r.lin / 2, r.ang, r.total / 2, r.steps, r.fell, r.vel_err, r.yaw_err, 10)
    norm = normalize(half, r, lay)
    assert norm["per_terrain"]["a"]["lin_tracking"] == pytest.approx(0.5)
    assert norm["per_terrain"]["a"]["ci"]["lin_tracking"] == pytest.approx([0.5, 0.5])  # paired
    assert norm["per_terrain"]["b"]["total"] is None        # teacher scored 0 there
    assert norm["per_terrain"]["b"]["ci"]["total"] is None
    assert norm["per_terrain"]["average"]["total"] == pytest.approx(0.5)
    assert norm["per_level"]["a"]["0"]["lin_tracking"] == pytest.approx(0.5)
    assert norm["per_terrain"]["average"]["trials"] == 4


def test_survival_is_the_share_not_fallen_with_its_wilson_interval():
    fallen = np.array([True, False, False, False, True, False])
    p, interval = survival(fallen)
    assert p == 4 / 6 and interval == wilson_interval(4 / 6, 6)
    # weighted (two strata of 2 and 4 episodes, each weighing 1/2): the stratified share
    w = np.array([0.25, 0.25, 0.125, 0.125, 0.125, 0.125])
    assert survival(fallen, w)[0] == pytest.approx(0.5 * 0.5 + 0.5 * 0.75)
