"""Reading a metrics.json for tables and plots: its runs per scenario, their policies and
conditions, the normalized cell of one run, and one cell formatted with its interval. The
report (:mod:`msta.eval.report`), the plots and the fault section read runs through here.
"""

from __future__ import annotations

from typing import Any

from msta.data.figures import fmt_ci

METRIC_TITLES = {"lin_tracking": "linear-velocity tracking", "ang_tracking":
                 "angular-velocity tracking", "total": "total reward"}


SHORT_TERRAIN = {"smooth_slope": "smooth", "rough_slope": "rough", "stairs_up": "stairs up",
                 "stairs_down": "stairs down", "discrete": "discrete", "flat": "flat",
                 "average": "avg"}


def fmt_cell(cell: dict | None, metric: str, digits: int = 2) -> str:
    """One figure of an msta.eval.metrics cell (``{metric: value, "ci": {metric: [lo, hi]}}``)
    with its interval."""
    if cell is None:
        return "n/a"
    return fmt_ci(cell.get(metric), (cell.get("ci") or {}).get(metric), digits)


def scenario_runs(metrics: dict, scenario: str) -> list[dict]:
    return [r for r in metrics["runs"] if r["scenario"] == scenario]


def policy_names(metrics: dict) -> list[str]:
    return [p["name"] for p in metrics["policies"]]


def conditions(runs: list[dict]) -> list[tuple[str, Any]]:
    """(label, value) in first-seen order."""
    seen: dict[str, Any] = {}
    for r in runs:
        seen.setdefault(r["condition"], r["value"])
    return list(seen.items())


def norm_cell(run: dict | None, terrain: str = "average") -> dict | None:
    if run is None or run["status"] != "ok":
        return None
    return run["normalized"]["per_terrain"].get(terrain)  # absent: no trial on that terrain


def lookup(runs: list[dict]) -> dict[tuple[str, str], dict]:
    return {(r["policy"], r["condition"]): r for r in runs}
