"""msta-train (stage 1): outputs, exact resume, learning, clear errors."""

from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest
import torch
from safetensors.torch import load_file

from msta.data.budget import EXIT_STOPPED
from msta.policies.factory import load_policy
from msta.policies.msta import MSTAPolicy
from msta.policies.registry import get_config_class, registered_policies
from msta.train.cli import parse_cli
from msta.train.offline import main
from msta.train.stage1 import train
from msta.train.train_config import TrainConfig

FAST = ["--policy.preset=tiny", "--policy.input_sensors=[command,joint_pos,gravity]",
        "--policy.history=5", "--batch_size=16", "--warmup_steps=2", "--progress=false",
        "--device=cpu"]


def cfg_for(dataset, out, *extra: str) -> TrainConfig:
    return parse_cli(TrainConfig, [f"--dataset={dataset}", f"--output_dir={out}", *FAST, *extra],
                     prog="msta-train")


def csv_rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_preset_and_overrides_parse(tmp_path):
    cfg = cfg_for(tmp_path, tmp_path / "o", "--policy.dim=16")
    assert (cfg.policy.dim, cfg.policy.num_layers, cfg.policy.history) == (16, 1, 5)
    assert cfg.policy.input_sensors == ("command", "joint_pos", "gravity")
    assert cfg.mask_ratio is None and cfg.policy.mask_ratio == 0.75


