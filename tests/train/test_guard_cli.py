"""msta-guard (train/guard_fit.py): fit saves a guard a checkpoint folder loads back, evaluate
measures detection and false alarms with msta.collect.faults injected, bad options are
one-line errors."""

from __future__ import annotations

import json

import numpy as np
import pytest

from msta.policies.guard import GuardConfig, load_guard
from msta.train.guard_eval import evaluate_guard, format_table
from msta.train.guard_fit import main


def test_fit_writes_a_guard_the_folder_loads(synthetic_dataset, tmp_path, capsys):
    # the synthetic episodes are 40 steps: shorter than the default warm-up
    main(["fit", f"--dataset={synthetic_dataset}", f"--output_dir={tmp_path}", "--guard.margin=2",
          "--guard.explain=false", "--guard.warmup=0"])
    assert "saved" in capsys.readouterr().out
    guard = load_guard(tmp_path, num_envs=3)
    meta = json.loads((tmp_path / "guard.json").read_text())
    assert guard.cfg.margin == 2.0 and meta["config"]["margin"] == 2.0
    assert meta["config"]["explain"] is False and meta["config"]["two_sided"] is True
    assert "weight2" in guard.stats and any(n.startswith("z2:") for n in meta["statistics"])
    assert len(meta["statistics"]) == len(guard.stats["threshold"])
    assert np.isfinite(guard.stats["threshold"]).all() and guard.flags.shape == (3, 34)


def test_evaluate_reports_detection_and_false_alarms(synthetic_dataset, tmp_path):
    from msta.train.guard_fit import fit_guard

    guard = fit_guard(synthetic_dataset, list(range(8)), cfg=GuardConfig(warmup=0))
    report = evaluate_guard(guard, synthetic_dataset, [8, 9, 10, 11], min_length=40,
                            faults=(("bias", 3.0),))
    fa = report["false_alarms"]
    assert fa["all"]["channel_steps"] == 4 * 40 * 34
    assert {"terrain:flat", "terrain:stairs_up"} <= set(fa)
    row = report["detection"]["bias:3:encoder"]
    assert row["faults"] == 0 and row["within_10"] is None  # onset 1-3 s: beyond 40 steps
    table = format_table(report)
    assert "| fault-free |" in table and "| bias 3 | encoder | 0 | - | - |" in table
    assert row["within_10_shown"] is None and "within 10 of showing" in table


@pytest.mark.parametrize("argv,msg", [
    (["nope", "--dataset=x", "--output_dir=y"], "command must be fit or evaluate"),
    (["fit"], "--dataset and --output_dir are required"),
    (["fit", "--dataset=SYNTH", "--output_dir=y"], "needs episodes longer than warmup + window"),
])
def test_bad_options_are_one_line_errors(argv, msg, capsys, synthetic_dataset, tmp_path):
    argv = [a.replace("SYNTH", str(synthetic_dataset)).replace("=y", f"={tmp_path}")
            for a in argv]
    with pytest.raises(SystemExit) as e:
        main(argv)
    err = capsys.readouterr().err.strip()
    assert e.value.code == 2 and msg in err and "\n" not in err


def test_detection_is_also_counted_from_the_first_changed_reading(synthetic_dataset):
    from msta.collect.faults import FaultSpec, std_from_stats
    from msta.data.sensors import PHYSICAL_SENSORS
    from msta.data.stats import load_stats
    from msta.policies.guard import SensorGuard
    from msta.train.guard_data import load_episodes
    from msta.train.guard_eval import run_fault, summarize
    from msta.train.guard_fit import fit_guard

    guard = fit_guard(synthetic_dataset, list(range(8)), cfg=GuardConfig(warmup=0))
    data = load_episodes(synthetic_dataset, [8, 9, 10, 11])
    std = std_from_stats(load_stats(synthetic_dataset), PHYSICAL_SENSORS)

    def factory(n):
        return SensorGuard(guard.cfg, guard.stats, guard.sensors, n, guard.dt)

    onset = (0.1, 0.3)  # steps 5-15 of 40
    stuck = run_fault(factory, data, FaultSpec("stuck", 0, "joint_pos:0", onset), std, 0)
    assert len(stuck["shown_ok"]) == 4  # a held q differs from the true one a step later
    on_time = (stuck["delay"] >= 0) & (stuck["delay"] < 10)
    assert (stuck["shown_ok"] >= on_time).all()
    unseen = run_fault(factory, data, FaultSpec("scale", 1.0, "joint_pos:0", onset), std, 0)
    assert len(unseen["shown_ok"]) == 0  # reading * 1 never changes a reading
    row = summarize([unseen])
    assert row["shown"] == 0 and row["within_10_shown"] is None and row["faults"] == 4
