"""msta-repro at the tiny scale: the whole study end to end, a resume after an injected
crash that redoes no finished phase, and a report whose tables have every row and column."""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import pytest

import msta.eval.apps.repro as repro_mod
from msta.data.budget import EXIT_STOPPED
from msta.eval.apps.repro import SCALES, ReproConfig, main, repro
from msta.policies.teacher.config import TeacherConfig

POLICIES = "msta,gru,msta_mask"


def config(out: Path, **kw) -> ReproConfig:
    return ReproConfig(**{"scale": "tiny", "output_dir": str(out), "policies": POLICIES,
                          "teacher": TeacherConfig(type="gait"), "progress": False, **kw})


@pytest.fixture(scope="module")
def study(tmp_path_factory) -> tuple[Path, str]:
    """One tiny study: stopped by --max_minutes after its first phase, killed once in the
    MSTA evaluation and re-run; (output, the last call's stdout)."""
    out = tmp_path_factory.mktemp("repro") / "out"
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf), pytest.raises(SystemExit) as stopped:
        main(["--scale=tiny", f"--output_dir={out}", f"--policies={POLICIES}",
              "--teacher.type=gait", "--progress=false", "--max_minutes=1e-9"])
    assert stopped.value.code == EXIT_STOPPED
    assert "msta-repro: stopped (before msta stage 1): --max_minutes reached" in buf.getvalue()
    assert (out / "teacher_dataset").is_dir() and not (out / "compare" / "runs").exists()
    real = repro_mod.run_eval

    def crash(cfg, name, *args, **kw):
        if name == "msta":
            raise KeyboardInterrupt("injected crash")
        return real(cfg, name, *args, **kw)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(repro_mod, "run_eval", crash)
        with contextlib.redirect_stdout(io.StringIO()), pytest.raises(KeyboardInterrupt):
            repro(config(out))
    assert (out / "eval" / "table1" / "metrics.json").is_file()
    assert not (out / "eval" / "msta").exists() and not (out / "report").exists()
    stamps = {p: p.stat().st_mtime_ns for p in
              [*(out / "compare" / "checkpoints").glob("*/model.safetensors"),
               out / "eval" / "table1" / "metrics.json"]}
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        repro(config(out), "msta-repro --scale=tiny")
    after = {p: p.stat().st_mtime_ns for p in stamps}
    assert after == stamps  # trained students and the finished evaluation were not redone
    return out, buf.getvalue()


def test_the_resumed_run_redoes_no_finished_phase(study) -> None:
    out, text = study
    for phase in ("dataset", "msta stage 1", "gru stage 2", "eval table1"):
        assert f"] {phase}:" not in text, phase
    assert "eval msta: done" in text and "eval heatmap: done" in text
    timing = json.loads((out / "timing.json").read_text())
    assert {"dataset", "msta stage 1", "msta stage 2", "gru stage 1", "eval table1",
            "eval msta", "eval heatmap"} <= set(timing)


def test_the_report_has_every_row_and_column(study) -> None:
    out, _ = study
    md = (out / "report" / "report.md").read_text()
    assert "msta-repro --scale=tiny" in md
    for name in POLICIES.split(","):
        for mask in ("mask 0%", "mask 25%", "mask 50%"):
            assert f"| {name} | {mask} | 2 | " in md, (name, mask)
    rows = [line for line in md.splitlines() if line.startswith("| msta | ")]
    assert all(line.count("|") == 7 for line in rows if "mask" in line or "T=" in line)
    for cond in ("none", "-joint_pos", "-gravity", "-last_action", "k=0", "k=6", "T=2",
                 "T=4", "T=8"):
        assert f"| msta | {cond} | 2 | " in md, cond
    s = SCALES["tiny"]
    for m1 in s.heatmap_stage1:
        for m2 in s.heatmap_stage2:
            assert f"| s1_{m1:g}_s2_{m2:g} | mask 50% | 2 | " in md
    assert "| msta | " in md and "0.97 | 0.95 | 0.94 |" in md  # the paper's Table I beside
    for finding in ("(a)", "(b)", "(c)", "(d)"):
        assert f"- {finding} " in md
    assert md.count("**met**") + md.count("**not met**") + md.count(": n/a") >= 6
    assert "## Levels 3, 4: where the teacher still walks" in md
    hard = md.split("## Levels 3, 4")[1].split("\n## ")[0]
    for name in ("msta", "gru"):
        for mask in ("mask 0%", "mask 50%"):
            assert f"| {name} | {mask} | 2 | " in hard, (name, mask)
    assert "| msta_mask |" not in hard
    for name in ("table1", "msta", "heatmap", "levels34"):
        metrics = json.loads((out / "report" / name / "metrics.json").read_text())
        assert metrics["config"]["trials"] == 2 and metrics["runs"]
    assert json.loads((out / "report" / "levels34" / "metrics.json").read_text()
                      )["config"]["levels"] == [3, 4]
    assert (out / "report" / "heatmap" / "mask_matrix.png").is_file()
    assert (out / "report" / "msta" / "history.png").is_file()


