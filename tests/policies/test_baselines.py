"""Baseline students (GRU, RMA TCN, TERT concat / separate / mask): the MSTA contract tests
plus the placeholder behaviour for missing inputs."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import draccus
import pytest
import torch
from msta_test_helpers import overfit, random_batch  # registered by tests/conftest.py

from msta.data import sensors
from msta.policies.baselines import BASELINES, REFERENCES, TCNConfig, TERTMaskConfig, TimestepPolicy
from msta.policies.baselines.common import random_input_mask
from msta.policies.config import PolicyConfig
from msta.policies.factory import load_policy, make_policy
from msta.policies.registry import get_config_class, make_config, registered_policies

T = 15  # the paper's window (RMA's convolutions need >= 12 steps)
#: every registered baseline and reference learner, plus the TCN variant that accepts any
#: window length
CASES = [(name, {}) for name in BASELINES + REFERENCES] + [("rma_tcn", {"readout": "mean"})]
IDS = [n + ("-mean" if o else "") for n, o in CASES]
#: baselines that run on windows of another length than their training one
ANY_T = [c for c in CASES if c not in (("rma_tcn", {}), ("mlp", {}))]


pytestmark = pytest.mark.usefixtures("one_thread")


def stats_for(names=sensors.STUDENT_SENSORS) -> dict[str, dict[str, list[float]]]:
    g = torch.Generator().manual_seed(0)
    stats = {
        sensors.get(n).column: {
            "mean": (0.3 * torch.randn(sensors.get(n).dim, generator=g)).tolist(),
            "std": (torch.rand(sensors.get(n).dim, generator=g) + 0.5).tolist(),
        }
        for n in names
        if not sensors.get(n).binary
    }
    stats["action"] = {"mean": (0.1 * torch.randn(12, generator=g)).tolist(), "std": [0.5] * 12}
    return stats


def make(name: str, overrides: dict | None = None, **more) -> TimestepPolicy:
    torch.manual_seed(0)
    cfg = get_config_class(name).from_preset("tiny", history=T, **(overrides or {}), **more)
    return make_policy(cfg, stats_for(cfg.input_sensors))


#: ``make_batch(B=4, steps=T, seed=1, names=None)``: seeded readings of the student inputs
make_batch = partial(random_batch, B=4, steps=T)


def randomize_placeholders(policy: TimestepPolicy) -> None:
    with torch.no_grad():
        policy.placeholder.copy_(
            torch.randn(policy.num_inputs, generator=torch.Generator().manual_seed(9))
        )


def raw_placeholder(policy: TimestepPolicy, name: str, B: int, steps: int) -> torch.Tensor:
    """The raw values of sensor ``name`` whose normalization equals its placeholders."""
    stats = policy.processor.stats[sensors.get(name).column]
    z = policy.placeholder.detach()[policy.processor.columns(name)]
    raw = torch.tensor(stats["mean"]) + z * torch.tensor(stats["std"])
    return raw.expand(B, steps, -1).clone()


# --- registry, presets, config --------------------------------------------------------
def test_registry_presets_and_draccus() -> None:
    assert set(BASELINES + REFERENCES) <= set(registered_policies())
    for name in BASELINES + REFERENCES:
        cls = get_config_class(name)
        assert {"paper", "cpu", "tiny"} <= set(cls.PRESETS)
        paper, cpu = cls.from_preset("paper"), cls.from_preset("cpu")
        assert paper.type == name and paper.history == 15
        assert sum(p.numel() for p in make_policy(cpu, stats_for()).parameters()) <= sum(
            p.numel() for p in make_policy(paper, stats_for()).parameters()
        )
        with pytest.raises(KeyError, match="'gpu'"):
            cls.from_preset("gpu")
    assert (
        make_config("tert_mask").mask_ratio == 0.75 and make_config("tert_concat").mask_ratio == 0
    )
    with pytest.raises(ValueError, match="hiden_dim"):
        make_config("gru", hiden_dim=3)

    @dataclass
    class TrainArgs:
        policy: PolicyConfig = field(default_factory=TERTMaskConfig)

    args = draccus.parse(
        TrainArgs, args=["--policy.type=rma_tcn", "--policy.readout=mean", "--policy.history=12"]
    )
    assert isinstance(args.policy, TCNConfig) and args.policy.readout == "mean"


@pytest.mark.parametrize(
    "name, bad, match",
    [
        ("tert_separate", {"input_sensors": ("joint_pos", "command")}, "last_action"),
        ("tert_concat", {"dim": 30, "num_heads": 4}, "divisible"),
        ("tert_mask", {"mask_ratio": 1.0}, "mask_ratio"),
        ("gru", {"input_sensors": ("joint_pos", "height_scan")}, "height_scan"),
        ("gru", {"input_sensors": ("joint_pos", "jointpos")}, "jointpos"),
        ("rma_tcn", {"conv_kernels": (4, 3), "conv_strides": (2, 1, 1)}, "equal length"),
        ("rma_tcn", {"history": 7}, "shorter than the convolutions need .12."),
        ("rma_tcn", {"readout": "max"}, "readout"),
        ("mlp", {"hidden_dims": ()}, "hidden_dims"),
        ("mlp", {"hidden_dims": (64, 0)}, "hidden_dims"),
    ],
)
def test_config_validation(name: str, bad: dict, match: str) -> None:
    with pytest.raises((ValueError, KeyError), match=match):
        get_config_class(name)(**bad)


# --- shapes, loss, save/load ----------------------------------------------------------
@pytest.mark.parametrize("name, overrides", CASES, ids=IDS)
def test_shapes_loss_and_gradients(name: str, overrides: dict) -> None:
    policy = make(name, overrides).train()
    batch = make_batch()
    action = policy.act(batch)
    assert action.shape == (4, 12) and torch.isfinite(action).all()
    loss, metrics = policy.loss({**batch, "action": torch.randn(4, 12)}, mask_ratio=0.3)
    loss.backward()
    assert set(metrics) == {"loss", "action_mse"} and metrics["loss"] == pytest.approx(loss.item())
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in policy.parameters())
    with pytest.raises(KeyError, match="'action'"):
        policy.loss(batch)


@pytest.mark.parametrize("name, overrides", CASES, ids=IDS)
def test_save_load_is_bit_identical(tmp_path: Path, name: str, overrides: dict) -> None:
    policy = make(name, overrides).train()
    opt = torch.optim.AdamW(policy.parameters(), lr=1e-2)
    batch = make_batch()
    for _ in range(3):  # weights (and placeholders) move away from their init
        loss, _ = policy.loss({**batch, "action": torch.randn(4, 12)}, mask_ratio=0.5)
        opt.zero_grad()
        loss.backward()
        opt.step()
    policy.eval()
    out = policy.save_pretrained(tmp_path / name)
    assert sorted(p.name for p in out.iterdir()) == [
        "config.json",
        "model.safetensors",
        "processor.json",
    ]
    assert json.loads((out / "config.json").read_text())["type"] == name
    loaded = load_policy(out)
    assert type(loaded) is type(policy) and loaded.config == policy.config
    assert torch.equal(loaded.placeholder, policy.placeholder)
    assert torch.equal(loaded.act(batch), policy.act(batch))
    minimal = {k: batch[k] for k in ("command", "joint_pos", "gravity", "last_action")}
    assert torch.equal(loaded.act(minimal), policy.act(minimal))
    masked = [
        p.act(batch, mask_ratio=0.5, generator=torch.Generator().manual_seed(1))
        for p in (policy, loaded)
    ]
    assert torch.equal(masked[0], masked[1])


@pytest.mark.parametrize("name, overrides", CASES, ids=IDS)
def test_overfits_a_tiny_dataset(name: str, overrides: dict) -> None:
    policy = make(name, overrides, mask_ratio=0.0).train()
    g = torch.Generator().manual_seed(5)
    batch = make_batch(B=16, seed=5)
    batch["action"] = torch.tanh(batch["joint_pos"][:, -1] @ torch.randn(12, 12, generator=g) / 3)
    first, final = overfit(policy, batch)
    assert final < first / 10, (first, final)


# --- flexible inputs ------------------------------------------------------------------
@pytest.mark.parametrize("name, overrides", CASES, ids=IDS)
def test_removed_sensor_reads_its_placeholders(name: str, overrides: dict) -> None:
    policy = make(name, overrides).eval()
    randomize_placeholders(policy)
    batch = make_batch()
    removed = {k: v for k, v in batch.items() if k != "joint_vel"}
    out = policy.act(removed)
    assert out.shape == (4, 12) and torch.isfinite(out).all()
    assert not torch.allclose(out, policy.act(batch), atol=1e-5)
    as_placeholder = {**batch, "joint_vel": raw_placeholder(policy, "joint_vel", 4, T)}
    torch.testing.assert_close(out, policy.act(as_placeholder), rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize("name, overrides", CASES, ids=IDS)
def test_dead_joints_read_their_placeholders(name: str, overrides: dict) -> None:
    policy = make(name, overrides).eval()
    randomize_placeholders(policy)
    batch = make_batch()
    alive = [j for j in range(12) if j not in (4, 9)]
    dead = {
        **batch,
        "joint_pos": batch["joint_pos"][..., alive],
        "joint_vel": batch["joint_vel"][..., alive],
    }
    out = policy.act(dead, channels={"joint_pos": alive, "joint_vel": alive})
    assert out.shape == (4, 12) and torch.isfinite(out).all()
    filled = {k: v.clone() for k, v in batch.items()}
    for s in ("joint_pos", "joint_vel"):
        filled[s][..., [4, 9]] = raw_placeholder(policy, s, 4, T)[..., [4, 9]]
    torch.testing.assert_close(out, policy.act(filled), rtol=1e-4, atol=1e-5)
    assert not torch.allclose(out, policy.act(batch), atol=1e-5)


def test_channel_identity_comes_from_the_declaration() -> None:
    policy = make("tert_concat").eval()
    batch = make_batch()
    perm = [3, 7, 0, 11, 1, 2, 4, 5, 6, 8, 9, 10]
    shuffled = {**batch, "joint_pos": batch["joint_pos"][..., perm]}
    torch.testing.assert_close(
        policy.act(shuffled, channels={"joint_pos": perm}), policy.act(batch), rtol=1e-5, atol=1e-6
    )


@pytest.mark.parametrize("name, overrides", ANY_T, ids=[IDS[CASES.index(c)] for c in ANY_T])
def test_other_window_lengths(name: str, overrides: dict) -> None:
    policy = make(name, overrides).eval()
    for steps in (12, T + 1, 20) + ((1,) if name != "rma_tcn" else ()):
        out = policy.act(make_batch(steps=steps))
        assert out.shape == (4, 12) and torch.isfinite(out).all()


def test_mlp_window_length_errors() -> None:
    mlp = make("mlp").eval()
    assert mlp.act(make_batch(steps=T)).shape == (4, 12)
    for steps in (T - 1, T + 5):
        with pytest.raises(ValueError, match=f"training length T=15; got T={steps}"):
            mlp.act(make_batch(steps=steps))


def test_tcn_window_length_errors() -> None:
    flat = make("rma_tcn").eval()
    with pytest.raises(ValueError, match=r"readout='flatten'.*T=15; got T=20"):
        flat.act(make_batch(steps=20))
    pooled = make("rma_tcn", {"readout": "mean"}).eval()
    assert pooled.config.min_steps == 12  # kernels 4/3/3, strides 2/1/1: 12 -> 5 -> 3 -> 1
    short = pooled.config.min_steps - 1
    with pytest.raises(
        ValueError, match=f"at least {pooled.config.min_steps} steps, got T={short}"
    ):
        pooled.act(make_batch(steps=short))


@pytest.mark.parametrize("name, overrides", CASES, ids=IDS)
def test_padded_steps_repeat_the_first_real_frame(name: str, overrides: dict) -> None:
    """Whatever sits in padded steps is replaced by the first real frame (data convention)."""
    policy = make(name, overrides).eval()
    batch = make_batch(B=2)
    pad = torch.zeros(2, T, dtype=torch.bool)
    pad[0, :2] = True
    garbage, repeated = ({k: v.clone() for k, v in batch.items()} for _ in range(2))
    for g, r in zip(garbage.values(), repeated.values()):
        g[0, :2] = 7.0
        r[0, :2] = r[0, 2]
    out = policy.act({**garbage, "pad": pad})
    torch.testing.assert_close(out, policy.act({**repeated, "pad": pad}), rtol=1e-5, atol=1e-6)
    if name.startswith("tert"):  # padded steps are also hidden from attention
        short = policy.act({k: v[:1, 2:] for k, v in batch.items()})
        torch.testing.assert_close(out[:1], short, rtol=1e-5, atol=1e-5)
    bad = pad.clone()
    bad[1, 3] = True
    with pytest.raises(ValueError, match="prefix"):
        policy.act({**batch, "pad": bad})


def test_random_input_mask_counts() -> None:
    missing = torch.zeros(49, dtype=torch.bool)
    missing[12:24] = True  # joint_vel removed: never counted, already a placeholder
    g = torch.Generator().manual_seed(0)
    hide = random_input_mask(missing, 3, T, 0.25, g)
    assert hide.sum((1, 2)).tolist() == [round(0.25 * T * 37)] * 3
    assert not hide[:, :, 12:24].any()
    assert not torch.equal(hide[0], hide[1])


@pytest.mark.parametrize("name, overrides", CASES, ids=IDS)
def test_sensor_order_and_test_time_masks(name: str, overrides: dict) -> None:
    policy = make(name, overrides).train()
    batch = make_batch()
    reordered = {k: batch[k] for k in reversed(list(batch))}
    for alpha in (0.0, 0.5):
        a, b = (
            policy(x, mask_ratio=alpha, generator=torch.Generator().manual_seed(3))
            for x in (batch, reordered)
        )
        assert torch.equal(a, b)
    policy.eval()
    masked = policy.act(batch, mask_ratio=0.5, generator=torch.Generator().manual_seed(4))
    assert torch.isfinite(masked).all() and not torch.allclose(masked, policy.act(batch))


def test_tert_mask_trains_its_placeholders() -> None:
    policy = make("tert_mask").train()
    loss, _ = policy.loss({**make_batch(), "action": torch.zeros(4, 12)})  # config: 75 % masked
    loss.backward()
    assert (policy.placeholder.grad != 0).sum() > 40
    plain = make("tert_concat").train()
    loss, _ = plain.loss({**make_batch(), "action": torch.zeros(4, 12)})  # mask_ratio 0
    loss.backward()
    assert plain.placeholder.grad is None or not plain.placeholder.grad.any()


# --- errors and input types -----------------------------------------------------------
def test_input_errors_name_the_culprit() -> None:
    policy = make("gru").eval()
    batch = make_batch()
    with pytest.raises(KeyError, match="joint_posiiton"):
        policy.act({**batch, "joint_posiiton": batch["joint_pos"]})
    with pytest.raises(ValueError, match="'base_lin_vel' is not an input"):
        policy.act({**batch, "base_lin_vel": torch.zeros(4, T, 3)})
    nan = {k: v.clone() for k, v in batch.items()}
    nan["gravity"][1, 2, 0] = float("nan")
    with pytest.raises(ValueError, match="'gravity'.*NaN"):
        policy.act(nan)
    with pytest.raises(ValueError, match="'command'"):
        policy.act({**batch, "command": torch.zeros(4, T - 1, 3)})
    with pytest.raises(ValueError, match="joint_pos"):
        policy.act(batch, channels={"joint_pos": [0, 1]})
    with pytest.raises(ValueError, match="no input sensor"):
        policy.act({"pad": torch.zeros(4, T, dtype=torch.bool)})


def test_missing_statistics_are_named() -> None:
    cfg = get_config_class("tert_separate").from_preset("tiny")
    stats = stats_for()
    del stats["observation.joint_vel"]
    with pytest.raises(KeyError, match="observation.joint_vel"):
        make_policy(cfg, stats)
    stats = stats_for()
    del stats["action"]
    with pytest.raises(KeyError, match="'action'"):
        make_policy(cfg, stats)
    stats = stats_for()
    stats["observation.ang_vel"]["std"] = [1.0, 1.0]
    with pytest.raises(ValueError, match="observation.ang_vel"):
        make_policy(cfg, stats)


def test_loading_errors(tmp_path: Path) -> None:
    make("rma_tcn").save_pretrained(tmp_path)
    data = json.loads((tmp_path / "config.json").read_text())
    (tmp_path / "config.json").write_text(json.dumps({**data, "conv_kernel": [3]}))
    with pytest.raises(ValueError, match="conv_kernel"):
        load_policy(tmp_path)
    (tmp_path / "config.json").write_text(json.dumps(data))
    proc = json.loads((tmp_path / "processor.json").read_text())
    (tmp_path / "processor.json").write_text(json.dumps({**proc, "format": "msta-processor/1"}))
    with pytest.raises(ValueError, match="msta-processor/1"):
        load_policy(tmp_path)


def test_numpy_batches_and_training_after_inference_mode() -> None:
    policy = make("tert_separate").eval()
    batch = {**make_batch(), "pad": torch.zeros(4, T, dtype=torch.bool)}
    as_numpy = {k: v.numpy() for k, v in batch.items()}
    assert torch.equal(policy.act(as_numpy), policy.act(batch))
    with torch.inference_mode():
        policy.act(batch, mask_ratio=0.5)
    loss, _ = policy.train().loss({**as_numpy, "action": torch.zeros(4, 12).numpy()})
    loss.backward()
    assert policy.state_token.grad is not None
