"""Trials, the paper's metrics, and their normalization by the teacher.

A *trial* is one episode of one environment pinned to a (terrain type, level) tile. Trial
``i`` draws everything random in its episode (spawn point and yaw, domain-randomization
variant, commands and target headings, latency, pushes, observation noise) from its own
generator keyed by ``(seed, i)`` (:class:`EvalEnv`), so a student and the teacher see
identical tiles, levels, spawns, command samples and noise on the same trial, whatever
happens in the other environments of the batch. Only the first episode of every
environment counts; the auto-reset episodes after it are ignored.

Metrics per trial (rewards are the simulator's, already scaled by dt):

- ``lin_tracking``, ``ang_tracking``, ``total``: the episode's return of the linear- and
  angular-velocity tracking terms and of the total reward, divided by the episode's time
  limit in steps (per-step return; a fall ends the return early);
- ``survival``: 1 if the episode ended by the time limit, 0 on a fall or physics blow-up;
- ``vel_err``, ``yaw_err``: mean |v_xy - cmd_xy| (m/s) and |w_z - cmd_wz| (rad/s) over the
  steps lived (true base velocities);
- ``length``: steps lived / time limit.

Per terrain type the metrics are means over that terrain's trials (errors weighted by
steps); the ``average`` row is the mean over terrain types (per level likewise: the
``average`` of ``per_level`` is the mean over the terrains at that level); ``normalized``
divides the three returns by the teacher's on the same trials (for ``average``: the
student's terrain-averaged return over the teacher's). Every cell records its number of
trials and a 95 % confidence interval per figure (:mod:`eval.intervals`: Student t over
trials, the delta method on paired trials for ratios, Wilson for survival).

``msta-eval`` (:mod:`eval.evaluate`) and ``msta-correct``'s per-round evaluation both go
through :class:`eval.evaluate.Evaluator`, so the same checkpoint on the same trials gets
the same figures in both (and on the stage-2 model card).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from tqdm import tqdm

from collect.rollout import as_policy
from collect.sim.env import PROPRIO, REASONS, EnvConfig, QuadrupedEnv
from eval.intervals import mean_interval, proportion_interval, ratio_interval
from msta_data.sensors import SENSORS

#: Returns normalized by the teacher's (the paper's three metrics).
RETURNS: tuple[str, ...] = ("lin_tracking", "ang_tracking", "total")
#: Every number reported per terrain.
METRICS: tuple[str, ...] = RETURNS + ("survival", "vel_err", "yaw_err", "length")
_TRIAL_SALT = 0x7E57


class NotApplicable(Exception):
    """A policy cannot take a condition (it raised on construction or on its first step)."""


class EvalEnv(QuadrupedEnv):
    """``QuadrupedEnv`` whose per-environment random draws come from per-trial generators.

    The parent draws commands, pushes, noise and resets for all environments from one
    generator, so a fall in one environment shifts the random numbers of all the others.
    Here every environment draws from the generator of the trial it runs.

    Args:
        cfg: the environment configuration (``terrain.curriculum`` must be False).
    """

    def __init__(self, cfg: EnvConfig) -> None:
        if cfg.terrain.curriculum:
            raise ValueError("evaluation pins tiles: terrain.curriculum must be False")
        super().__init__(cfg)
        self.trial_rngs: list[np.random.Generator] = []
        widths = [np.full(SENSORS[k].dim, self._noise[k]) for k in PROPRIO]
        self._noise_width = np.concatenate(widths)

    def start(self, trials: np.ndarray, type_idx: np.ndarray, level: np.ndarray,
              ) -> dict[str, np.ndarray]:
        """Reset every environment into its trial.

        Args:
            trials: (N,) trial indices (key each environment's generator).
            type_idx: (N,) terrain type index per environment.
            level: (N,) level per environment.
        Returns:
            the first observations.
        """
        seed = self.cfg.seed
        self.trial_rngs = [np.random.default_rng([seed, _TRIAL_SALT, int(t)]) for t in trials]
        self.rng = np.random.default_rng([seed, _TRIAL_SALT])  # no per-env draw uses it
        if not self.meas:  # the parent updates measurements row by row after the first reset
            self.state[:] = self._template
            self.meas = self._measure(self.state, np.zeros((self.num_envs, 1,
                                                            self.model.nsensordata)))
        return self.reset(type_idx=type_idx, level=level)

    def _reset_ids(self, ids: np.ndarray) -> None:
        shared = self.rng
        # the parent re-steers the yaw-rate command of *every* env on a reset: keep the others'
        yaw_rate = self.commands.command[:, 2].copy()
        try:
            for i in ids:
                self.rng = self.trial_rngs[i]
                super()._reset_ids(np.array([i]))
        finally:
            self.rng = shared
        others = np.setdiff1d(np.arange(self.num_envs), ids)
        self.commands.command[others, 2] = yaw_rate[others]
        self._hist_fresh = np.asarray(ids)

    def _resample_commands(self) -> None:
        every = max(1, round(self.cfg.commands.resample_s / self.dt))
        ids = np.flatnonzero((self.episode_step % every == 0) & (self.episode_step > 0))
        for i in ids:
            self.commands.resample(np.array([i]), self.trial_rngs[i])

    def _push(self) -> None:
        rc = self.cfg.randomization
        if not (rc.enabled and rc.push_interval_s > 0 and rc.push_max_vel > 0):
            return
        every = max(1, round(rc.push_interval_s / self.dt))
        v = self.layout.base_linvel
        for i in np.flatnonzero((self.episode_step + self.push_step) % every == every - 1):
            self.state[i, v.start:v.start + 2] += self.trial_rngs[i].uniform(
                -rc.push_max_vel, rc.push_max_vel, 2)

    def _proprio(self, m: dict[str, np.ndarray], ids: np.ndarray) -> np.ndarray:
        x = np.concatenate([m["base_ang_vel"] if k == "ang_vel" else m[k] for k in PROPRIO],
                           axis=1)
        if self._noise_width.any():
            u = np.stack([self.trial_rngs[i].random(x.shape[1]) for i in ids])
            x = x + (2.0 * u - 1.0) * self._noise_width
        return x.astype(np.float32)


@dataclass(frozen=True)
class TrialLayout:
    """Which tile each trial runs on: trial i -> terrain i mod n_terrains, then level.

    Args:
        terrains: terrain types evaluated (a subset of the env's ``terrain.types``).
        levels: levels evaluated.
        trials: number of trials.
    """

    terrains: tuple[str, ...]
    levels: tuple[int, ...]
    trials: int

    def __post_init__(self) -> None:
        if self.trials < 1:
            raise ValueError(f"trials={self.trials} must be >= 1")
        if not self.terrains or not self.levels:
            raise ValueError("at least one terrain and one level are needed")

    def terrain_of(self, trials: np.ndarray) -> np.ndarray:
        """Index into ``terrains`` of each trial."""
        return np.asarray(trials) % len(self.terrains)

    def level_of(self, trials: np.ndarray) -> np.ndarray:
        return np.asarray(self.levels)[(np.asarray(trials) // len(self.terrains))
                                       % len(self.levels)]

    def rounds(self, max_envs: int) -> list[np.ndarray]:
        """Trial ids per round (equal sizes; the last round is topped up with extra trials
        beyond ``trials`` whose results are discarded)."""
        n_rounds = math.ceil(self.trials / max_envs)
        size = math.ceil(self.trials / n_rounds)
        return [np.arange(r * size, (r + 1) * size) for r in range(n_rounds)]


@dataclass
class TrialResults:
    """Per-trial sums; arrays of shape (trials,)."""

    lin: np.ndarray
    ang: np.ndarray
    total: np.ndarray
    steps: np.ndarray
    fell: np.ndarray
    vel_err: np.ndarray
    yaw_err: np.ndarray
    max_steps: int

    @classmethod
    def zeros(cls, n: int, max_steps: int) -> TrialResults:
        z = [np.zeros(n) for _ in range(6)]
        return cls(*z[:4], np.zeros(n, dtype=bool), *z[4:6], max_steps=max_steps)

    def take(self, idx: np.ndarray) -> TrialResults:
        return TrialResults(self.lin[idx], self.ang[idx], self.total[idx], self.steps[idx],
                            self.fell[idx], self.vel_err[idx], self.yaw_err[idx],
                            self.max_steps)


#: round index, number of envs -> an actor with act(obs) / reset(ids)
ActorFactory = Callable[[int, int], Any]


def _first_act(make_actor: ActorFactory, n: int, obs: dict[str, np.ndarray]):
    """Build the round-0 actor and take its first step; failures mean n/a."""
    try:
        actor = make_actor(0, n)
        act, reset = as_policy(actor)
        reset(np.arange(n))
        return act, reset, act(obs)
    except (ValueError, KeyError, NotImplementedError) as e:
        raise NotApplicable(f"{type(e).__name__}: {e}") from e


def run_trials(env: EvalEnv, make_actor: ActorFactory, layout: TrialLayout, desc: str = "",
               progress: bool = True) -> TrialResults:
    """Run every trial of ``layout`` with actors from ``make_actor``.

    Args:
        env: the evaluation env; ``env.num_envs`` environments per round.
        make_actor: (round, num_envs) -> fresh actor (a teacher, or a ``StudentActor``).
        layout: trials and their tiles.
        desc: progress-bar label.
        progress: show a tqdm bar over env steps.
    Raises:
        NotApplicable: the actor cannot be built or fails on its first step.
    """
    n, max_steps = env.num_envs, env.max_steps
    rounds = layout.rounds(n)
    if len(rounds[0]) != n:
        raise ValueError(f"env has {n} envs, the layout needs rounds of {len(rounds[0])}")
    out = TrialResults.zeros(len(rounds) * n, max_steps)
    bar = tqdm(total=len(rounds) * n * max_steps, desc=desc, unit="step", unit_scale=True,
               disable=not progress, leave=False)
    for r, ids in enumerate(rounds):
        types = np.asarray([env.cfg.terrain.types.index(t) for t in layout.terrains])
        obs = env.start(ids, types[layout.terrain_of(ids)], layout.level_of(ids))
        if r == 0:
            act, _, first = _first_act(make_actor, n, obs)
        else:
            act, reset = as_policy(make_actor(r, n))
            reset(np.arange(n))
            first = act(obs)
        _episode(env, act, obs, first, out, ids, bar)
    bar.close()
    return out.take(np.arange(layout.trials))


def _episode(env: EvalEnv, act: Callable, obs: dict, action: np.ndarray, out: TrialResults,
             ids: np.ndarray, bar: tqdm) -> None:
    """One round: step until every environment's first episode ended; sum into ``out``."""
    n = env.num_envs
    alive = np.ones(n, dtype=bool)
    bad = np.isin(np.arange(len(REASONS)), [REASONS.index("fall"), REASONS.index("nan")])
    for t in range(env.max_steps):
        if t:
            action = act(obs)
        cmd = env.commands.command.copy()
        res = env.step(action)
        m, w = env.meas_before_reset, alive.astype(np.float64)
        out.lin[ids] += w * res.metrics["lin_vel_tracking"]
        out.ang[ids] += w * res.metrics["ang_vel_tracking"]
        out.total[ids] += w * res.reward
        out.steps[ids] += w
        out.vel_err[ids] += w * np.linalg.norm(m["base_lin_vel"][:, :2] - cmd[:, :2], axis=1)
        out.yaw_err[ids] += w * np.abs(m["base_ang_vel"][:, 2] - cmd[:, 2])
        ended = alive & res.done
        out.fell[ids[ended]] = bad[res.reason[ended]]
        alive &= ~res.done
        bar.update(n)
        if not alive.any():
            bar.update(n * (env.max_steps - t - 1))
            break
        obs = res.obs


def _cells(layout: TrialLayout) -> dict[str, Any]:
    """Every reported cell as its strata (index arrays of trials, one per terrain).

    ``{"per_terrain": {terrain: [idx], "average": [idx per terrain]}, "per_level":
    {terrain: {level: [idx]}, "average": {level: [idx per terrain]}}}``; terrains or levels
    without trials are left out.
    """
    trials = np.arange(layout.trials)
    t_of, l_of = layout.terrain_of(trials), layout.level_of(trials)
    per_terrain: dict[str, Any] = {}
    per_level: dict[str, Any] = {}
    for i, name in enumerate(layout.terrains):
        if not (t_of == i).any():
            continue
        per_terrain[name] = [np.flatnonzero(t_of == i)]
        per_level[name] = {str(lv): [np.flatnonzero((t_of == i) & (l_of == lv))]
                           for lv in layout.levels if ((t_of == i) & (l_of == lv)).any()}
    per_terrain["average"] = [s for name in list(per_terrain) for s in per_terrain[name]]
    per_level["average"] = {
        str(lv): [np.flatnonzero((t_of == i) & (l_of == lv)) for i in range(len(layout.terrains))
                  if ((t_of == i) & (l_of == lv)).any()]
        for lv in layout.levels if (l_of == lv).any()}
    return {"per_terrain": per_terrain, "per_level": per_level}


def _map_cells(cells: dict[str, Any], fn: Callable[[list[np.ndarray]], dict]) -> dict[str, Any]:
    return {"per_terrain": {k: fn(v) for k, v in cells["per_terrain"].items()},
            "per_level": {t: {lv: fn(v) for lv, v in by.items()}
                          for t, by in cells["per_level"].items()}}


def _weights(strata: list[np.ndarray], mass: np.ndarray | None = None
             ) -> tuple[np.ndarray, np.ndarray]:
    """(trial indices, weights summing to 1): every stratum weighs 1/K, split over its
    trials equally or in proportion to ``mass`` (steps lived)."""
    parts = []
    for s in strata:
        v = np.ones(len(s)) if mass is None else mass[s].astype(np.float64)
        parts.append(v / v.sum() / len(strata))
    return np.concatenate(strata), np.concatenate(parts)


def _ci(interval: tuple[float, float] | None) -> list[float] | None:
    return None if interval is None else [float(interval[0]), float(interval[1])]


def summarize(res: TrialResults, strata: list[np.ndarray]) -> dict[str, Any]:
    """One cell's metrics: the mean over its strata of each stratum's mean (module
    docstring), the cell's trial count and a 95 % interval per metric (eval.intervals).

    Args:
        res: per-trial results.
        strata: index arrays into ``res`` (one per terrain of the cell).
    Returns:
        ``{metric: value, ..., "trials": n, "ci": {metric: [low, high] or None}}``.
    """
    idx, w = _weights(strata)
    steps = np.maximum(res.steps, 1.0)
    _, w_steps = _weights(strata, steps)
    m = float(res.max_steps)
    out: dict[str, Any] = {}
    ci: dict[str, list[float] | None] = {}
    for key, x, wk in (("lin_tracking", res.lin / m, w), ("ang_tracking", res.ang / m, w),
                       ("total", res.total / m, w), ("vel_err", res.vel_err / steps, w_steps),
                       ("yaw_err", res.yaw_err / steps, w_steps), ("length", res.steps / m, w)):
        value, interval = mean_interval(x[idx], wk)
        out[key], ci[key] = value, _ci(interval)
    value, interval = proportion_interval((~res.fell[idx]).astype(np.float64), w)
    out["survival"], ci["survival"] = value, _ci(interval)
    out = {k: out[k] for k in METRICS}
    return {**out, "trials": len(idx), "ci": {k: ci[k] for k in METRICS}}


def aggregate(res: TrialResults, layout: TrialLayout) -> dict[str, Any]:
    """Per-terrain and per-(terrain, level) summaries, plus the averages over terrains.

    Args:
        res: per-trial results (``layout.trials`` of them).
        layout: which tile each trial ran on.
    Returns:
        ``{"per_terrain": {terrain: summary, ..., "average": summary}, "per_level":
        {terrain: {level: summary}, "average": {level: summary}}}`` (:func:`summarize`).
    """
    return _map_cells(_cells(layout), lambda strata: summarize(res, strata))


def normalize(student: TrialResults, teacher: TrialResults, layout: TrialLayout
              ) -> dict[str, Any]:
    """The three returns divided by the teacher's on the same trials, with 95 % intervals
    (delta method on the paired trials, eval.intervals).

    Args:
        student, teacher: per-trial results over the same ``layout``.
        layout: which tile each trial ran on.
    Returns:
        ``{"per_terrain": {terrain: {metric: ratio, "trials": n, "ci": {metric: [low,
        high]}}}, "per_level": ...}`` in :func:`aggregate`'s layout; the average divides
        the student's terrain-averaged return by the teacher's (defined even when the
        teacher scores 0 on one terrain); a ratio over a zero teacher value is None.
    """
    m = float(student.max_steps)
    pairs = {"lin_tracking": (student.lin, teacher.lin), "ang_tracking": (student.ang,
             teacher.ang), "total": (student.total, teacher.total)}

    def cell(strata: list[np.ndarray]) -> dict[str, Any]:
        idx, w = _weights(strata)
        out: dict[str, Any] = {}
        ci: dict[str, list[float] | None] = {}
        for key in RETURNS:
            s, t = pairs[key]
            out[key], interval = ratio_interval(s[idx] / m, t[idx] / m, w)
            ci[key] = _ci(interval)
        return {**out, "trials": len(idx), "ci": ci}

    return _map_cells(_cells(layout), cell)