def test_the_msta_students_train_at_the_scales_window_and_the_others_at_15(study) -> None:
    out, _ = study
    windows = {p.name: json.loads((p / "config.json").read_text())["history"]
               for p in (out / "compare" / "checkpoints").iterdir()}
    assert windows == {"msta": 4, "msta_mask": 4, "gru": 15}
    heat = {json.loads((p / "config.json").read_text())["history"]
            for p in (out / "heatmap" / "checkpoints").iterdir()}
    assert heat == {4}
    md = (out / "report" / "report.md").read_text()
    assert "MSTA's window T = 4" in md
    assert "- (b) T = 2 within 5 % of the trained T = 4 and the unseen T = 5, 8 not worse: " \
        "**" in md


def test_masked_students_roll_out_masked_in_stage_2_and_the_others_do_not(study) -> None:
    out, _ = study
    runs = out / "compare" / "runs"
    masks = {name: json.loads((runs / name / "stage2" / "progress.json").read_text()
                              )["config"]["rollout_mask_ratios"] for name in POLICIES.split(",")}
    assert masks == {"msta": [0.0, 0.5], "msta_mask": [0.0, 0.5], "gru": []}


def test_heatmap_cells_are_distinct_students_on_the_shared_stage1(study) -> None:
    out, _ = study
    s = SCALES["tiny"]
    cells = {m2: out / "heatmap" / "checkpoints" / f"s1_{s.heatmap_stage1[0]:g}_s2_{m2:g}"
             for m2 in s.heatmap_stage2}
    # each cell retrained at its own stage-2 ratio (training.json) and its config keeps
    # the stage-1 ratio it was trained with first
    assert {m2: json.loads((c / "training.json").read_text())["mask_ratio"]
            for m2, c in cells.items()} == {m: m for m in s.heatmap_stage2}
    assert {json.loads((c / "config.json").read_text())["mask_ratio"]
            for c in cells.values()} == {s.heatmap_stage1[0]}
    # stage 1 at the study's own MSTA mask is the study's MSTA stage 1, not trained again
    assert not (out / "heatmap" / f"s1_{s.heatmap_stage1[0]:g}").exists()


def test_a_different_study_in_the_same_folder_is_refused(study, capsys) -> None:
    out, _ = study
    with pytest.raises(SystemExit):
        main(["--scale=tiny", f"--output_dir={out}", "--policies=msta", "--teacher.type=gait"])
    assert "different ['policies']" in capsys.readouterr().err


def test_bad_options_are_one_line_errors(tmp_path, capsys) -> None:
    for argv, words in ((["--scale=huge"], "unknown scale 'huge'"),
                        (["--policies=msta,lstm"], "unknown policy 'lstm'")):
        with pytest.raises(SystemExit):
            main([*argv, f"--output_dir={tmp_path / 'o'}"])
        err = capsys.readouterr().err
        assert words in err and err.count("\n") == 1, err
    assert not (tmp_path / "o").exists()


def test_without_the_heatmap_the_report_says_finding_a_was_not_measured(study) -> None:
    out, _ = study
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        path = repro(config(out, heatmap=False, report_dir=str(out / "report_nh")))
    text = buf.getvalue()
    assert "heatmap 0 MSTA students" in text and "stage 2:" not in text
    md = path.read_text()
    assert "- (a) stage-2 mask vs stage-1 mask: n/a (no heatmap)" in md
    assert "## Train-mask heatmap" not in md and "| msta | T=8 | 2 | " in md
    assert not (out / "report_nh" / "heatmap").exists()


def test_the_study_defaults_to_the_demos_teacher_and_names_it() -> None:
    from msta.eval.apps.demo import DemoConfig

    cfg = ReproConfig(scale="tiny")
    assert cfg.teacher == DemoConfig().teacher
    assert cfg.teacher.label == "rma (rma_ppo)"
