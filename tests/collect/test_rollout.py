"""The one rollout loop (msta.collect.rollout.rollout), its per-step figures and the labelling
actor that recording and stage 2 drive it with."""

from __future__ import annotations

import os

import numpy as np
import pytest

from msta.collect.recorder import LabelledActor, record_rollouts
from msta.collect.rollout import fell, film, rollout, run, step_quantities
from msta.collect.sim.env import QuadrupedEnv
from msta.collect.sim.env_config import EnvConfig, NoiseConfig
from msta.collect.sim.randomization import RandomizationConfig
from msta.collect.sim.terrain import TerrainConfig


def env_cfg(n: int = 3, seconds: float = 0.2) -> EnvConfig:
    return EnvConfig(num_envs=n, seed=1, episode_length_s=seconds, nthread=1,
                     terrain=TerrainConfig(types=("flat",), num_levels=1, max_init_level=0,
                                           border=2.0),
                     randomization=RandomizationConfig(enabled=False),
                     noise=NoiseConfig(enabled=False))


class Recorder:
    """A fixed-action policy that logs its calls."""

    def __init__(self, value: float = 0.0) -> None:
        self.value, self.calls = value, []

    def act(self, obs):
        self.calls.append(("act", len(obs["joint_pos"])))
        return np.full((len(obs["joint_pos"]), 12), self.value)

    def reset(self, ids):
        self.calls.append(("reset", tuple(int(i) for i in ids)))


def test_the_loop_resets_the_policy_and_stops_where_told():
    env = QuadrupedEnv(env_cfg())
    env.reset()
    pol, seen = Recorder(), []
    steps = rollout(env, pol, lambda s: seen.append(s.t) or s.t == 14)
    # 0.2 s = 10 steps: every env's episode ends at step 9 and the policy is reset for them
    assert steps == 15 and seen == list(range(15))
    assert pol.calls[0] == ("reset", (0, 1, 2))
    assert pol.calls.count(("reset", (0, 1, 2))) == 2 and pol.calls[11] == ("reset", (0, 1, 2))
    env.reset()
    pol = Recorder()
    assert rollout(env, pol, lambda s: False, max_steps=12, reset_done=False) == 12
    assert pol.calls.count(("reset", (0, 1, 2))) == 1     # only before the first step


def test_step_quantities_are_the_true_tracking_errors():
    env = QuadrupedEnv(env_cfg(n=2))
    env.reset()
    steps = []
    rollout(env, Recorder(), steps.append, max_steps=3)
    s = steps[-1]
    q = step_quantities(s)
    v = s.meas["base_lin_vel"][:, :2] - s.command[:, :2]
    np.testing.assert_allclose(q["vel_err"], np.hypot(v[:, 0], v[:, 1]))
    np.testing.assert_array_equal(q["total"], s.res.reward)
    np.testing.assert_array_equal(q["lin"], s.res.metrics["lin_vel_tracking"])


def test_msta_sim_summary_counts_every_step_and_episode():
    env = QuadrupedEnv(env_cfg())
    env.reset()
    summary = run(env, Recorder(), 25, progress=False)
    row = summary.per_type["flat"].row()
    assert row["steps"] == 75 and row["episodes"] == 6 and row["survival"] == 1.0


def test_survival_counts_falls_and_blowups_not_time_limits():
    """msta.collect.rollout.fell, the one survival definition: an episode that ends by a fall (or
    a physics blow-up) is not survived, one that ends by the time limit is; msta-sim's table
    counts exactly these."""
    env = QuadrupedEnv(env_cfg(n=4, seconds=1.0))
    env.reset()
    rng = np.random.default_rng(0)
    marks = []
    summary = run(env, lambda obs: rng.uniform(-20, 20, (4, 12)), 50, progress=False)
    env.reset()
    rollout(env, lambda obs: rng.uniform(-20, 20, (4, 12)),
            lambda s: marks.append((fell(s.res), s.res.terminated, s.res.truncated)), 50)
    fallen, terminated, truncated = (np.array(m) for m in zip(*marks, strict=True))
    assert fallen.sum() > 0 and (fallen == terminated).all() and not (fallen & truncated).any()
    row = summary.per_type["flat"].row()
    assert row["survival"] < 1.0
    started = row["episodes"] + summary.per_type["flat"].unfinished
    assert row["survival"] == 1.0 - summary.per_type["flat"].fell / started
    env.reset()
    ends = []
    rollout(env, Recorder(), lambda s: ends.append(s.res.done.copy()) or bool(fell(s.res).any()),
            50)
    assert len(ends) == 50 and ends[-1].all()   # every standing robot reached its time limit