def test_every_policy_type_parses_in_a_fresh_process(tmp_path):
    """--policy.type=gru / mlp / ... must not depend on someone importing the baselines
    first (a fresh msta-train said "invalid choice: 'gru' (choose from 'msta')")."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    repo = Path(__file__).resolve().parents[2]
    code = ("from msta.train.cli import parse_cli; from msta.train.offline import TrainConfig; "
            "import sys; cfgs = [parse_cli(TrainConfig, ['--dataset=x', '--policy.type=' + t], "
            "'msta-train').policy for t in sys.argv[1:]]; "
            "print(' '.join(f'{c.type}:{type(c).__name__}' for c in cfgs))")
    out = subprocess.run([sys.executable, "-c", code, "gru", "mlp", "tert_mask", "rma_tcn"],
                         check=False, capture_output=True, text=True, timeout=120, cwd=tmp_path,
                         env={**os.environ, "PYTHONPATH": str(repo)})
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["gru:GRUConfig", "mlp:MLPConfig", "tert_mask:TERTMaskConfig",
                                  "rma_tcn:TCNConfig"]


@pytest.mark.parametrize("policy_type", registered_policies())
def test_every_registered_policy_trains_two_steps_through_msta_train(policy_type, synthetic_dataset,
                                                                      tmp_path):
    """Adding a policy is one registration: msta-train then trains it (tiny preset where the
    policy has presets) and saves a final checkpoint that loads as that type."""
    out = tmp_path / policy_type
    has_presets = hasattr(get_config_class(policy_type), "from_preset")
    preset = ["--policy.preset=tiny"] if has_presets else []
    main([f"--dataset={synthetic_dataset}", f"--output_dir={out}", f"--policy.type={policy_type}",
          *preset, "--steps=2", "--batch_size=4", "--eval_every=0", "--save_every=0",
          "--val_samples=8", "--progress=false"])
    rows = csv_rows(out / "metrics.csv")
    assert [r["step"] for r in rows][-1] == "2" and math.isfinite(float(rows[-1]["loss"]))
    loaded = load_policy(out / "final")
    assert loaded.config.type == policy_type


def test_run_writes_metrics_checkpoints_and_a_loadable_final(synthetic_dataset, tmp_path):
    out = tmp_path / "run"
    final = train(cfg_for(synthetic_dataset, out, "--steps=6", "--save_every=3",
                          "--eval_every=3", "--log_every=2"))
    rows = csv_rows(out / "metrics.csv")
    assert [int(r["step"]) for r in rows] == [2, 3, 4, 6]
    assert all(float(r["loss"]) > 0 for r in rows if r["loss"])
    assert rows[1]["val_loss"] and rows[-1]["val_loss_unmasked"] and not rows[0]["val_loss"]
    assert list((out / "tensorboard").glob("events.out.tfevents.*"))
    ckpts = out / "checkpoints"
    assert sorted(p.name for p in ckpts.iterdir()) == ["000003", "000006", "last"]
    assert (ckpts / "last").resolve() == (ckpts / "000006").resolve()
    state = ckpts / "000003" / "training_state"
    assert {p.name for p in state.iterdir()} == {
        "optimizer.safetensors", "optimizer.json", "scheduler.json", "rng.safetensors",
        "rng.json", "training_step.json"}
    assert json.loads((state / "training_step.json").read_text())["step"] == 3
    policy = MSTAPolicy.from_pretrained(final)
    assert policy.config.history == 5 and policy.config.dim == 32
    last = load_file(str(ckpts / "000006" / "pretrained_model" / "model.safetensors"))
    for k, v in policy.state_dict().items():
        assert torch.equal(v, last[k]), k
    # the processor normalizes with the dataset's own statistics
    stats = json.loads((synthetic_dataset / "meta" / "stats.json").read_text())
    np.testing.assert_allclose(policy.processor.stats["action"]["mean"],
                               stats["action"]["mean"], rtol=1e-6)


class Crash(RuntimeError):
    pass


def test_max_minutes_stops_with_a_checkpoint_and_the_resume_is_bit_identical(
        synthetic_dataset, tmp_path, capsys):
    args = ("--steps=6", "--save_every=0", "--eval_every=0", "--lr=3e-3")
    ref = train(cfg_for(synthetic_dataset, tmp_path / "ref", *args))
    out = tmp_path / "stopped"
    argv = [f"--dataset={synthetic_dataset}", f"--output_dir={out}", *FAST, *args]
    with pytest.raises(SystemExit) as stopped:
        main([*argv, "--max_minutes=1e-9"])  # passed at once: stops after the first step
    assert stopped.value.code == EXIT_STOPPED
    assert ("msta-train: stopped (train: step 1 of 6, checkpoint saved): --max_minutes "
            "reached; run the same command with --resume=true again") in capsys.readouterr().out
    assert (out / "checkpoints" / "last").resolve().name == "000001"  # save_every=0: only this
    assert not (out / "final").exists()
    main([*argv, "--resume=true"])
    a = load_file(str(ref / "model.safetensors"))
    b = load_file(str(out / "final" / "model.safetensors"))
    assert all(torch.equal(a[k], b[k]) for k in a), "the stopped and resumed run differs"


@pytest.mark.parametrize("extra", ["--ema_decay=0.0", "--ema_decay=0.9", "--optimizer=muon",
                                   "--unmasked_share=0.5", "--sensor_dropout=0.5"],
                         ids=["plain", "ema", "muon", "unmasked_share", "sensor_dropout"])
def test_resume_after_a_crash_is_bit_identical(synthetic_dataset, tmp_path, extra):
    args = ("--steps=8", "--save_every=4", "--eval_every=4", "--log_every=1", "--lr=3e-3",
            extra)
    ref = train(cfg_for(synthetic_dataset, tmp_path / "ref", *args))

    def crash_at_6(step, metrics):  # two steps after checkpoint 4: those are lost
        if step == 6:
            raise Crash

    out = tmp_path / "crashed"
    with pytest.raises(Crash):
        train(cfg_for(synthetic_dataset, out, *args), on_step=crash_at_6)
    assert not (out / "final").exists()
    assert (out / "checkpoints" / "last").resolve().name == "000004"
    resumed = train(cfg_for(synthetic_dataset, out, *args, "--resume=true"))
    a = load_file(str(ref / "model.safetensors"))
    b = load_file(str(resumed / "model.safetensors"))
    assert a.keys() == b.keys()
    for k in a:
        assert torch.equal(a[k], b[k]), f"{k} differs after resume"
    # same loss curve, no duplicated rows from the lost steps 5-6
    ra, rb = csv_rows(tmp_path / "ref" / "metrics.csv"), csv_rows(out / "metrics.csv")
    assert [r["step"] for r in rb] == [str(s) for s in range(1, 9)]
    for x, y in zip(ra, rb, strict=True):
        assert (x["loss"], x["lr"], x["val_loss"]) == (y["loss"], y["lr"], y["val_loss"])


def test_ema_makes_the_final_weights_the_running_average(synthetic_dataset, tmp_path):
    """--ema_decay: the final checkpoint holds the running average of the weights after
    every step (decay min(d, (1+t)/(10+t)), from the initial weights), not the last step's."""
    from msta.train import stage1

    init: dict[str, torch.Tensor] = {}
    seen: list[dict[str, torch.Tensor]] = []
    real_fit = stage1.fit

    def spy_fit(policy, *a, **kw):
        init.update({k: v.detach().clone() for k, v in policy.named_parameters()})

        def grab(step, metrics):  # after each step (the last one: already averaged)
            seen.append({k: v.detach().clone() for k, v in policy.named_parameters()})
        return real_fit(policy, *a, **{**kw, "on_step": grab})

    args = ("--steps=6", "--save_every=0", "--eval_every=0", "--lr=3e-3")
    stage1.fit = spy_fit
    try:
        final = train(cfg_for(synthetic_dataset, tmp_path / "ema", *args, "--ema_decay=0.5"))
    finally:
        stage1.fit = real_fit
    # the average only reads the weights: the plain run with the same seed walks the same
    # path, and its final weights are the last raw step
    plain = load_file(str(train(cfg_for(synthetic_dataset, tmp_path / "plain", *args))
                          / "model.safetensors"))
    got = load_file(str(final / "model.safetensors"))
    raws = seen[:-1] + [{k: plain[k] for k in init}]
    assert len(raws) == 6
    avg = {k: v.clone() for k, v in init.items()}
    for t, w in enumerate(raws, start=1):
        a = 1.0 - min(0.5, (1.0 + t) / (10.0 + t))
        avg = {k: avg[k] + a * (w[k] - avg[k]) for k in avg}
    changed = 0
    for k in avg:
        assert torch.allclose(got[k], avg[k], atol=1e-6), k
        changed += not torch.equal(got[k], plain[k])
    assert changed  # the average is not the last step's weights


