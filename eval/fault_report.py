"""report.md's sensor_faults section: one table per fault condition (docs/faults.md).

Rows: every student x removal (unguarded, oracle, guard when it ran); columns: linear-
velocity tracking and total reward normalized by the fault-free teacher on the same trials,
survival, each with its 95 % interval, and for the oracle and guard rows what they removed
(the fraction of begun faults removed, within 0.2 s of onset, mean delay, and removed
channel-steps that were not the fault's per channel-step).
"""

from __future__ import annotations

from typing import Any

from msta.data.figures import fmt as _fmt
from msta.eval.report_cells import fmt_cell, norm_cell
from msta.eval.scenarios import REMOVALS

_HEAD = ("| policy | removal | lin tracking vs teacher | total vs teacher | survival | "
         "faults removed | within 0.2 s | mean delay (s) | false removals / channel-step |")


def _detection_cells(det: dict[str, Any] | None) -> list[str]:
    if not det:
        return ["-"] * 4
    fa = det.get("false_alarms_per_channel_step")
    return [_fmt(det.get("detected")), _fmt(det.get("within_0.2s")),
            _fmt(det.get("mean_delay_s"), 3), "n/a" if fa is None else f"{fa:.1e}"]


def _row(run: dict[str, Any]) -> str:
    if run["status"] != "ok":
        return f"| {run['policy']} | {run['removal']} | n/a: {run['reason']} |||||||"
    norm, raw = norm_cell(run), run["raw"]["per_terrain"]["average"]
    cells = [fmt_cell(norm, "lin_tracking"), fmt_cell(norm, "total"),
             fmt_cell(raw, "survival")] + _detection_cells(run.get("detection"))
    return f"| {run['policy']} | {run['removal']} | " + " | ".join(cells) + " |"


def section(metrics: dict[str, Any]) -> str:
    """The Markdown section (a heading, a note, one table per fault in sweep order)."""
    runs = [r for r in metrics["runs"] if r["scenario"] == "sensor_faults"]
    by_fault: dict[str, list[dict]] = {}
    for r in runs:
        by_fault.setdefault(str(r["value"]), []).append(r)
    parts = ["## Sensor faults", "",
             "Each fault starts at a random onset per trial (the same trials and onsets in "
             "every row); the teacher runs fault-free. Returns normalized by the teacher's, "
             "terrain average, 95 % intervals; see docs/faults.md.", ""]
    for fault, rows in by_fault.items():
        rows = sorted(rows, key=lambda r: REMOVALS.index(r.get("removal") or "unguarded"))
        title = "fault-free" if fault == "none" else f"`{fault}`"
        parts += [f"### {title}", "", _HEAD, "|" + "---|" * 9]
        parts += [_row(r) for r in rows] + [""]
    return "\n".join(parts)
