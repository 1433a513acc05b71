"""Markdown tables and PNG plots from a metrics.json written by ``msta-eval``.

    python -m msta.eval.report outputs/eval/metrics.json      # rewrite report.md and the plots
    python -m msta.eval.report outputs/eval/metrics.json --output_dir=outputs/eval_restyled

Everything here reads only the metrics dictionary, so reports can be regenerated (or
restyled) without rerunning the simulator. n/a runs stay visible: "n/a" in tables, an
"n/a" mark in plots.

Every table cell shows its figure with the 95 % confidence interval stored in metrics.json
(:mod:`msta.eval.intervals`: ``±`` half-width of a Student-t / delta-method interval, or
``(low–high)`` Wilson bounds for survival), and every table ends with a *trials per cell*
row; the header says how the trials spread over terrain cells. A student whose figures are
identical (to 4 significant digits, every cell) across conditions that change its inputs
(test masks, removed sensors, ...) gets a warning line (:func:`identical_warnings`), also
printed by msta-eval.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from msta.data.cli import parse_config
from msta.data.hub_eval import read_json_input
from msta.eval.fault_report import section
from msta.eval.metrics import RETURNS
from msta.eval.plots import write_plots
from msta.eval.report_cells import (
    METRIC_TITLES,
    SHORT_TERRAIN,
    conditions,
    fmt_cell,
    lookup,
    norm_cell,
    policy_names,
    scenario_runs,
)
from msta.eval.scenarios import SCENARIOS


def trials_note(metrics: dict) -> str:
    """How many trials stand behind each cell (the header of report.md)."""
    cfg, per = metrics["config"], metrics["reference"]["per_terrain"]
    counts = {t: per[t]["trials"] for t in metrics["terrains"] if t in per}
    low, high = min(counts.values()), max(counts.values())
    each = f"{low}" if low == high else f"{low}-{high}"
    text = (f"{cfg['trials']} trials per policy and condition, spread over {len(counts)} "
            f"terrain(s) x {len(metrics['levels'])} level(s): **{each} trial(s) per terrain "
            f"cell**")
    if low != high:
        text += " (" + ", ".join(f"{SHORT_TERRAIN.get(t, t)} {n}" for t, n in counts.items()) + ")"
    missing = [t for t in metrics["terrains"] if t not in counts]
    if missing:
        text += f"; no trial on {', '.join(missing)}"
    return text + f", {per['average']['trials']} in the average"


CI_NOTE = ("Each figure is the mean over its cell's trials with a 95 % confidence interval: "
           "`± half-width` (Student t over trials; for ratios to the teacher the delta method "
           "on the paired trials) or `(low–high)` for survival (Wilson); a cell with one trial "
           "has no interval. Cells mixing terrains (avg) count the spread between terrains as "
           "noise, so their intervals are conservative (eval/intervals.py).")


#: Figures closer than this (relative) count as identical in :func:`identical_groups`.
IDENTICAL_RTOL = 1e-4


def _figures(run: dict) -> np.ndarray:
    """Every number of a run's raw figures (all cells, metrics and bounds), in key order."""
    out: list[float] = []

    def walk(x: Any) -> None:
        if isinstance(x, dict):
            for k in sorted(x):
                walk(x[k])
        elif isinstance(x, (list, tuple)):
            for v in x:
                walk(v)
        elif isinstance(x, (int, float)):
            out.append(float(x))
        else:  # None: no interval
            out.append(math.nan)

    walk(run["raw"])
    return np.asarray(out)


