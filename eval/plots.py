"""PNG plots of a metrics.json written by ``msta-eval`` (msta-compare's and msta-repro's too):
the sweeps of scenarios 2-5 and the train-mask heatmap.

Every point says how many trials stand behind it (``n`` in the title) and carries its 95 %
interval as an error bar (the interval stored in metrics.json, :mod:`msta.eval.intervals`). A
policy that is n/a under every condition of a sweep (the teacher under test-time input
changes) is left out of the plot and its legend; the dashed line at 1 is the teacher, by
which every figure is normalized. Other n/a points are marked "n/a".
"""

from __future__ import annotations

import math
from pathlib import Path

from msta.eval.metrics import RETURNS
from msta.eval.report_cells import (
    METRIC_TITLES,
    conditions,
    lookup,
    norm_cell,
    policy_names,
    scenario_runs,
)
from msta.eval.scenarios import SCENARIOS


def _pyplot():
    import matplotlib  # lazy: matplotlib (~0.5 s) loads only when a picture is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # lazy: matplotlib (~0.5 s) loads only when a picture is drawn

    return plt


def trials_label(metrics: dict, counts: set[int], what: str = "point") -> str:
    """``n = 100 trials per point (20 per terrain)`` for the trial counts of the cells drawn
    (a range when they differ)."""
    if not counts:
        return "no trials"
    low, high = min(counts), max(counts)
    text = f"n = {low} trials per {what}" if low == high else f"n = {low}-{high} trials per {what}"
    per = metrics["reference"]["per_terrain"]
    each = {per[t]["trials"] for t in metrics["terrains"] if t in per}
    if len(metrics["terrains"]) > 1 and each:
        spread = (f"{min(each)}" if len(each) == 1 else f"{min(each)}-{max(each)}")
        text += f" ({spread} per terrain)"
    return text


def _value_and_error(cell: dict | None, metric: str) -> tuple[float, float, float]:
    """(value, error below, error above) of one cell's metric; NaN where there is none."""
    if cell is None or cell.get(metric) is None:
        return math.nan, math.nan, math.nan
    v = float(cell[metric])
    ci = (cell.get("ci") or {}).get(metric)
    if not ci:  # one trial: no interval
        return v, 0.0, 0.0
    return v, max(v - ci[0], 0.0), max(ci[1] - v, 0.0)


