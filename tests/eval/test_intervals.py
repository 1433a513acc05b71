"""95 % confidence intervals (msta.eval.intervals) on distributions whose answer is known."""

from __future__ import annotations

import numpy as np
import pytest

from msta.eval.intervals import (
    mean_interval,
    proportion_interval,
    ratio_interval,
    t_quantile,
    wilson_interval,
)

REPEATS = 2000


def test_t_quantile_matches_the_tables():
    table = {1: 12.7062, 2: 4.3027, 4: 2.7764, 9: 2.2622, 30: 2.0423, 1000: 1.9623}
    for df, q in table.items():
        assert t_quantile(df) == pytest.approx(q, abs=2e-4), df
    assert t_quantile(4, 0.90) == pytest.approx(2.1318, abs=2e-4)


@pytest.mark.parametrize("n", [3, 8, 50])
def test_mean_interval_covers_the_true_mean_95_percent_of_the_time(n):
    rng = np.random.default_rng(n)
    mu, sigma = 3.0, 2.0
    hits = 0
    for _ in range(REPEATS):
        x = rng.normal(mu, sigma, n)
        mean, (lo, hi) = mean_interval(x)
        assert mean == pytest.approx(x.mean())
        hits += lo <= mu <= hi
    assert 0.935 <= hits / REPEATS <= 0.965, hits / REPEATS


def test_mean_interval_width_shrinks_like_one_over_sqrt_n():
    rng = np.random.default_rng(1)
    widths = {}
    for n in (100, 400, 1600):
        w = [np.subtract(*mean_interval(rng.normal(0.0, 1.0, n))[1][::-1])
             for _ in range(200)]
        widths[n] = float(np.mean(w))
    assert widths[100] / widths[400] == pytest.approx(2.0, rel=0.05)
    assert widths[400] / widths[1600] == pytest.approx(2.0, rel=0.05)
    assert widths[1600] == pytest.approx(2 * 1.96 / 40, rel=0.05)  # 2 z sigma / sqrt(n)


def test_ratio_interval_on_paired_trials_covers_the_true_ratio():
    """Student return = 0.7 x teacher return + noise on the same trial: true ratio 0.7."""
    rng = np.random.default_rng(2)
    hits, paired, unpaired = 0, [], []
    for _ in range(REPEATS):
        t = rng.normal(2.0, 0.5, 40)
        s = 0.7 * t + rng.normal(0.0, 0.2, 40)
        r, (lo, hi) = ratio_interval(s, t)
        assert r == pytest.approx(s.mean() / t.mean())
        hits += lo <= 0.7 <= hi
        paired.append(hi - lo)
        # the delta method as if student and teacher trials were independent
        unpaired.append(2 * 1.96 * np.sqrt((s.var() + r * r * t.var()) / 40) / t.mean())
    assert 0.935 <= hits / REPEATS <= 0.965, hits / REPEATS
    assert np.mean(paired) < 0.5 * np.mean(unpaired)  # pairing removes the shared trial noise


def test_wilson_covers_a_proportion_and_stays_in_bounds():
    rng = np.random.default_rng(3)
    hits = 0
    for _ in range(REPEATS):
        x = (rng.random(30) < 0.8).astype(float)
        _, (lo, hi) = proportion_interval(x)
        hits += lo <= 0.8 <= hi
    assert 0.92 <= hits / REPEATS <= 0.98, hits / REPEATS
    assert wilson_interval(1.0, 1)[1] == 1.0 and 0.0 < wilson_interval(1.0, 1)[0] < 0.5
    assert wilson_interval(0.0, 5)[0] == 0.0
    assert wilson_interval(0.5, 10) == pytest.approx((0.2366, 0.7634), abs=1e-4)


def test_one_trial_has_no_interval_and_a_zero_teacher_no_ratio():
    assert mean_interval(np.array([0.4]))[1] is None
    assert ratio_interval(np.array([0.4]), np.array([0.5]))[1] is None
    assert ratio_interval(np.array([0.4, 0.1]), np.zeros(2)) == (None, None)
    _, (lo, hi) = mean_interval(np.array([0.3, 0.3, 0.3]))
    assert lo == hi == pytest.approx(0.3)


def test_weights_give_the_stratified_mean():
    """Two terrains of 1 and 3 trials, each weighing 1/2."""
    x = np.array([1.0, 0.0, 0.0, 0.0])
    w = np.array([0.5, 0.5 / 3, 0.5 / 3, 0.5 / 3])
    mean, (lo, hi) = mean_interval(x, w)
    assert mean == pytest.approx(0.5) and lo < 0.5 < hi
    p, _ = proportion_interval(x, w)
    assert p == pytest.approx(0.5)
