"""Markdown tables and PNG plots from a metrics.json written by ``msta-eval``.

    python -m eval.report outputs/eval/metrics.json      # rewrite report.md and the plots

Everything here reads only the metrics dictionary, so reports can be regenerated (or
restyled) without rerunning the simulator. n/a runs stay visible: "n/a" in tables, an
"n/a" mark in plots.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

from eval.metrics import RETURNS

METRIC_TITLES = {"lin_tracking": "linear-velocity tracking", "ang_tracking":
                 "angular-velocity tracking", "total": "total reward"}
SHORT_TERRAIN = {"smooth_slope": "smooth", "rough_slope": "rough", "stairs_up": "stairs up",
                 "stairs_down": "stairs down", "discrete": "discrete", "flat": "flat",
                 "average": "avg"}


def _fmt(v: float | None, digits: int = 2) -> str:
    return "n/a" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.{digits}f}"


def _runs(metrics: dict, scenario: str) -> list[dict]:
    return [r for r in metrics["runs"] if r["scenario"] == scenario]


def _policy_names(metrics: dict) -> list[str]:
    return [p["name"] for p in metrics["policies"]]


def _conditions(runs: list[dict]) -> list[tuple[str, Any]]:
    """(label, value) in first-seen order."""
    seen: dict[str, Any] = {}
    for r in runs:
        seen.setdefault(r["condition"], r["value"])
    return list(seen.items())


def _value(run: dict | None, metric: str, terrain: str = "average") -> float | None:
    if run is None or run["status"] != "ok":
        return None
    per = run["normalized"]["per_terrain"].get(terrain)  # absent: no trial on that terrain
    return None if per is None else per.get(metric)


def _lookup(runs: list[dict]) -> dict[tuple[str, str], dict]:
    return {(r["policy"], r["condition"]): r for r in runs}


def table_one(metrics: dict, metric: str = "total") -> str:
    """The paper's Table I layout: rows policies, columns terrains x test masks.

    Args:
        metrics: metrics.json content.
        metric: lin_tracking, ang_tracking or total (normalized to the teacher).
    """
    runs = _runs(metrics, "token_removal")
    title = f"**{METRIC_TITLES[metric]}, normalized to the teacher** (test masks " \
            f"{', '.join(c for c, _ in _conditions(runs))})"
    if not runs:
        return f"{title}: the token_removal scenario was not run."
    conds = _conditions(runs)
    look = _lookup(runs)
    terrains = metrics["terrains"] + ["average"]
    head = ["policy"] + [f"{SHORT_TERRAIN.get(t, t)} {c.split()[-1]}"
                         for t in terrains for c, _ in conds]
    lines = [title, "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for p in _policy_names(metrics):
        cells = [_fmt(_value(look.get((p, c)), metric, t)) for t in terrains for c, _ in conds]
        lines.append(f"| {p} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def scenario_table(metrics: dict, scenario: str, metric: str = "total") -> str:
    """Rows policies, columns the scenario's conditions; terrain-averaged normalized metric."""
    runs = _runs(metrics, scenario)
    conds = _conditions(runs)
    look = _lookup(runs)
    head = ["policy"] + [c for c, _ in conds]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for p in _policy_names(metrics):
        lines.append(f"| {p} | " + " | ".join(_fmt(_value(look.get((p, c)), metric))
                                               for c, _ in conds) + " |")
    return "\n".join(lines)