def test_loss_decreases_on_a_learnable_dataset(synthetic_dataset, tmp_path):
    out = tmp_path / "learn"
    train(cfg_for(synthetic_dataset, out, "--steps=60", "--lr=3e-3", "--warmup_steps=10",
                  "--eval_every=0", "--save_every=0", "--log_every=1", "--val_fraction=0",
                  "--policy.input_sensors=[command,gravity]", "--mask_ratio=0.25",
                  "--batch_size=32"))
    losses = [float(r["loss"]) for r in csv_rows(out / "metrics.csv")]
    first, last = np.mean(losses[:10]), np.mean(losses[-20:])
    assert last < 0.25 * first, (first, last)


def test_bad_inputs_give_clear_errors(synthetic_dataset, tmp_path, capsys):
    with pytest.raises(FileNotFoundError, match="no such dataset directory"):
        train(cfg_for(tmp_path / "missing", tmp_path / "o"))
    with pytest.raises(FileNotFoundError, match="not a LeRobot"):
        train(cfg_for(tmp_path, tmp_path / "o"))
    with pytest.raises(ValueError, match="--dataset is required"):
        train(cfg_for("", tmp_path / "o"))
    (tmp_path / "used").mkdir()
    (tmp_path / "used" / "x").write_text("")
    with pytest.raises(FileExistsError, match="--resume=true"):
        train(cfg_for(synthetic_dataset, tmp_path / "used"))
    with pytest.raises(FileNotFoundError, match="nothing to resume"):
        train(cfg_for(synthetic_dataset, tmp_path / "used", "--resume=true"))
    with pytest.raises(SystemExit):
        main([f"--dataset={synthetic_dataset}", "--bogus_key=1"])
    assert "unknown option --bogus_key" in capsys.readouterr().err
    with pytest.raises(SystemExit, match="unknown msta preset 'huge'"):
        main([f"--dataset={synthetic_dataset}", "--policy.preset=huge"])
    with pytest.raises(SystemExit, match="unknown sensor 'bogus'"):
        cfg_for(synthetic_dataset, tmp_path / "o", "--policy.input_sensors=[bogus]")
    with pytest.raises(SystemExit, match="mask_ratio=1.5"):
        cfg_for(synthetic_dataset, tmp_path / "o", "--mask_ratio=1.5")