def identical_groups(runs: list[dict]) -> list[list[str]]:
    """Condition labels whose figures are identical although the inputs differ.

    "Identical": every raw figure of every cell (per terrain and per level, intervals
    included) agrees to a relative :data:`IDENTICAL_RTOL`; a student whose actions change
    with its inputs drives the robots elsewhere and changes them far more.

    Args:
        runs: run records of one policy and scenario (metrics.json ``runs`` entries or
            msta-correct's per-mask records).
    Returns:
        one list of labels per group of >= 2 identical runs over >= 2 different inputs
        (``inputs`` digest, else the spec).
    """
    groups: list[tuple[np.ndarray, list[dict]]] = []
    for r in runs:
        if r.get("status") != "ok":
            continue
        x = _figures(r)
        for ref, members in groups:
            if ref.shape == x.shape and np.allclose(x, ref, rtol=IDENTICAL_RTOL, atol=1e-12,
                                                    equal_nan=True):
                members.append(r)
                break
        else:
            groups.append((x, [r]))
    return [[r["condition"] for r in rs] for _, rs in groups
            if len({r.get("inputs") or json.dumps(r["spec"], sort_keys=True) for r in rs}) > 1]


def identical_line(policy: str, what: str, labels: list[str]) -> str:
    """The warning for :func:`identical_groups`."""
    return (f"{policy}: the student's figures are identical across {what} "
            f"{', '.join(labels)}: it may ignore its inputs")


def identical_warnings(metrics: dict) -> list[str]:
    """One warning per student and scenario whose figures do not change across conditions
    that change its inputs (e.g. test masks 0/25/50 %, or removing different sensors)."""
    kinds = {p["name"]: p["kind"] for p in metrics["policies"]}
    groups: dict[tuple[str, str], list[dict]] = {}
    # oracle runs on one target are identical by design, and a guard that removed nothing
    # gives the unguarded figures (its removal columns say so)
    for r in metrics["runs"]:
        if kinds.get(r["policy"]) == "student" and r.get("removal") not in ("oracle", "guard"):
            groups.setdefault((r["policy"], r["scenario"]), []).append(r)
    return [identical_line(policy, f"{scenario} conditions", labels)
            for (policy, scenario), runs in groups.items()
            for labels in identical_groups(runs)]


def _trials_row(label: str, counts: list[int | None]) -> str:
    return f"| *{label}* | " + " | ".join("-" if n is None else str(n) for n in counts) + " |"


def _ref_trials(metrics: dict, terrain: str) -> int | None:
    cell = metrics["reference"]["per_terrain"].get(terrain)
    return None if cell is None else cell.get("trials")


