"""msta-compare end to end at a tiny budget: record, train two policies (both stages, each on
its own dataset copy), evaluate them with the teacher, print and save the Table I."""

from __future__ import annotations

import contextlib
import io
import json
import time
from pathlib import Path

import pytest

from msta.data.features import load_info
from msta.eval.apps.compare import CompareConfig, main

TINY = ["--preset=tiny", "--stage1_steps=3", "--stage2_rounds=1", "--stage2_steps=2",
        "--episodes_per_round=2", "--stage2_episode_length_s=0.3", "--stage2_num_envs=2",
        "--batch_size=8", "--trials=2", "--eval_terrains=flat", "--eval_episode_length_s=1.0",
        "--collect_num_envs=2", "--collect_episode_length_s=0.4", "--progress=false"]


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> tuple[Path, Path, str]:
    """One tiny comparison (msta + gru), recorded by the command itself; its stdout."""
    out = tmp_path_factory.mktemp("compare") / "out"
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        main(args(out))
    return out, out / "teacher_dataset", buf.getvalue()


def args(out: Path, *extra: str) -> list[str]:
    return [f"--output_dir={out}", "--collect_episodes=3", "--teacher.type=gait",
            "--policies=msta,gru", *TINY, *extra]


def test_table_has_a_row_per_policy_and_metrics(run) -> None:
    out, _, stdout = run
    metrics = json.loads((out / "eval" / "metrics.json").read_text())
    names = [p["name"] for p in metrics["policies"]]
    assert names == ["teacher", "msta", "gru"]
    assert [p.get("type") for p in metrics["policies"][1:]] == ["msta", "gru"]
    ok = {(r["policy"], r["condition"]) for r in metrics["runs"] if r["status"] == "ok"}
    masks = {"mask 0%", "mask 25%", "mask 50%"}
    assert {(p, c) for p in ("msta", "gru") for c in masks} <= ok
    assert ("teacher", "mask 0%") in ok
    md = (out / "comparison.md").read_text()
    assert metrics["reference"]["per_terrain"]["average"]["total"] > 0
    for name in ("msta", "gru"):  # the row of normalized averages at 0 / 25 / 50 % test masks
        avg = [r["normalized"]["per_terrain"]["average"]["total"] for r in metrics["runs"]
               if r["policy"] == name]
        assert len(avg) == 3 and all(v >= 0.0 for v in avg)
        row = f"| {name} | " + " | ".join(f"{v:.2f}" for v in avg) + " | "
        assert row in stdout and row in md
    assert "msta-compare --output_dir=" in md and "--policies=msta,gru" in md
    timing = json.loads((out / "timing.json").read_text())
    assert {"collect", "msta stage 1", "msta stage 2", "gru stage 1", "gru stage 2",
            "eval"} <= set(timing)


def test_each_policy_corrects_on_its_own_copy(run) -> None:
    out, source, _ = run
    assert load_info(source)["total_episodes"] == 3  # the shared dataset is untouched
    for name in ("msta", "gru"):
        copy = out / "runs" / name / "dataset"
        assert load_info(copy)["total_episodes"] == 3 + 2
        prog = json.loads((out / "runs" / name / "stage2" / "progress.json").read_text())
        assert Path(prog["dataset"]) == copy
        assert (out / "checkpoints" / name / "model.safetensors").is_file()


def test_rerun_skips_trained_policies_and_checks_budgets(run, capsys) -> None:
    out, _, _ = run
    names = ("msta", "gru")
    before = {n: (out / "checkpoints" / n / "model.safetensors").stat().st_mtime_ns
              for n in names}
    main(args(out))
    text = capsys.readouterr().out
    assert "msta: final checkpoint" in text and "gru: final checkpoint" in text
    assert "stage 1:" not in text and "stage 2:" not in text
    after = {n: (out / "checkpoints" / n / "model.safetensors").stat().st_mtime_ns
             for n in names}
    assert after == before
    with pytest.raises(SystemExit):
        main(args(out, "--stage1_steps=4"))
    assert "different ['stage1_steps']" in capsys.readouterr().err