def test_a_film_is_the_rollout_loop_filmed_before_its_steps():
    """film: the frame before step ``first`` and every ``every``-th after it, of env_id's
    state at that moment, taken in the one loop (the caller's hook runs first)."""
    os.environ.setdefault("MUJOCO_GL", "egl")
    import mujoco

    from msta.collect.sim.render import make_renderer, render_state, tracking_camera

    env = QuadrupedEnv(env_cfg(n=2, seconds=0.1))  # 5-step episodes: the loop resets
    env.reset()
    states, pol = {0: env.state[1].copy()}, Recorder(0.3)
    frames = film(env, pol, 10, every=3, first=2, env_id=1, size=(48, 64),
                  on_step=lambda s: states.update({s.t + 1: env.state[1].copy()}))
    assert len(frames) == 3 and frames[0].shape == (48, 64, 3)
    assert pol.calls.count(("reset", (0, 1))) == 3   # before the first step, at 5 and 10
    renderer = make_renderer(env.model, 48, 64)
    data = mujoco.MjData(env.model)
    for frame, t in zip(frames, (2, 5, 8), strict=True):
        np.testing.assert_array_equal(
            frame, render_state(renderer, env.model, data, states[t], tracking_camera()))
    renderer.close()


def test_labelled_actor_records_the_label_and_mixes_by_beta():
    obs = {"joint_pos": np.zeros((400, 12))}
    for beta, share in ((0.0, 0.0), (1.0, 1.0), (0.5, 0.5)):
        a = LabelledActor(Recorder(1.0), Recorder(2.0), beta=beta, seed=0)
        executed = a.act(obs)
        np.testing.assert_array_equal(a.label_action, 2.0)
        assert abs((executed[:, 0] == 2.0).mean() - share) < 0.1
        assert a.label_share == [int((executed[:, 0] == 2.0).sum()), 400]
    alone = LabelledActor(Recorder(1.0))
    np.testing.assert_array_equal(alone.act(obs), alone.label_action)


def test_recording_with_a_label_stores_both_actions():
    env = QuadrupedEnv(env_cfg(n=2))
    got = []
    steps = record_rollouts(env, Recorder(0.1), 3, lambda f, t, lv: got.append(f),
                            label=Recorder(0.3), progress=False)
    assert len(got) == 3 and steps == 20 * 2    # two rounds of 10-step episodes
    for f in got:
        np.testing.assert_allclose(f["executed_action"], 0.1, rtol=1e-6)
        np.testing.assert_allclose(f["action"], 0.3, rtol=1e-6)
        assert len(f["action"]) == 10 and f["next.done"][-1, 0]


def test_recording_to_a_horizon_keeps_the_running_episodes_cut():
    env = QuadrupedEnv(env_cfg(n=2))
    got = []
    steps = record_rollouts(env, Recorder(0.1), 1, lambda f, t, lv: got.append(f),
                            progress=False, horizon=15)
    assert steps == 15 * 2                       # exactly the horizon, every env
    assert sorted(len(f["action"]) for f in got) == [5, 5, 10, 10]
    for f in got:                                # finished ones end done, cut ones do not
        assert bool(f["next.done"][-1, 0]) == (len(f["action"]) == 10)
    with pytest.raises(ValueError, match="horizon"):
        record_rollouts(env, Recorder(0.1), 1, lambda f, t, lv: None, horizon=0)
