"""Trials, the paper's metrics, and their normalization by the teacher.

A *trial* is one episode of one environment pinned to a (terrain type, level) tile. Trial
``i`` draws everything random in its episode (spawn point and yaw, domain-randomization
variant, commands and target headings, latency, pushes, observation noise) from its own
generator keyed by ``(seed, i)`` (the simulator's per-environment streams,
``QuadrupedEnv.reset(streams=...)``; :func:`start_trials`), so a student and the teacher see
identical tiles, levels, spawns, command samples and noise on the same trial, whatever
happens in the other environments of the batch. Only the first episode of every
environment counts; the auto-reset episodes after it are ignored. The trials run through the
one rollout loop (:func:`msta.collect.rollout.rollout`), and the per-step figures are
:func:`msta.collect.rollout.step_quantities`, the same that msta-sim and the teacher report sum.

Metrics per trial (rewards are the simulator's, already scaled by dt):

- ``lin_tracking``, ``ang_tracking``, ``total``: the episode's return of the linear- and
  angular-velocity tracking terms and of the total reward, divided by the episode's time
  limit in steps (per-step return; a fall ends the return early);
- ``survival``: 1 if the episode ended by the time limit, 0 on a fall or physics blow-up
  (:func:`msta.collect.rollout.fell`; the cell's figure is :func:`survival`);
- ``vel_err``, ``yaw_err``: mean |v_xy - cmd_xy| (m/s) and |w_z - cmd_wz| (rad/s) over the
  steps lived (true base velocities);
- ``length``: steps lived / time limit.

Per terrain type the metrics are means over that terrain's trials (errors weighted by
steps); the ``average`` row is the mean over terrain types (per level likewise: the
``average`` of ``per_level`` is the mean over the terrains at that level); ``normalized``
divides the three returns by the teacher's on the same trials (for ``average``: the
student's terrain-averaged return over the teacher's). Every cell records its number of
trials and a 95 % confidence interval per figure (:mod:`msta.eval.intervals`: Student t over
trials, the delta method on paired trials for ratios, Wilson for survival).

``msta-eval`` (:mod:`msta.eval.evaluate`) and ``msta-correct``'s per-round evaluation both go
through :class:`msta.eval.evaluator.Evaluator`, so the same checkpoint on the same trials (and
device type) gets the same figures in both; msta-correct's round table and the stage-2 model card pick theirs
from the run record with :func:`headline`. The teacher report summarizes its tiles with
:func:`summarize` (one trial per finished episode).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from tqdm import tqdm

from msta.collect.rollout import STEP_QUANTITIES, Step, as_policy, fell, rollout, step_quantities
from msta.collect.sim.env import QuadrupedEnv
from msta.data.hub_eval import HEADLINE_FIGURES
from msta.eval.intervals import Interval, mean_interval, proportion_interval, ratio_interval

#: Returns normalized by the teacher's (the paper's three metrics).
RETURNS: tuple[str, ...] = ("lin_tracking", "ang_tracking", "total")
#: Every number reported per terrain.
METRICS: tuple[str, ...] = RETURNS + ("survival", "vel_err", "yaw_err", "length")




class NotApplicable(Exception):
    """A policy cannot take a condition (it raised on construction or on its first step)."""


def start_trials(env: QuadrupedEnv, trials: np.ndarray, type_idx: np.ndarray,
                 level: np.ndarray) -> dict[str, np.ndarray]:
    """Reset every environment into its trial: its tile, and the trial's own random stream
    (``QuadrupedEnv.reset(streams=trials)``).

    Args:
        env: a simulator with ``terrain.curriculum`` off.
        trials: (N,) trial indices (key each environment's generator).
        type_idx: (N,) terrain type index per environment.
        level: (N,) level per environment.
    Returns:
        the first observations.
    """
    return env.reset(type_idx=type_idx, level=level, streams=trials)


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

    def rounds(self, num_envs: int) -> list[np.ndarray]:
        """Trial ids per round (equal sizes; the last round is topped up with extra trials
        beyond ``trials`` whose results are discarded)."""
        n_rounds = math.ceil(self.trials / num_envs)
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

    def add(self, ids: np.ndarray, step: Step, weight: np.ndarray) -> None:
        """Sum one step's :func:`~msta.collect.rollout.step_quantities` of the environments
        running trials ``ids``, each times ``weight`` (1 while its first episode runs)."""
        q = step_quantities(step)
        for key in STEP_QUANTITIES:
            getattr(self, key)[ids] += weight * q[key]
        self.steps[ids] += weight

    def take(self, idx: np.ndarray) -> TrialResults:
        return TrialResults(self.lin[idx], self.ang[idx], self.total[idx], self.steps[idx],
                            self.fell[idx], self.vel_err[idx], self.yaw_err[idx],
                            self.max_steps)

    def put(self, idx: np.ndarray, part: TrialResults) -> None:
        """Write ``part`` (from :meth:`take` with the same ``idx``) back at ``idx``."""
        for key in ("lin", "ang", "total", "steps", "fell", "vel_err", "yaw_err"):
            getattr(self, key)[idx] = getattr(part, key)


#: round index, number of envs -> an actor with act(obs) / reset(ids)
ActorFactory = Callable[[int, int], Any]


class _FirstStepGuard:
    """The round-0 actor: a failure when it is reset or takes its first step means n/a."""

    def __init__(self, act: Callable, reset: Callable) -> None:
        self._act, self._reset, self.first = act, reset, True

    def reset(self, ids: np.ndarray) -> None:
        try:
            self._reset(ids)
        except (ValueError, KeyError, NotImplementedError) as e:
            raise NotApplicable(f"{type(e).__name__}: {e}") from e

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        if not self.first:
            return self._act(obs)
        self.first = False
        try:
            return self._act(obs)
        except (ValueError, KeyError, NotImplementedError) as e:
            raise NotApplicable(f"{type(e).__name__}: {e}") from e


def run_trials(env: QuadrupedEnv, make_actor: ActorFactory, layout: TrialLayout,
               desc: str = "", progress: bool = True, done: Sequence[TrialResults] = (),
               on_round: Callable[[int, int, TrialResults], None] | None = None
               ) -> TrialResults:
    """Run every trial of ``layout`` with actors from ``make_actor``.

    Rounds are independent (a fresh actor each; every trial has its own random stream),
    which is what lets an interrupted run continue at its next round.

    Args:
        env: the evaluation simulator (``terrain.curriculum`` off); ``env.num_envs``
            environments per round.
        make_actor: (round, num_envs) -> fresh actor (a teacher, or a ``StudentActor``).
        layout: trials and their tiles.
        desc: progress-bar label.
        progress: show a tqdm bar over env steps.
        done: the results of the first ``len(done)`` rounds, finished earlier (each as
            ``on_round`` received it); they are not run again.
        on_round: called as ``on_round(round, rounds, results_of_that_round)`` after each
            round this call runs.
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
        if r < len(done):
            out.put(ids, done[r])
            bar.update(n * max_steps)
            continue
        play_round(env, make_actor, layout, r, ids, out, bar)
        if on_round is not None:
            on_round(r, len(rounds), out.take(ids))
    bar.close()
    return out.take(np.arange(layout.trials))


def play_round(env: QuadrupedEnv, make_actor: ActorFactory, layout: TrialLayout, r: int,
               ids: np.ndarray, out: TrialResults, bar: tqdm) -> None:
    """Round ``r`` of the trials ``ids``: start them on their tiles, build the round's actor
    and play it (:func:`run_trials`' round, also what a Ray worker runs).

    Raises:
        NotApplicable: round 0's actor cannot be built or fails on its first step.
    """
    n = env.num_envs
    types = np.asarray([env.cfg.terrain.types.index(t) for t in layout.terrains])
    start_trials(env, ids, types[layout.terrain_of(ids)], layout.level_of(ids))
    if r == 0:
        try:
            actor: Any = _FirstStepGuard(*as_policy(make_actor(0, n)))
        except (ValueError, KeyError, NotImplementedError) as e:
            raise NotApplicable(f"{type(e).__name__}: {e}") from e
    else:
        actor = make_actor(r, n)
    _round(env, actor, out, ids, bar)


def _round(env: QuadrupedEnv, actor: Any, out: TrialResults, ids: np.ndarray,
           bar: tqdm) -> None:
    """One round: step until every environment's first episode ended; sum into ``out``."""
    n = env.num_envs
    alive = np.ones(n, dtype=bool)

    def on_step(step: Step) -> bool:
        res = step.res
        out.add(ids, step, alive.astype(np.float64))
        ended = alive & res.done
        out.fell[ids[ended]] = fell(res)[ended]
        alive[:] &= ~res.done
        bar.update(n)
        if not alive.any():
            bar.update(n * (env.max_steps - step.t - 1))
            return True
        return False

    rollout(env, actor, on_step, max_steps=env.max_steps, reset_done=False)


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


def survival(fallen: np.ndarray, w: np.ndarray | None = None) -> tuple[float, Interval]:
    """msta's survival figure: the (weighted) share of episodes that did not end by a fall
    or a physics blow-up (``fallen``: :func:`msta.collect.rollout.fell` at each episode's end),
    with its 95 % Wilson interval (:func:`msta.eval.intervals.proportion_interval`; equal weights:
    the share survived / episodes over that many episodes).

    Args:
        fallen: (n,) bool per episode.
        w: (n,) weights (default equal).
    """
    return proportion_interval((~np.asarray(fallen, dtype=bool)).astype(np.float64), w)


def summarize(res: TrialResults, strata: list[np.ndarray]) -> dict[str, Any]:
    """One cell's metrics: the mean over its strata of each stratum's mean (module
    docstring), the cell's trial count and a 95 % interval per metric (msta.eval.intervals).

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
    value, interval = survival(res.fell[idx], w)
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
    (delta method on the paired trials, msta.eval.intervals).

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


def headline(run: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """The :data:`HEADLINE_FIGURES` of one run record (``msta.eval.evaluator.Evaluator.condition``
    with status ok) per terrain and ``average``, as cells keyed by figure name:
    ``{terrain: {name: value, ..., "trials": n, "ci": {name: [low, high] or None}}}``
    (``msta.eval.report_cells.fmt_cell`` formats them). msta-correct's round table and the stage-2 model
    card read their figures here, so both show msta-eval's numbers."""
    out: dict[str, dict[str, Any]] = {}
    for name, figure, key in HEADLINE_FIGURES:
        for t, cell in run[figure]["per_terrain"].items():
            row = out.setdefault(t, {"ci": {}})
            row[name] = cell[key]
            row["ci"][name] = cell["ci"][key]
            row["trials"] = cell["trials"]
    return out
