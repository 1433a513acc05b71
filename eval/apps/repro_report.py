"""msta-repro's report: every table with the paper's value beside ours, the minimums of the
reference study and the paper's qualitative findings, each checked with the numbers.

All figures are msta-eval's (normalized to the teacher on the same trials, survival raw),
read from the evaluations' run records; nothing here is tuned or re-measured.
"""

from __future__ import annotations

import datetime
from pathlib import Path
from typing import Any

from msta.data.figures import fmt as _fmt
from msta.eval.apps.compare import paper_table
from msta.eval.metrics import headline
from msta.eval.report import table_one
from msta.eval.report_cells import fmt_cell
from msta.train.config import STAGE2_ROLLOUT_MASK_RATIOS

#: (figure name in msta.eval.metrics.headline, column title)
FIGURES = (("lin_tracking_vs_teacher", "lin. tracking vs teacher"), ("survival", "survival"),
           ("total_vs_teacher", "total vs teacher"))
#: sensors the paper found individually redundant, and the critical ones
REDUNDANT, CRITICAL = ("joint_vel", "foot_contact", "ang_vel", "last_action"), \
    ("joint_pos", "gravity")
#: the "within 5 %" of the paper's findings
TOLERANCE = 0.05


def cell(metrics: dict | None, policy: str, condition: str) -> dict | None:
    """The average headline cell of ``policy`` under ``condition`` (None: absent / n/a)."""
    for run in (metrics or {}).get("runs", []):
        if run["policy"] == policy and run["condition"] == condition and run["status"] == "ok":
            return headline(run)["average"]
    return None


def value(c: dict | None, figure: str) -> float | None:
    return None if c is None else c.get(figure)


def verdict(ok: bool | None) -> str:
    return "n/a" if ok is None else ("**met**" if ok else "**not met**")


def minimums(table1: dict) -> list[str]:
    """The reference study's minimums, with their figures."""
    m50, g50 = cell(table1, "msta", "mask 50%"), cell(table1, "gru", "mask 50%")
    lin, surv = value(m50, "lin_tracking_vs_teacher"), value(m50, "survival")
    ok1 = None if lin is None or surv is None else (lin >= 0.90 and surv >= 0.90)
    mt, gt = value(m50, "total_vs_teacher"), value(g50, "total_vs_teacher")
    ok2 = None if mt is None or gt is None else gt < mt
    return [
        f"- MSTA at 50 % test mask: linear tracking {fmt_cell(m50, 'lin_tracking_vs_teacher')} "
        f"(>= 0.90), survival {fmt_cell(m50, 'survival')} (>= 0.90): {verdict(ok1)}",
        f"- GRU below MSTA at 50 % test mask (total reward vs teacher): GRU "
        f"{fmt_cell(g50, 'total_vs_teacher')}, MSTA {fmt_cell(m50, 'total_vs_teacher')}: "
        f"{verdict(ok2)}"]


def finding_heatmap(heat: dict | None) -> str:
    """(a) the stage-2 training mask matters more than stage 1's: the mean spread over one
    axis with the other fixed, of total reward vs teacher at test mask 50 %."""
    if not heat:
        return "(a) stage-2 mask vs stage-1 mask: n/a (no heatmap)"
    grid = {tuple(p["train_masks"]): p["name"] for p in heat["policies"] if p.get("train_masks")}
    val = {k: value(cell(heat, n, "mask 50%"), "total_vs_teacher") for k, n in grid.items()}
    a1s, a2s = sorted({a for a, _ in grid}), sorted({b for _, b in grid})

    def spread(groups: list[list[float | None]]) -> float | None:
        s = [max(g) - min(g) for g in ([v for v in g if v is not None] for g in groups)
             if len(g) > 1]
        return sum(s) / len(s) if s else None

    s2 = spread([[val.get((a, b)) for b in a2s] for a in a1s])
    s1 = spread([[val.get((a, b)) for a in a1s] for b in a2s])
    cells = ", ".join(f"({a:g}, {b:g}) {_fmt(v)}" for (a, b), v in sorted(val.items()))
    ok = None if s1 is None or s2 is None else s2 > s1
    return (f"(a) the stage-2 mask matters more than stage 1's: {verdict(ok)}: mean spread "
            f"over stage-2 masks {_fmt(s2)}, over stage-1 masks {_fmt(s1)} (total vs teacher "
            f"at test mask 50 %; cells (stage 1, stage 2): {cells})")