def test_bad_input_is_named(tmp_path, capsys) -> None:
    with pytest.raises(ValueError, match="unknown policy 'lstm'"):
        CompareConfig(dataset="x", policies="msta,lstm")
    with pytest.raises(ValueError, match="--collect_episodes"):
        CompareConfig(policies="msta")
    with pytest.raises(SystemExit):
        main(["--dataset=/nonexistent/ds", "--policies=msta", "--bogus=1"])
    with pytest.raises(SystemExit):
        main([f"--dataset={tmp_path / 'missing'}", "--policies=msta", f"--output_dir={tmp_path / 'o'}"])
    assert f"{tmp_path / 'missing'}" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_a_phase_stopped_by_max_minutes_keeps_its_time_for_the_call_that_finishes_it(tmp_path):
    from msta.eval.apps.phases import PhaseLog

    first = PhaseLog(tmp_path, deadline=None)
    first.start("msta stage 1")
    time.sleep(0.2)
    first.stopped()  # what compare() / repro() do when --max_minutes stops a call
    second = PhaseLog(tmp_path)
    t = second.start("msta stage 1")
    second.done("msta stage 1", t)
    timing = json.loads((tmp_path / "timing.json").read_text())
    assert 0.2 <= timing["msta stage 1"] < 5  # the first call's share is in the total
    assert json.loads((tmp_path / "timing_partial.json").read_text()) == {}


def test_a_policys_copy_leaves_the_quarantine_and_the_lock_behind(tmp_path) -> None:
    """Each policy appends to its own copy of the teacher dataset: what a resume set aside
    (``.msta-quarantine/``: up to 100 MB per file of an interrupted flush) stays with the
    original, where the user checks it, instead of being copied once per policy."""
    from msta.data.layout import LOCK_NAME, QUARANTINE_DIR
    from msta.eval.apps.compare import copy_dataset

    root = tmp_path / "teacher"
    files = {"data/chunk-000/file-000.parquet": b"episodes", "meta/info.json": b"{}",
             f"{QUARANTINE_DIR}/20261204T000000Z/data/chunk-000/file-001.parquet": b"aside",
             LOCK_NAME: b"123"}
    for rel, content in files.items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_bytes(content)
    own = copy_dataset(root, tmp_path / "run" / "dataset")
    copied = sorted(p.relative_to(own).as_posix() for p in own.rglob("*") if p.is_file())
    assert copied == ["data/chunk-000/file-000.parquet", "meta/info.json"]
    assert (own / "data/chunk-000/file-000.parquet").read_bytes() == b"episodes"


def test_a_run_saved_under_the_rollout_masks_old_name_continues(tmp_path) -> None:
    """compare_config.json written when the option was ``stage2_rollout_masks`` still matches
    the same budgets under ``stage2_rollout_mask_ratios``; another value is still refused."""
    from msta.eval.apps.compare import check_run_config

    cfg = CompareConfig(dataset=str(tmp_path / "ds"), policies="msta",
                        stage2_rollout_mask_ratios=(0.0, 0.5))
    check_run_config(cfg, tmp_path)
    path = tmp_path / "compare_config.json"
    saved = json.loads(path.read_text())
    saved["stage2_rollout_masks"] = saved.pop("stage2_rollout_mask_ratios")
    path.write_text(json.dumps(saved))
    check_run_config(cfg, tmp_path)  # the old name: the same run
    other = CompareConfig(dataset=str(tmp_path / "ds"), policies="msta",
                          stage2_rollout_mask_ratios=(0.0,))
    with pytest.raises(ValueError, match="stage2_rollout_mask_ratios"):
        check_run_config(other, tmp_path)


def test_msta_window_and_stage1_mask_reach_the_msta_students_only(tmp_path) -> None:
    cfg = CompareConfig(dataset=str(tmp_path / "ds"), policies="msta,msta_mask,gru",
                        msta_history=4, msta_mask_ratio=0.5)
    msta, learnable, gru = (cfg.policy(n) for n in ("msta", "msta_mask", "gru"))
    assert (msta.history, msta.mask_ratio) == (4, 0.5)
    assert (learnable.history, learnable.mask_ratio, learnable.learnable_mask) == (4, 0.5, True)
    preset = CompareConfig(dataset=str(tmp_path / "ds"), policies="msta,gru")
    assert (gru.history, gru.mask_ratio) == (preset.policy("gru").history, preset.policy("gru").mask_ratio)
    assert (preset.policy("msta").history, preset.policy("msta").mask_ratio) == (15, 0.75)
    with pytest.raises(ValueError, match="msta_mask_ratio=1.0 must be in"):
        CompareConfig(dataset=str(tmp_path / "ds"), policies="msta", msta_mask_ratio=1.0)
    with pytest.raises(ValueError, match="msta_history"):
        CompareConfig(dataset=str(tmp_path / "ds"), policies="msta", msta_history=-1)
