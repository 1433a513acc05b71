"""report.md helpers: interval formatting and the identical-figures warning."""

from __future__ import annotations

import copy
import json
from pathlib import Path

from msta.data.figures import fmt_ci
from msta.eval.report import identical_groups, identical_warnings, markdown, raw_table

#: a metrics.json written before the window was named ``history`` (its runs' spec has "T"):
#: the 2026-12-04 reference study's MSTA sweeps, three conditions of them
OLD_METRICS = Path(__file__).parent / "fixtures" / "metrics_before_history.json"


def _run(condition: str, inputs: str, lin: float, policy: str = "s") -> dict:
    cell = {"lin_tracking": lin, "survival": 1.0, "trials": 4,
            "ci": {"lin_tracking": [lin - 0.1, lin + 0.1], "survival": [0.5, 1.0]}}
    return {"policy": policy, "scenario": "token_removal", "condition": condition,
            "inputs": inputs, "spec": {}, "status": "ok",
            "raw": {"per_terrain": {"flat": cell, "average": copy.deepcopy(cell)}}}


def test_identical_figures_over_different_inputs_are_flagged():
    runs = [_run("mask 0%", "a", 0.5), _run("mask 25%", "b", 0.5), _run("mask 50%", "c", 0.5)]
    assert identical_groups(runs) == [["mask 0%", "mask 25%", "mask 50%"]]
    metrics = {"policies": [{"name": "s", "kind": "student"}], "runs": runs}
    assert identical_warnings(metrics) == [
        "s: the student's figures are identical across token_removal conditions mask 0%, "
        "mask 25%, mask 50%: it may ignore its inputs"]


def test_differing_figures_or_equal_inputs_are_not_flagged():
    differing = [_run("mask 0%", "a", 0.5), _run("mask 50%", "b", 0.501)]
    assert identical_groups(differing) == []
    same_inputs = [_run("T=15", "a", 0.5), _run("T=20", "a", 0.5)]  # the same run, shared
    assert identical_groups(same_inputs) == []
    na = [_run("mask 0%", "a", 0.5), {**_run("mask 50%", "b", 0.5), "status": "n/a"}]
    assert identical_groups(na) == []
    teacher = {"policies": [{"name": "s", "kind": "teacher"}],
               "runs": [_run("mask 0%", "a", 0.5), _run("mask 50%", "b", 0.5)]}
    assert identical_warnings(teacher) == []


def test_removal_rows_equal_to_the_unguarded_one_are_not_flagged():
    """A guard that removed nothing (a fault-free run) and an oracle give the unguarded
    figures by design; two different faults with identical unguarded figures still warn."""
    def fault(condition, inputs, removal, lin):
        return {**_run(condition, inputs, lin), "scenario": "sensor_faults", "removal": removal}
    metrics = {"policies": [{"name": "s", "kind": "student"}], "runs": [
        fault("none | unguarded", "a", "unguarded", 0.5), fault("none | guard", "b", "guard", 0.5),
        fault("stuck | oracle", "c", "oracle", 0.5)]}
    assert identical_warnings(metrics) == []
    metrics["runs"].append(fault("bias | unguarded", "d", "unguarded", 0.5))
    assert identical_warnings(metrics) == [
        "s: the student's figures are identical across sensor_faults conditions "
        "none | unguarded, bias | unguarded: it may ignore its inputs"]


def test_interval_formatting():
    assert fmt_ci(0.85, [0.75, 0.95]) == "0.85 ±0.10"
    assert fmt_ci(0.8, [0.49, 0.94]) == "0.80 (0.49–0.94)"
    assert fmt_ci(0.85, None) == "0.85"
    assert fmt_ci(None, [0.1, 0.2]) == "n/a"


def test_a_metrics_json_from_before_history_was_named_renders_the_same():
    old = json.loads(OLD_METRICS.read_text())
    assert all("T" in r["spec"] and "history" not in r["spec"] for r in old["runs"])
    new = copy.deepcopy(old)
    for r in new["runs"]:
        r["spec"] = {("history" if k == "T" else k): v for k, v in r["spec"].items()}
    table = raw_table(old)
    assert table == raw_table(new) and markdown(old) == markdown(new)
    # every policy's baseline row (the run with no input change) is found in the old file
    assert all(f"\n| {p['name']} |" in table for p in old["policies"])