def table_one(metrics: dict, metric: str = "total") -> str:
    """The paper's Table I layout: rows policies, columns terrains x test masks.

    Args:
        metrics: metrics.json content.
        metric: lin_tracking, ang_tracking or total (normalized to the teacher).
    """
    runs = scenario_runs(metrics, "token_removal")
    title = f"**{METRIC_TITLES[metric]}, normalized to the teacher** (test masks " \
            f"{', '.join(c for c, _ in conditions(runs))})"
    if not runs:
        return f"{title}: the token_removal scenario was not run."
    conds = conditions(runs)
    look = lookup(runs)
    terrains = metrics["terrains"] + ["average"]
    head = ["policy"] + [f"{SHORT_TERRAIN.get(t, t)} {c.split()[-1]}"
                         for t in terrains for c, _ in conds]
    lines = [title, "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for p in policy_names(metrics):
        cells = [fmt_cell(norm_cell(look.get((p, c)), t), metric)
                 for t in terrains for c, _ in conds]
        lines.append(f"| {p} | " + " | ".join(cells) + " |")
    lines.append(_trials_row("trials per cell", [_ref_trials(metrics, t) for t in terrains
                                                 for _ in conds]))
    return "\n".join(lines)


def scenario_table(metrics: dict, scenario: str, metric: str = "total") -> str:
    """Rows policies, columns the scenario's conditions; terrain-averaged normalized metric."""
    runs = scenario_runs(metrics, scenario)
    conds = conditions(runs)
    look = lookup(runs)
    head = ["policy"] + [c for c, _ in conds]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for p in policy_names(metrics):
        lines.append(f"| {p} | " + " | ".join(fmt_cell(norm_cell(look.get((p, c))), metric)
                                               for c, _ in conds) + " |")
    lines.append(_trials_row("trials per cell", [_ref_trials(metrics, "average")] * len(conds)))
    return "\n".join(lines)


def spec_history(spec: dict) -> int | None:
    """The window of a run's ``spec`` (``history``; ``T`` in metrics.json files written
    before it was named so)."""
    return spec["history"] if "history" in spec else spec["T"]


def _baseline_runs(metrics: dict) -> dict[str, dict]:
    """Each policy's first successful run with no input change (spec all defaults)."""
    out: dict[str, dict] = {}
    for r in metrics["runs"]:
        s = r["spec"]
        plain = spec_history(s) is None and not s["drop_sensors"] and not s["dead_joints"] \
            and s["mask_ratio"] == 0 and not s.get("dummy_tokens") and not r.get("fault") \
            and r.get("removal") in (None, "unguarded")
        if plain and r["status"] == "ok":
            out.setdefault(r["policy"], r)
    return out


def raw_table(metrics: dict) -> str:
    """Survival and velocity errors per terrain (no input changes), with the teacher's."""
    base = _baseline_runs(metrics)
    terrains = metrics["terrains"] + ["average"]
    head = ["policy"] + [f"{SHORT_TERRAIN.get(t, t)} {k}" for t in terrains
                         for k in ("surv", "|v-cmd|", "|w-cmd|")]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    rows = [("reference teacher", metrics["reference"])] + [
        (p, base[p]["raw"]) for p in policy_names(metrics) if p in base]
    for name, agg in rows:
        cells = []
        for t in terrains:
            v = agg["per_terrain"].get(t)  # absent: no trial on that terrain
            cells += [fmt_cell(v, k) for k in ("survival", "vel_err", "yaw_err")]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    lines.append(_trials_row("trials per cell", [_ref_trials(metrics, t) for t in terrains
                                                 for _ in range(3)]))
    return "\n".join(lines)


def level_table(metrics: dict, metric: str = "total") -> str:
    """Normalized metric per level, no input changes: the student's terrain-averaged
    return at that level over the teacher's (as the avg column of the other tables)."""
    base = _baseline_runs(metrics)
    levels = [str(lv) for lv in metrics["levels"]]
    lines = ["| policy | " + " | ".join(f"level {lv}" for lv in levels) + " |",
             "|" + "---|" * (len(levels) + 1)]
    for p in policy_names(metrics):
        if p not in base:
            continue
        per = base[p]["normalized"]["per_level"]["average"]
        lines.append(f"| {p} | " + " | ".join(fmt_cell(per.get(lv), metric) for lv in levels)
                     + " |")
    ref = metrics["reference"]["per_level"]["average"]
    lines.append(_trials_row("trials per cell", [ref[lv]["trials"] if lv in ref else None
                                                 for lv in levels]))
    return "\n".join(lines)


def markdown(metrics: dict) -> str:
    """The whole report.md."""
    cfg = metrics["config"]
    episode = cfg.get("episode_length_s", cfg.get("episode_s", 0))  # files before the rename
    intro = (f"{trials_note(metrics)} (terrains {', '.join(cfg['terrains'])}; levels "
             f"{', '.join(map(str, cfg['levels']))}; one trial = one {episode:g} s "
             f"episode); seed {cfg['seed']}; reference teacher `{cfg['teacher']['type']}` "
             f"({metrics['reference']['revision']}). Returns are per-step means normalized by "
             "the teacher's on identical trials; see docs/eval.md.")
    parts = [f"# msta-eval report ({cfg['suite']} suite)", "", intro, "", CI_NOTE, ""]
    parts += [f"> **Warning**: {w}\n" for w in identical_warnings(metrics)]
    parts += ["## Policies", "", "| name | kind | source | revision |", "|---|---|---|---|"]
    parts += [f"| {p['name']} | {p['kind']} | `{p['source']}` | {p['revision']} |"
              for p in metrics["policies"]]
    parts.append("")
    if scenario_runs(metrics, "token_removal"):
        parts += ["## Table I: random token removal at test time", ""]
        parts += [table_one(metrics, m) + "\n" for m in ("total", "lin_tracking", "ang_tracking")]
    parts += ["## Survival and velocity errors (no input changes)", "", raw_table(metrics), ""]
    if len(metrics["levels"]) > 1:
        parts += ["## Total reward per level (normalized, terrain average)", "",
                  level_table(metrics), ""]
    for name in ("sensor_removal", "dead_joints", "history", "dummy_tokens"):
        if not scenario_runs(metrics, name):
            continue
        parts += [f"## {SCENARIOS[name].title}", "", f"![{name}]({name}.png)", ""]
        for m in RETURNS:
            parts += [f"{METRIC_TITLES[m]} (normalized, mean over terrains):", "",
                      scenario_table(metrics, name, m), ""]
    if scenario_runs(metrics, "sensor_faults"):
        parts += [section(metrics)]
    if "mask_matrix" in cfg["scenarios"]:
        parts += ["## Train mask ratios (stage 1 x stage 2)", ""]
        if any(p.get("train_masks") for p in metrics["policies"]):
            parts += ["![mask matrix](mask_matrix.png)", ""]
        else:
            parts += ["No evaluated checkpoint has train mask ratios (pass --matrix).", ""]
    na = [r for r in metrics["runs"] if r["status"] != "ok"]
    if na:
        parts += ["## Not applicable", "", "| policy | condition | reason |", "|---|---|---|"]
        parts += [f"| {r['policy']} | {r['scenario']}/{r['condition']} | {r['reason']} |"
                  for r in na]
    return "\n".join(parts) + "\n"


def write_report(metrics: dict, out: str | Path) -> list[Path]:
    """Write report.md and every plot into ``out``; returns the paths written.

    Args:
        metrics: metrics.json content.
        out: output directory.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "report.md"
    path.write_text(markdown(metrics))
    return [path] + write_plots(metrics, out)


@dataclass
class EvalReportConfig:
    """``python -m msta.eval.report``: rewrite report.md and the plots from a metrics.json.

    Args:
        metrics: a metrics.json written by msta-eval (also the first bare word).
        output_dir: folder for report.md and the plots (empty: the metrics file's folder).
    """

    metrics: str = ""
    output_dir: str = ""

    def __post_init__(self) -> None:
        if not self.metrics:
            raise ValueError("give the metrics.json to report on (--metrics=PATH or a bare PATH)")
        if not Path(self.metrics).is_file():
            raise FileNotFoundError(f"--metrics {self.metrics!r}: no such file")


#: The largest metrics.json read (a full study's is a few MB).
MAX_METRICS_BYTES = 256 << 20


def main(argv: list[str] | None = None) -> None:
    """Rewrite report.md and the plots (``python -m msta.eval.report METRICS [--output_dir=DIR]``)."""
    cfg = parse_config(EvalReportConfig, argv, "python -m msta.eval.report", positionals=("metrics",))
    path = Path(cfg.metrics)
    try:
        metrics = read_json_input(path, "METRICS", max_bytes=MAX_METRICS_BYTES)
        files = write_report(metrics, Path(cfg.output_dir) if cfg.output_dir else path.parent)
    except (KeyError, TypeError, ValueError, AttributeError) as e:  # ValueError: unreadable
        raise SystemExit(f"python -m msta.eval.report: error: {path}: not a metrics.json of "
                         f"msta-eval ({' '.join(str(e).split())[:160]})") from None
    for f in files:
        print(f)
    for line in identical_warnings(metrics):
        print(f"warning: {line}")

if __name__ == "__main__":
    main()