def finding_window(msta: dict | None, trained: int = 15) -> str:
    """(b) half the trained window within 5 % of it, and the longer, unseen windows not worse
    (by more than 5 %): the paper's T = 7 against T = 15 and T = 20, for a student trained at
    T = 15; for one trained at T = 4, T = 2 against T = 4 and the sweep's T > 4."""
    measured = {int(c["condition"][2:]): value(headline(c)["average"], "total_vs_teacher")
                for c in (msta or {}).get("runs", []) if c["policy"] == "msta"
                and c["condition"].startswith("T=") and c["status"] == "ok"}
    half, longer = trained // 2, sorted(t for t in measured if t > trained)
    v = {t: measured.get(t) for t in (half, trained, *longer)}
    if not longer or None in v.values():
        return f"(b) window T (trained at {trained}): n/a (not measured)"
    ok = abs(v[half] - v[trained]) <= TOLERANCE * v[trained] and \
        all(v[t] >= (1 - TOLERANCE) * v[trained] for t in longer)
    return (f"(b) T = {half} within 5 % of the trained T = {trained} and the unseen T = "
            f"{', '.join(map(str, longer))} not worse: {verdict(ok)}: total vs teacher "
            + ", ".join(f"T = {t} {_fmt(x)}" for t, x in sorted(v.items())))


def finding_sensors(msta: dict | None) -> str:
    """(c) q-dot, contact, omega and a_{t-1} each redundant (<= 5 % loss), q and g critical."""
    full = value(cell(msta, "msta", "none"), "total_vs_teacher")
    if not full:
        return "(c) one sensor removed: n/a (not measured)"
    loss = {s: (full - v) / full for s in (*REDUNDANT, *CRITICAL)
            if (v := value(cell(msta, "msta", f"-{s}"), "total_vs_teacher")) is not None}
    ok = all(loss.get(s, 1.0) <= TOLERANCE for s in REDUNDANT) and \
        all(loss.get(s, 0.0) > TOLERANCE for s in CRITICAL)
    parts = ", ".join(f"{s} {100 * x:+.0f} %" for s, x in loss.items())
    return (f"(c) {', '.join(REDUNDANT)} redundant and {', '.join(CRITICAL)} critical: "
            f"{verdict(ok)}: loss of total vs teacher when removed ({parts}; full "
            f"{_fmt(full)})")


def finding_learnable_mask(table1: dict) -> str:
    """(d) the learnable-mask variants underperform removal at 0 % test mask."""
    v = {p: value(cell(table1, p, "mask 0%"), "total_vs_teacher")
         for p in ("msta", "msta_mask", "tert_concat", "tert_separate", "tert_mask")}
    pairs = [("msta_mask", "msta")]
    tert = [t for t in ("tert_concat", "tert_separate") if v[t] is not None]
    if tert:
        pairs.append(("tert_mask", max(tert, key=lambda t: v[t] or 0.0)))
    pairs = [(a, b) for a, b in pairs if v[a] is not None and v[b] is not None]
    if not pairs:
        return "(d) learnable mask vs removal: n/a (not measured)"
    ok = all(v[a] < v[b] for a, b in pairs)
    parts = "; ".join(f"{a} {_fmt(v[a])} vs {b} {_fmt(v[b])}" for a, b in pairs)
    return (f"(d) the learnable-mask variants underperform removal at 0 % test mask: "
            f"{verdict(ok)}: total vs teacher {parts}")


def headline_table(metrics: dict, conditions: list[str], policies: list[str]) -> str:
    """Rows = policies x conditions; the three headline figures with 95 % intervals."""
    rows = ["| policy | condition | trials | " + " | ".join(t for _, t in FIGURES) + " |",
            "|---|---|---|" + "---|" * len(FIGURES)]
    for p in policies:
        for c in conditions:
            x = cell(metrics, p, c)
            if x is not None:
                rows.append(f"| {p} | {c} | {x['trials']} | "
                            + " | ".join(fmt_cell(x, f) for f, _ in FIGURES) + " |")
    return "\n".join(rows)


