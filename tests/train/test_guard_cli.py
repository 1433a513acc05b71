"""msta-guard (train/guard_fit.py): fit saves a guard a checkpoint folder loads back, evaluate
measures detection and false alarms with msta.collect.faults injected, bad options are
one-line errors."""

from __future__ import annotations

import json

import numpy as np
import pytest

from msta.policies.guard import GuardConfig
from msta.policies.guard_file import load_guard
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


@pytest.mark.parametrize("option,msg", [
    ("--guard.margin=inf", "--guard.margin=inf must be a finite number"),  # command line
    ("--guard.margin=nan", "--guard.margin=nan must be a finite number"),
    ("--guard.margin=1e300", "guard margin must be a number in (0, 1e+06]"),  # the config
    ("--guard.contact_lags=100000", "guard contact_lags must be an integer in [1, 100]"),
    ("--guard.window=0", "guard window must be an integer in [1, 1000]"),
])
def test_settings_that_would_switch_the_guard_off_or_exhaust_memory_are_refused(
        option, msg, capsys, synthetic_dataset, tmp_path):
    with pytest.raises(ValueError, match="guard margin must be a number"):
        GuardConfig(margin=float("inf"))  # from Python too
    with pytest.raises(SystemExit) as e:
        main(["fit", f"--dataset={synthetic_dataset}", f"--output_dir={tmp_path}", option])
    err = capsys.readouterr().err.strip()
    assert e.value.code == 2 and msg in err and "\n" not in err
    assert not list(tmp_path.iterdir())  # nothing saved


@pytest.fixture(scope="module")
def saved(synthetic_dataset, tmp_path_factory):
    """A guard fitted on the synthetic dataset, saved: (folder, guard)."""
    from msta.policies.guard_file import save_guard
    from msta.train.guard_fit import fit_guard

    folder = tmp_path_factory.mktemp("guard")
    guard = fit_guard(synthetic_dataset, cfg=GuardConfig(warmup=0))
    save_guard(guard, folder)
    return folder, guard


def _edited_copy(saved, tmp_path, meta=None, arrays=None, text=None):
    """A copy of the saved guard whose settings (guard.json and the arrays' header) or arrays
    are replaced, as a hostile or damaged checkpoint would hold them."""
    from safetensors.numpy import save_file

    folder, guard = saved
    stats = {k: v.copy() for k, v in guard.stats.items()} | (arrays or {})
    good = json.loads((folder / "guard.json").read_text())
    body = text if text is not None else json.dumps(good if meta is None else meta(good))
    save_file(stats, str(tmp_path / "guard.safetensors"), metadata={"msta_guard": body})
    (tmp_path / "guard.json").write_text(body)
    return tmp_path


def _set(path, value):
    def edit(meta):
        node = meta
        for key in path[:-1]:
            node = node[key]
        node[path[-1]] = value
        return meta
    return edit


@pytest.mark.parametrize("meta,arrays,text,msg", [
    (_set(["dt"], float("inf")), None, None, "0 < dt <= 1 s"),
    (_set(["dt"], "0.02"), None, None, "'dt' must be a number"),
    (_set(["config", "margin"], "2"), None, None, "'margin' must be a float"),
    (_set(["config", "window"], [1]), None, None, "'window' must be a int"),
    (_set(["config", "contact_lags"], 10**9), None, None, "contact_lags must be an integer in"),
    (_set(["config"], None), None, None, "'config' must be an object"),
    (_set(["sensors"], "joint_pos"), None, None, "'sensors' must be a list"),
    (lambda m: [m], None, None, "must be a JSON object"),
    (None, None, "[" * 100_000, "not valid JSON"),
    (None, {"threshold": "nan"}, None, "'threshold' must be not NaN and >= 0"),
    (None, {"threshold": "inf"}, None, "'threshold' must be finite (an infinite"),
    (None, {"z_std": "zero"}, None, "'z_std' must be finite and > 0"),
    (None, {"weight": "short"}, None, "'weight' must be finite with shape"),
])
def test_a_malformed_or_disarming_guard_file_is_one_line(saved, tmp_path, meta, arrays, text,
                                                         msg):
    from msta.policies.guard_file import GuardFileError

    stats = saved[1].stats
    values = {"nan": np.nan, "inf": np.inf, "zero": 0.0}
    arrays = {k: (stats[k][:3].copy() if v == "short" else np.full_like(stats[k], values[v]))
              for k, v in (arrays or {}).items()}
    folder = _edited_copy(saved, tmp_path, meta, arrays, text)
    with pytest.raises(GuardFileError) as err:
        load_guard(folder)
    assert msg in str(err.value) and "\n" not in str(err.value)
    assert str(folder / "guard.") in str(err.value)


def test_a_damaged_arrays_file_is_one_line(saved, tmp_path):
    from msta.policies.guard_file import GuardFileError

    (tmp_path / "guard.json").write_bytes((saved[0] / "guard.json").read_bytes())
    (tmp_path / "guard.safetensors").write_bytes(b"\xff" * 64)
    with pytest.raises(GuardFileError, match=r"guard\.safetensors: not a readable safetensors"):
        load_guard(tmp_path)


def test_a_save_killed_between_its_two_files_leaves_a_consistent_guard(saved, tmp_path,
                                                                       synthetic_dataset):
    """The arrays file carries the settings: new arrays beside an old guard.json (a kill
    after the first rename) load as the new guard."""
    import shutil

    from msta.policies.guard_file import save_guard
    from msta.train.guard_fit import fit_guard

    folder, old = saved
    shutil.copytree(folder, tmp_path / "ckpt")
    new = fit_guard(synthetic_dataset, cfg=GuardConfig(warmup=0, two_sided=False))
    save_guard(new, tmp_path / "new")
    shutil.copy(tmp_path / "new" / "guard.safetensors", tmp_path / "ckpt")  # json is the old
    back = load_guard(tmp_path / "ckpt")
    assert not back.cfg.two_sided and back.names == new.names != old.names
    assert all((back.stats[k] == new.stats[k]).all() for k in new.stats)