def test_warns_when_the_student_has_not_learned(synthetic_dataset, tmp_path, capsys):
    from msta.train.loop import warn_if_not_learned

    # six steps leave the tiny student near the mean: the warning says so
    train(cfg_for(synthetic_dataset, tmp_path / "short", "--steps=6", "--eval_every=0"))
    out = capsys.readouterr().out
    loss = float(csv_rows(tmp_path / "short" / "metrics.csv")[-1]["val_loss_unmasked"])
    assert loss > 0.5 and "has not learned to use its inputs" in out
    assert warn_if_not_learned({"loss_unmasked": 0.9})
    assert not warn_if_not_learned({"loss_unmasked": 0.2})
    assert not warn_if_not_learned({})


def test_mask_ratio_flag_is_what_the_saved_config_says(synthetic_dataset, tmp_path):
    final = train(cfg_for(synthetic_dataset, tmp_path / "m", "--steps=2", "--mask_ratio=0.25"))
    assert MSTAPolicy.from_pretrained(final).config.mask_ratio == 0.25


def test_dummy_tokens_take_part_in_training_and_only_token_students_take_them(
        synthetic_dataset, tmp_path):
    """--dummy_tokens appends random tokens to every training sample: they pass through
    every block of the forward that the loss is taken on, and change the trained weights."""
    seen: list[int] = []
    real = MSTAPolicy.forward

    def spy(self, batch, channels=None, mask_ratio=None, generator=None, dummy_tokens=0):
        hooks = [b.register_forward_pre_hook(lambda m, a: seen.append(a[0].shape[1]))
                 for b in self.model.blocks[:1]]
        try:
            return real(self, batch, channels, mask_ratio, generator, dummy_tokens)
        finally:
            for h in hooks:
                h.remove()

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(MSTAPolicy, "forward", spy)
        plain = train(cfg_for(synthetic_dataset, tmp_path / "a", "--steps=2", "--eval_every=0",
                              "--mask_ratio=0.0"))
        n_plain = seen[0]
        seen.clear()
        dummy = train(cfg_for(synthetic_dataset, tmp_path / "b", "--steps=2", "--eval_every=0",
                              "--mask_ratio=0.0", "--dummy_tokens=16"))
    assert seen[0] == n_plain + 16  # the training forward (validation has none)
    a, b = load_file(plain / "model.safetensors"), load_file(dummy / "model.safetensors")
    assert any(not torch.equal(a[k], b[k]) for k in a)
    with pytest.raises(ValueError, match="MSTA students only"):
        train(cfg_for(synthetic_dataset, tmp_path / "c", "--steps=1", "--policy.type=gru",
                      "--dummy_tokens=4"))