def _save(fig, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    _pyplot().close(fig)
    return path


def sweep_figure(metrics: dict, scenario: str, bars: bool):
    """A sweep's matplotlib figure: one subplot per return; x = conditions, one line (or bar
    group) per policy with 95 % error bars.

    Args:
        metrics: metrics.json content.
        scenario: a sweep that was run (sensor_removal, dead_joints, history, dummy_tokens).
        bars: bar groups (categorical conditions) instead of lines.
    """
    plt = _pyplot()
    runs = scenario_runs(metrics, scenario)
    conds = conditions(runs)
    look = lookup(runs)
    cells = {p: [norm_cell(look.get((p, c))) for c, _ in conds] for p in policy_names(metrics)}
    drawn = [p for p, row in cells.items() if any(c is not None for c in row)]
    counts = {c["trials"] for p in drawn for c in cells[p] if c is not None}
    fig, axes = plt.subplots(1, len(RETURNS), figsize=(5 * len(RETURNS), 4.0), squeeze=False)
    x = list(range(len(conds)))
    width = 0.8 / max(len(drawn), 1)
    for ax, metric in zip(axes[0], RETURNS):
        for j, p in enumerate(drawn):
            ys, lo, hi = zip(*(_value_and_error(c, metric) for c in cells[p]))
            if bars:
                xs = [i + (j - (len(drawn) - 1) / 2) * width for i in x]
                ax.bar(xs, ys, width=width, yerr=[lo, hi], capsize=2, label=p,
                       error_kw={"lw": 0.8})
            else:
                xs = x
                ax.errorbar(xs, ys, yerr=[lo, hi], marker="o", capsize=3, label=p)
            for xi, v in zip(xs, ys):
                if math.isnan(v):
                    ax.annotate("n/a", (xi, 0.02), ha="center", fontsize=7, color="gray",
                                xycoords=("data", "axes fraction"), rotation=90)
        ax.axhline(1.0, color="gray", lw=0.8, ls="--", label="teacher (= 1)")
        ax.set_ylim(bottom=0.0)
        ax.set_xticks(x, [str(v) for _, v in conds], rotation=30 if bars else 0)
        ax.set_xlabel(SCENARIOS[scenario].axis)
        ax.set_ylabel("normalized to teacher")
        ax.set_title(METRIC_TITLES[metric])
    axes[0][-1].legend(fontsize=8)
    fig.suptitle(f"{SCENARIOS[scenario].title}: {trials_label(metrics, counts)}, "
                 "error bars 95 % intervals")
    return fig


def heatmap_figure(metrics: dict):
    """The train-mask heatmap's figure (None: no policy has train mask ratios): rows =
    returns, columns = test masks; cells = (stage-1, stage-2) train ratios, each with its
    figure and the half-width of its 95 % interval."""
    plt = _pyplot()
    ratios = {p["name"]: tuple(p["train_masks"]) for p in metrics["policies"]
              if p.get("train_masks")}
    if not ratios:
        return None
    runs = scenario_runs(metrics, "token_removal")
    conds = conditions(runs)
    look = lookup(runs)
    a1s = sorted({a for a, _ in ratios.values()})
    a2s = sorted({b for _, b in ratios.values()})
    counts = {c["trials"] for name in ratios for cond, _ in conds
              if (c := norm_cell(look.get((name, cond)))) is not None}
    fig, axes = plt.subplots(len(RETURNS), len(conds), squeeze=False,
                             figsize=(3.4 * len(conds), 3.0 * len(RETURNS) + 0.4))
    for i, metric in enumerate(RETURNS):
        for j, (cond, _) in enumerate(conds):
            grid = [[(math.nan, math.nan, math.nan)] * len(a2s) for _ in a1s]
            for name, (a1, a2) in ratios.items():
                grid[a1s.index(a1)][a2s.index(a2)] = _value_and_error(
                    norm_cell(look.get((name, cond))), metric)
            ax = axes[i][j]
            im = ax.imshow([[v for v, _, _ in row] for row in grid], cmap="viridis",
                           origin="lower", aspect="auto")
            for r, row in enumerate(grid):
                for c, (v, lo, hi) in enumerate(row):
                    text = "n/a" if math.isnan(v) else f"{v:.2f}\n±{(lo + hi) / 2:.2f}"
                    ax.text(c, r, text, ha="center", va="center", color="w", fontsize=8)
            ax.set_xticks(range(len(a2s)), [f"{a:g}" for a in a2s])
            ax.set_yticks(range(len(a1s)), [f"{a:g}" for a in a1s])
            ax.set_xlabel("stage-2 mask ratio")
            ax.set_ylabel("stage-1 mask ratio")
            ax.set_title(f"{METRIC_TITLES[metric]}, test {cond}", fontsize=9)
            fig.colorbar(im, ax=ax, fraction=0.046)
    fig.suptitle(f"Normalized to the teacher: {trials_label(metrics, counts, 'cell')}, "
                 "± half-width of the 95 % interval")
    return fig


def write_plots(metrics: dict, out: Path) -> list[Path]:
    """PNG plots of scenarios 2-5 that were run; returns the paths written."""
    written = []
    for name, bars in (("sensor_removal", True), ("dead_joints", False), ("history", False),
                       ("dummy_tokens", False)):
        if scenario_runs(metrics, name):
            written.append(_save(sweep_figure(metrics, name, bars), out / f"{name}.png"))
    if "mask_matrix" in metrics["config"]["scenarios"]:
        fig = heatmap_figure(metrics)
        if fig is not None:
            written.append(_save(fig, out / "mask_matrix.png"))
    return written
