"""95 % confidence intervals for the evaluation figures (``msta-eval``, ``msta-correct``).

Every figure of :mod:`msta.eval.metrics` is a weighted mean over the trials of its cell,
``theta = sum_i w_i x_i`` with ``sum_i w_i = 1`` (a terrain cell: equal weights; the
``average`` row: each terrain weighs 1/K, split over its trials; step-weighted errors:
weights proportional to the steps lived), or a ratio of two such means over the *same*
trials (a student's return over the teacher's). The intervals:

- **means** (returns, length, errors): ``theta ± t(n-1) * se`` with the linearization
  ("sandwich") variance ``se^2 = n/(n-1) * sum_i w_i^2 (x_i - theta)^2``, n the trials of
  the cell. With equal weights this is the textbook Student-t interval
  ``mean ± t(n-1) * s/sqrt(n)`` (exact 95 % coverage for normal trials); the weights are
  taken as fixed.
- **ratios to the teacher** (normalized returns): the delta method on paired trials,
  ``R = S/T``, influence ``psi_i = w_i (s_i - R t_i) / T``,
  ``se^2 = n/(n-1) * sum_i psi_i^2``, interval ``R ± t(n-1) * se``. Pairing matters: a
  trial that is hard for the teacher is usually hard for the student, and the interval
  uses the spread of ``s_i - R t_i``, not the two spreads separately.
- **survival** (a proportion): Wilson's score interval with the Kish effective sample size
  ``n_eff = 1 / sum_i w_i^2`` (n for equal weights); it stays inside [0, 1] and is defined
  for one trial and for 0 % or 100 %.

A mean or ratio over one trial has no interval (None). Cells that mix terrains or levels
(the ``average`` row, a terrain with several levels) use the pooled spread over their
trials, so the tile-to-tile differences count as noise: those intervals are conservative.
The intervals describe trial-to-trial noise of this evaluation (its seed, tiles and
episode length), not the spread over training runs.
"""

from __future__ import annotations

import math
from functools import lru_cache
from statistics import NormalDist

import numpy as np

#: Confidence level of every interval in the reports.
LEVEL = 0.95

Interval = tuple[float, float]


def _t_central(t: float, df: int) -> float:
    """P(|T| <= t) for Student's t with integer ``df`` (Abramowitz & Stegun 26.7.3-4)."""
    theta = math.atan(t / math.sqrt(df))
    s, c2 = math.sin(theta), math.cos(theta) ** 2
    if df % 2:
        if df == 1:
            return 2.0 * theta / math.pi
        term = total = math.cos(theta)
        for k in range(3, df - 1, 2):  # cos^k terms up to cos^(df-2)
            term *= c2 * (k - 1) / k
            total += term
        return 2.0 / math.pi * (theta + s * total)
    term = total = 1.0
    for k in range(2, df - 1, 2):
        term *= c2 * (k - 1) / k
        total += term
    return s * total


@lru_cache(maxsize=256)
def t_quantile(df: int, level: float = LEVEL) -> float:
    """Two-sided Student-t critical value: P(|T| <= q) = ``level`` with ``df`` degrees of
    freedom (12.706 for df = 1, 2.262 for df = 9, -> 1.960 as df grows).

    Args:
        df: degrees of freedom (>= 1).
        level: central probability, in (0, 1).
    """
    if df < 1:
        raise ValueError(f"df={df} must be >= 1")
    if not 0.0 < level < 1.0:
        raise ValueError(f"level={level} must be in (0, 1)")
    lo, hi = 0.0, 2.0
    while _t_central(hi, df) < level:
        hi *= 2.0
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if _t_central(mid, df) < level else (lo, mid)
    return 0.5 * (lo + hi)


def _weights(n: int, w: np.ndarray | None) -> np.ndarray:
    w = np.full(n, 1.0 / n) if w is None else np.asarray(w, dtype=np.float64)
    if w.shape != (n,) or (w < 0).any() or not w.sum() > 0:
        raise ValueError("weights must be (n,) non-negative with a positive sum")
    return w / w.sum()


def _from_influence(theta: float, psi: np.ndarray, level: float) -> Interval | None:
    n = len(psi)
    if n < 2:
        return None
    se = math.sqrt(n / (n - 1) * float(np.sum(psi ** 2)))
    half = t_quantile(n - 1, level) * se
    return (theta - half, theta + half)


def mean_interval(x: np.ndarray, w: np.ndarray | None = None, level: float = LEVEL
                  ) -> tuple[float, Interval | None]:
    """Weighted mean of per-trial values and its Student-t interval (module docstring).

    Args:
        x: (n,) one value per trial.
        w: (n,) weights (default equal); normalized to sum 1.
        level: confidence level.
    Returns:
        (mean, (low, high)), the interval None for one trial.
    """
    x = np.asarray(x, dtype=np.float64)
    w = _weights(len(x), w)
    theta = float(np.sum(w * x))
    return theta, _from_influence(theta, w * (x - theta), level)


def ratio_interval(s: np.ndarray, t: np.ndarray, w: np.ndarray | None = None,
                   level: float = LEVEL) -> tuple[float | None, Interval | None]:
    """Ratio of weighted means over paired trials, ``sum w s / sum w t``, and its
    delta-method interval (module docstring).

    Args:
        s: (n,) numerator per trial (the student's).
        t: (n,) denominator per trial (the teacher's on the same trial).
        w: (n,) weights (default equal).
        level: confidence level.
    Returns:
        (ratio, (low, high)); (None, None) when the denominator's mean is 0.
    """
    s, t = np.asarray(s, dtype=np.float64), np.asarray(t, dtype=np.float64)
    w = _weights(len(s), w)
    den = float(np.sum(w * t))
    if den == 0.0:
        return None, None
    r = float(np.sum(w * s)) / den
    return r, _from_influence(r, w * (s - r * t) / den, level)


def wilson_interval(p: float, n: float, level: float = LEVEL) -> Interval:
    """Wilson score interval of a proportion ``p`` observed over ``n`` (effective) trials.

    Args:
        p: observed proportion in [0, 1].
        n: number of trials (> 0; may be an effective, non-integer count).
        level: confidence level.
    """
    if not n > 0:
        raise ValueError(f"n={n} must be > 0")
    z = NormalDist().inv_cdf(0.5 + level / 2)
    z2n = z * z / n
    center = (p + z2n / 2) / (1 + z2n)
    half = z / (1 + z2n) * math.sqrt(max(p * (1 - p), 0.0) / n + z2n / (4 * n))
    return (max(0.0, center - half), min(1.0, center + half))


def proportion_interval(x: np.ndarray, w: np.ndarray | None = None, level: float = LEVEL
                        ) -> tuple[float, Interval]:
    """Weighted share of successes (x in {0, 1}) and its Wilson interval with the Kish
    effective sample size ``1 / sum w^2``; equal weights (``w`` None): the share k/n over
    n trials, exactly.

    Args:
        x: (n,) 0/1 per trial.
        w: (n,) weights (default equal).
        level: confidence level.
    """
    x = np.asarray(x, dtype=np.float64)
    if w is None and len(x):
        p = float(x.sum()) / len(x)
        return p, wilson_interval(min(max(p, 0.0), 1.0), len(x), level)
    w = _weights(len(x), w)
    p = float(np.sum(w * x))
    return p, wilson_interval(min(max(p, 0.0), 1.0), 1.0 / float(np.sum(w ** 2)), level)