def test_sensor_dropout_removes_one_whole_physical_sensor_per_sample(synthetic_dataset, tmp_path):
    """--sensor_dropout=1: every training sample loses all tokens of one physical sensor
    (joint_pos or gravity here; the command is software and stays); the weights change."""
    from msta.train import loop

    seen: list[dict] = []
    real = loop.train_step

    def spy(*args, **kw):
        seen.append(kw["absent"])
        return real(*args, **kw)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(loop, "train_step", spy)
        plain = train(cfg_for(synthetic_dataset, tmp_path / "a", "--steps=3", "--eval_every=0",
                              "--mask_ratio=0.0"))
        assert seen == [None] * 3
        seen.clear()
        dropped = train(cfg_for(synthetic_dataset, tmp_path / "b", "--steps=3",
                                "--eval_every=0", "--mask_ratio=0.0", "--sensor_dropout=1.0"))
    assert len(seen) == 3
    for absent in seen:
        assert set(absent) == {"joint_pos", "gravity"}
        jp, g = absent["joint_pos"].numpy(), absent["gravity"].numpy()
        assert jp.shape == (16, 12) and g.shape == (16, 3)
        assert (jp.all(1) == jp.any(1)).all() and (g.all(1) == g.any(1)).all()  # whole sensors
        assert (jp.any(1) ^ g.any(1)).all()  # exactly one per sample
        assert 0 < jp.any(1).sum() < 16
    a, b = load_file(plain / "model.safetensors"), load_file(dropped / "model.safetensors")
    assert any(not torch.equal(a[k], b[k]) for k in a)
    # the baselines take it too: their placeholders stand in for the removed sensor
    gru = [train(cfg_for(synthetic_dataset, tmp_path / f"g{r}", "--steps=2", "--eval_every=0",
                         "--policy.type=gru", f"--sensor_dropout={r}")) for r in (0, 1)]
    a, b = (load_file(g / "model.safetensors") for g in gru)
    assert any(not torch.equal(a[k], b[k]) for k in a)
    from msta.data.cli import UsageError

    with pytest.raises(UsageError, match=r"sensor_dropout=1.5 must be in \[0, 1\]"):
        cfg_for(synthetic_dataset, tmp_path / "d", "--sensor_dropout=1.5")


def test_sensor_dropout_draws_the_rate_evenly_over_the_physical_sensors():
    from types import SimpleNamespace

    from msta.data.sensors import PHYSICAL_SENSORS, STUDENT_SENSORS
    from msta.train.step import draw_sensor_dropout

    student = SimpleNamespace(required_sensors=STUDENT_SENSORS, device=torch.device("cpu"))
    B = 20000
    gen = torch.Generator().manual_seed(0)
    absent = draw_sensor_dropout(student, B, 0.3, gen)
    assert set(absent) == set(PHYSICAL_SENSORS)  # never the command or the last action
    lost = torch.stack([absent[s].any(1) for s in PHYSICAL_SENSORS])  # (5, B)
    assert int(lost.sum(0).max()) == 1  # at most one sensor per sample
    assert abs(float(lost.any(0).float().mean()) - 0.3) < 0.02
    share = lost.sum(1).float() / lost.sum()
    assert (share - 1 / len(PHYSICAL_SENSORS)).abs().max() < 0.03
    again = draw_sensor_dropout(student, B, 0.3, torch.Generator().manual_seed(0))
    assert all(torch.equal(absent[s], again[s]) for s in absent)  # seeded
    assert draw_sensor_dropout(student, B, 0.0, gen) is None


def test_unmasked_share_trains_that_share_of_the_steps_with_every_token(synthetic_dataset, tmp_path):
    """--unmasked_share=p: each step trains at mask 0 with probability p, else at the
    training mask; the draws are seeded (two runs see the same steps unmasked; a resumed
    run draws the same: test_resume_after_a_crash_is_bit_identical)."""
    from msta.train import loop

    seen: list[float] = []
    real = loop.train_step

    def spy(*args, **kw):
        seen.append(args[5])  # the step's mask ratio
        return real(*args, **kw)

    runs = {}
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(loop, "train_step", spy)
        for name, share in (("none", 0.0), ("all", 1.0), ("half", 0.5), ("again", 0.5)):
            seen.clear()
            train(cfg_for(synthetic_dataset, tmp_path / name, "--steps=12", "--eval_every=0",
                          "--mask_ratio=0.5", f"--unmasked_share={share}"))
            runs[name] = list(seen)
    assert runs["none"] == [0.5] * 12 and runs["all"] == [0.0] * 12
    assert set(runs["half"]) == {0.0, 0.5}  # 12 draws at p = 0.5 (seed 0): both kinds
    assert runs["again"] == runs["half"]
    from msta.data.cli import UsageError

    with pytest.raises(UsageError, match=r"unmasked_share=2.0 must be in \[0, 1\]"):
        cfg_for(synthetic_dataset, tmp_path / "d", "--unmasked_share=2")