def _conditions(metrics: dict, policy: str) -> list[str]:
    seen: list[str] = []
    for run in metrics["runs"]:
        if run["policy"] == policy and run["condition"] not in seen:
            seen.append(run["condition"])
    return seen


def write_report(cfg: Any, evals: dict[str, dict], command: str, timing: dict[str, float],
                 machine: str, out: Path) -> Path:
    """``out/report.md`` from the evaluations (``table1``, and ``msta`` / ``heatmap`` when
    MSTA was in the study)."""
    t1, msta, heat = evals["table1"], evals.get("msta"), evals.get("heatmap")
    ec = t1["config"]
    students = [p["name"] for p in t1["policies"] if p["kind"] == "student"]
    s = cfg.sizes
    lines = [
        f"# The paper's experiments, {cfg.scale} scale (msta-repro)", "",
        "```bash", command, "```", "",
        f"Made {datetime.date.today().isoformat()} on {machine}. Teacher `{cfg.teacher.label}`; "
        f"dataset {s.collect_episodes} teacher episodes of {s.collect_episode_length_s:g} s "
        f"(levels 0-2, DART noise 0.5); preset `{s.preset}`, MSTA's window T = "
        f"{cfg.msta_window}; stage 1 {s.stage1_steps} steps x "
        f"{s.batch_size}; stage 2 {s.stage2_rounds} rounds x {s.episodes_per_round} episodes "
        f"+ {s.stage2_steps} steps (MSTA's masks 0.75 / 0.5; rollouts of masked students at "
        f"test masks {' / '.join(f'{m:g}' for m in STAGE2_ROLLOUT_MASK_RATIOS)}); optimizer "
        f"`{cfg.optimizer}`. Evaluation: {ec['trials']} "
        f"trials of {ec['episode_length_s']:g} s per (policy, condition) over "
        f"{', '.join(ec['terrains'])} at levels {ec['levels']}, seed {ec['seed']}; every "
        "figure is normalized to the teacher on the same trials except survival; 95 % "
        "intervals.", "",
        "## Minimums", "", *minimums(t1), "",
        "## The paper's findings, checked", "",
        *(f"- {x}" for x in (finding_heatmap(heat), finding_window(msta, cfg.msta_window),
                             finding_sensors(msta), finding_learnable_mask(t1))), "",
        "## Table I: average total reward vs the paper", "", paper_table(t1), "",
        "## Table I: every figure", "",
        headline_table(t1, ["mask 0%", "mask 25%", "mask 50%"], students), "",
        table_one(t1, "lin_tracking"), "", table_one(t1, "ang_tracking"), ""]
    hard = evals.get("levels34")
    if hard:
        names = [p["name"] for p in hard["policies"] if p["kind"] == "student"]
        lines += [f"## Levels {', '.join(map(str, hard['config']['levels']))}: where the teacher still walks", "",
                  f"The students trained on levels 0-2 only; {hard['config']['trials']} trials "
                  "per condition at the harder levels, normalized to the teacher on the same "
                  "trials (the teacher's own survival there is in `levels34/report.md`).", "",
                  headline_table(hard, ["mask 0%", "mask 25%", "mask 50%"], names), ""]
    if msta:
        lines += ["## MSTA: one sensor removed, dead joint encoders, the window T", "",
                  headline_table(msta, _conditions(msta, "msta"), ["msta"]), "",
                  "Plots: `msta/sensor_removal.png`, `msta/dead_joints.png`, "
                  "`msta/history.png`.", ""]
    if heat:
        names = [p["name"] for p in heat["policies"] if p.get("train_masks")]
        lines += ["## Train-mask heatmap (stage 1 x stage 2)", "",
                  headline_table(heat, ["mask 0%", "mask 25%", "mask 50%"], names), "",
                  "![heatmap](heatmap/mask_matrix.png)", ""]
    lines += ["## Time per phase (s)", "", "| phase | s |", "|---|---|",
              *(f"| {k} | {v:.0f} |" for k, v in timing.items()), "",
              "Each evaluation's metrics.json (msta-eval's format), report.md and plots are "
              "in the folder of its name beside this file."]
    path = out / "report.md"
    path.write_text("\n".join(lines) + "\n")
    return path