def _baseline_runs(metrics: dict) -> dict[str, dict]:
    """Each policy's first successful run with no input change (spec all defaults)."""
    out: dict[str, dict] = {}
    for r in metrics["runs"]:
        s = r["spec"]
        plain = s["T"] is None and not s["drop_sensors"] and not s["dead_joints"] \
            and s["mask_ratio"] == 0
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
        (p, base[p]["raw"]) for p in _policy_names(metrics) if p in base]
    for name, agg in rows:
        cells = []
        for t in terrains:
            v = agg["per_terrain"].get(t)  # absent: no trial on that terrain
            cells += ([_fmt(v["survival"]), _fmt(v["vel_err"]), _fmt(v["yaw_err"])] if v
                      else [_fmt(None)] * 3)
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def level_table(metrics: dict, metric: str = "total") -> str:
    """Normalized metric per level (mean over terrains), no input changes."""
    base = _baseline_runs(metrics)
    levels = [str(lv) for lv in metrics["levels"]]
    lines = ["| policy | " + " | ".join(f"level {lv}" for lv in levels) + " |",
             "|" + "---|" * (len(levels) + 1)]
    for p in _policy_names(metrics):
        if p not in base:
            continue
        per = base[p]["normalized"]["per_level"]
        cells = []
        for lv in levels:
            vals = [per[t][lv][metric] for t in per if lv in per[t]]
            ok = vals and all(v is not None for v in vals)
            cells.append(_fmt(sum(vals) / len(vals) if ok else None))
        lines.append(f"| {p} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def markdown(metrics: dict) -> str:
    """The whole report.md."""
    from eval.scenarios import SCENARIOS

    cfg = metrics["config"]
    intro = (f"{cfg['trials']} trials per policy and condition over "
             f"{', '.join(cfg['terrains'])} at levels {', '.join(map(str, cfg['levels']))}; "
             f"{cfg['episode_s']:g} s episodes; seed {cfg['seed']}; reference teacher "
             f"`{cfg['teacher']['type']}` ({metrics['reference']['revision']}). Returns are "
             "per-step means normalized by the teacher's on identical trials; see docs/eval.md.")
    parts = [f"# msta-eval report ({cfg['suite']} suite)", "", intro, ""]
    parts += ["## Policies", "", "| name | kind | source | revision |", "|---|---|---|---|"]
    parts += [f"| {p['name']} | {p['kind']} | `{p['source']}` | {p['revision']} |"
              for p in metrics["policies"]]
    parts.append("")
    if _runs(metrics, "token_removal"):
        parts += ["## Table I: random token removal at test time", ""]
        parts += [table_one(metrics, m) + "\n" for m in ("total", "lin_tracking", "ang_tracking")]
    parts += ["## Survival and velocity errors (no input changes)", "", raw_table(metrics), ""]
    if len(metrics["levels"]) > 1:
        parts += ["## Total reward per level (normalized, mean over terrains)", "",
                  level_table(metrics), ""]
    for name in ("sensor_removal", "dead_joints", "history"):
        if not _runs(metrics, name):
            continue
        parts += [f"## {SCENARIOS[name].title}", "", f"![{name}]({name}.png)", ""]
        for m in RETURNS:
            parts += [f"{METRIC_TITLES[m]} (normalized, mean over terrains):", "",
                      scenario_table(metrics, name, m), ""]
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


# ----------------------------------------------------------------------------- plots
def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _sweep_plot(metrics: dict, scenario: str, path: Path, bars: bool) -> Path:
    """One subplot per return; x = conditions, one line (or bar group) per policy."""
    from eval.scenarios import SCENARIOS

    plt = _pyplot()
    runs = _runs(metrics, scenario)
    conds = _conditions(runs)
    look = _lookup(runs)
    names = _policy_names(metrics)
    fig, axes = plt.subplots(1, len(RETURNS), figsize=(5 * len(RETURNS), 3.8), squeeze=False)
    x = list(range(len(conds)))
    width = 0.8 / max(len(names), 1)
    for ax, metric in zip(axes[0], RETURNS):
        for j, p in enumerate(names):
            vals = [_value(look.get((p, c)), metric) for c, _ in conds]
            ys = [math.nan if v is None else v for v in vals]
            if bars:
                xs = [i + (j - (len(names) - 1) / 2) * width for i in x]
                ax.bar(xs, ys, width=width, label=p)
            else:
                xs = x
                ax.plot(xs, ys, marker="o", label=p)
            for xi, v in zip(xs, vals):
                if v is None:
                    ax.annotate("n/a", (xi, 0.02), ha="center", fontsize=7, color="gray",
                                xycoords=("data", "axes fraction"), rotation=90)
        ax.axhline(1.0, color="gray", lw=0.8, ls="--")
        ax.set_ylim(bottom=0.0)
        ax.set_xticks(x, [str(v) for _, v in conds], rotation=30 if bars else 0)
        ax.set_xlabel(SCENARIOS[scenario].axis)
        ax.set_ylabel("normalized to teacher")
        ax.set_title(METRIC_TITLES[metric])
    axes[0][-1].legend(fontsize=8)
    fig.suptitle(SCENARIOS[scenario].title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _heatmap_plot(metrics: dict, path: Path) -> Path | None:
    """Rows = returns, columns = test masks; cells = (stage-1, stage-2) train ratios."""
    plt = _pyplot()
    ratios = {p["name"]: tuple(p["train_masks"]) for p in metrics["policies"]
              if p.get("train_masks")}
    if not ratios:
        return None
    runs = _runs(metrics, "token_removal")
    conds = _conditions(runs)
    look = _lookup(runs)
    a1s = sorted({a for a, _ in ratios.values()})
    a2s = sorted({b for _, b in ratios.values()})
    fig, axes = plt.subplots(len(RETURNS), len(conds), squeeze=False,
                             figsize=(3.4 * len(conds), 3.0 * len(RETURNS)))
    for i, metric in enumerate(RETURNS):
        for j, (cond, _) in enumerate(conds):
            grid = [[math.nan] * len(a2s) for _ in a1s]
            for name, (a1, a2) in ratios.items():
                v = _value(look.get((name, cond)), metric)
                grid[a1s.index(a1)][a2s.index(a2)] = math.nan if v is None else v
            ax = axes[i][j]
            im = ax.imshow(grid, cmap="viridis", origin="lower", aspect="auto")
            for r, row in enumerate(grid):
                for c, v in enumerate(row):
                    ax.text(c, r, "n/a" if math.isnan(v) else f"{v:.2f}", ha="center",
                            va="center", color="w", fontsize=8)
            ax.set_xticks(range(len(a2s)), [f"{a:g}" for a in a2s])
            ax.set_yticks(range(len(a1s)), [f"{a:g}" for a in a1s])
            ax.set_xlabel("stage-2 mask ratio")
            ax.set_ylabel("stage-1 mask ratio")
            ax.set_title(f"{METRIC_TITLES[metric]}, test {cond}", fontsize=9)
            fig.colorbar(im, ax=ax, fraction=0.046)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def write_plots(metrics: dict, out: Path) -> list[Path]:
    """PNG plots of scenarios 2-5 that were run; returns the paths written."""
    written = []
    for name, bars in (("sensor_removal", True), ("dead_joints", False), ("history", False)):
        if _runs(metrics, name):
            written.append(_sweep_plot(metrics, name, out / f"{name}.png", bars))
    if "mask_matrix" in metrics["config"]["scenarios"]:
        p = _heatmap_plot(metrics, out / "mask_matrix.png")
        if p is not None:
            written.append(p)
    return written


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description="Rewrite report.md and plots from a metrics.json.")
    p.add_argument("metrics", type=Path)
    p.add_argument("--out", type=Path, default=None, help="default: the metrics file's folder")
    args = p.parse_args(argv)
    metrics = json.loads(args.metrics.read_text())
    for f in write_report(metrics, args.out or args.metrics.parent):
        print(f)


if __name__ == "__main__":
    main()
