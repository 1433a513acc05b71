"""python -m msta.eval.bench.deploy_loop: its table and the int8 verdict from msta-eval's metrics."""

from __future__ import annotations

import pytest

from msta.eval.bench.deploy_loop import DeployLoopConfig, figures, report


def _run(policy: str, mask: float, lin: float, survival: float) -> dict:
    return {"policy": policy, "status": "ok", "spec": {"mask_ratio": mask},
            "normalized": {"per_terrain": {"average": {
                "lin_tracking": lin, "ci": {"lin_tracking": [lin - 0.03, lin + 0.03]}}}},
            "raw": {"per_terrain": {"average": {"survival": survival, "trials": 100}}}}


def _metrics(int8_lin: float) -> dict:
    runs = [_run("teacher", 0.0, 1.0, 1.0)]
    for mask in (0.0, 0.5):
        runs += [_run("pytorch", mask, 0.88, 0.97), _run("onnxruntime", mask, 0.87, 0.96),
                 _run("onnxruntime-int8", mask, int8_lin if mask else 0.87, 0.90)]
    return {"runs": runs}


def test_int8_is_accepted_on_tracking_within_the_tolerance_of_the_fp32_graph() -> None:
    lines = report(figures(_metrics(0.885)), 0.02)
    assert lines[-1].startswith("int8 vs fp32 closed loop: max |d tracking| 0.015 (tolerance 0.02)"
                                ": accepted")
    assert "max |d survival| 0.060" in lines[-1]  # reported, not gated
    assert "onnxruntime vs pytorch: max |d tracking| 0.010, max |d survival| 0.010" in lines
    assert sum(line.startswith("onnxruntime-int8  ") for line in lines) == 2  # a row per mask


def test_int8_is_refused_beyond_the_tolerance_and_the_teacher_is_no_row() -> None:
    got = figures(_metrics(0.80))
    assert set(got) == {"pytorch", "onnxruntime", "onnxruntime-int8"}
    assert report(got, 0.02)[-1].endswith("refused; max |d survival| 0.060")


def test_a_missing_checkpoint_is_one_line() -> None:
    with pytest.raises(ValueError, match="policy_path"):
        DeployLoopConfig()
    with pytest.raises(ValueError, match="not a directory"):
        DeployLoopConfig(policy_path="/nonexistent/ckpt")
