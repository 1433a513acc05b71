"""msta-eval's plots (msta-compare's and msta-repro's too) on real metrics.json files from
docs/reference: every figure says how many trials stand behind a point and draws its 95 %
interval; the legend lists only what is drawn."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from msta.eval.metrics import RETURNS
from msta.eval.plots import heatmap_figure, sweep_figure, write_plots

REFERENCE = Path(__file__).resolve().parents[2] / "docs" / "reference"


def _metrics(name: str) -> dict:
    return json.loads((REFERENCE / name / "metrics.json").read_text())


def _legend(ax) -> list[str]:
    return [t.get_text() for t in ax.get_legend().get_texts()]


def test_history_plot_draws_what_its_legend_lists_with_n_and_intervals():
    metrics = _metrics("msta")
    fig = sweep_figure(metrics, "history", bars=False)
    title = fig._suptitle.get_text()
    assert "n = 100 trials per point (20 per terrain)" in title and "95 % intervals" in title
    axes = fig.axes
    # the teacher is n/a under every window: no teacher line, only its reference at 1
    assert _legend(axes[-1]) == ["teacher (= 1)", "msta"]
    runs = {r["condition"]: r for r in metrics["runs"]
            if r["policy"] == "msta" and r["scenario"] == "history"}
    for ax, metric in zip(axes[:len(RETURNS)], RETURNS):
        drawn = next(c for c in ax.containers if c.get_label() == "msta")
        line, _, (bars,) = drawn.lines
        ys = np.asarray(line.get_ydata(), dtype=float)
        # each point is its run's figure, its error bar spans the run's 95 % interval
        for y, seg, (cond, run) in zip(ys, bars.get_segments(), runs.items(), strict=True):
            cell = run["normalized"]["per_terrain"]["average"]
            assert y == pytest.approx(cell[metric]), cond
            assert sorted(seg[:, 1]) == pytest.approx(cell["ci"][metric]), cond
    fig.clf()


def test_sensor_removal_keeps_the_teachers_one_bar_and_marks_its_na():
    fig = sweep_figure(_metrics("msta"), "sensor_removal", bars=True)
    ax = fig.axes[0]
    assert _legend(fig.axes[2]) == ["teacher (= 1)", "teacher", "msta"]
    from matplotlib.container import BarContainer

    bars = [c for c in ax.containers if isinstance(c, BarContainer)]
    assert [c.get_label() for c in bars] == ["teacher", "msta"]
    teacher = [p.get_height() for p in bars[0].patches]
    assert teacher[0] == pytest.approx(1.0) and all(math.isnan(h) for h in teacher[1:])
    assert sum(t.get_text() == "n/a" for t in ax.texts) == len(teacher) - 1
    fig.clf()


def test_heatmap_cells_carry_their_interval_and_the_title_n(tmp_path):
    metrics = _metrics("heatmap")
    fig = heatmap_figure(metrics)
    assert "n = 100 trials per cell (20 per terrain)" in fig._suptitle.get_text()
    texts = [t.get_text() for t in fig.axes[0].texts]
    assert len(texts) == 4 and all("\n±0.0" in t for t in texts)
    fig.clf()
    written = write_plots(metrics, tmp_path)
    assert [p.name for p in written] == ["mask_matrix.png"] and written[0].stat().st_size > 10_000
