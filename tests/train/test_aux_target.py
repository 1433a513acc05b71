"""MSTA's auxiliary target (``--policy.aux_target``): the readout also predicts a privileged
signal from the dataset, which trains a head of its own and never changes how it acts."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from msta_test_helpers import (  # registered by tests/conftest.py
    random_batch,
    random_episode,
    tiny_msta,
)

from msta.data import sensors
from msta.data.writer import DatasetWriter
from msta.policies.factory import load_policy
from msta.policies.msta import MSTAConfig
from msta.train.cli import parse_cli
from msta.train.loop import load_windows
from msta.train.stage1 import train
from msta.train.train_config import TrainConfig

VEL = sensors.get("base_lin_vel").column
T = 5


def tiny(**overrides):
    return tiny_msta(T, **overrides)


def without_head(policy):
    """A student without the auxiliary head holding ``policy``'s other weights."""
    plain = tiny()
    plain.load_state_dict({k: v for k, v in policy.state_dict().items()
                           if not k.startswith("model.aux_head.")})
    return plain


def batch_with_velocity(B: int = 8) -> dict[str, torch.Tensor]:
    batch = random_batch(B, T)
    batch["action"] = torch.randn(B, 12)
    batch[VEL] = torch.randn(B, 3)
    return batch


@pytest.mark.parametrize("name", ["joint_pos", "nope"])
def test_only_a_privileged_sensor_can_be_the_target(name):
    with pytest.raises(ValueError, match="not a privileged sensor"):
        MSTAConfig(aux_target=name)


def test_the_loss_adds_the_weighted_auxiliary_mse_and_trains_its_head():
    policy = tiny(aux_target="base_lin_vel", aux_weight=0.5).train()
    assert policy.target_columns == ("action", VEL)
    batch = batch_with_velocity()
    total, metrics = policy.loss(batch, mask_ratio=0.0)
    assert set(metrics) == {"loss", "action_mse", "aux_mse"}
    assert total.item() == pytest.approx(metrics["loss"] + 0.5 * metrics["aux_mse"], rel=1e-5)
    total.backward()
    assert policy.model.aux_head.weight.grad.abs().sum() > 0
    plain = without_head(policy).train()
    _, m = plain.loss({k: v for k, v in batch.items() if k != VEL}, mask_ratio=0.0)
    assert m["loss"] == pytest.approx(metrics["loss"], rel=1e-6)  # the action part is as before


def test_acting_ignores_the_target_and_a_missing_column_is_named():
    policy = tiny(aux_target="base_lin_vel").eval()
    batch = batch_with_velocity()
    plain = without_head(policy).eval()
    inputs = {k: v for k, v in batch.items() if k not in ("action", VEL)}
    assert torch.equal(policy.act(inputs), plain.act(inputs))
    with pytest.raises(KeyError, match=VEL):
        policy.loss({k: v for k, v in batch.items() if k != VEL})
    with pytest.raises(ValueError, match="no aux_target"):
        plain(inputs, with_aux=True)


def test_msta_train_learns_the_target_from_the_dataset(tmp_path):
    """A dataset whose base velocity follows the command: the head learns it (its MSE falls
    far below the target's variance) and the checkpoint keeps the setting."""
    rng = np.random.default_rng(0)
    with DatasetWriter.create(tmp_path / "ds", "local/aux_test") as w:
        for i in range(12):
            ep = random_episode(40, rng)
            vx = rng.uniform(-1, 1)
            ep[sensors.get("command").column][:] = [vx, 0.0, 0.0]
            ep["action"] = np.full((40, 12), vx, dtype=np.float32)
            ep["executed_action"] = ep["action"].copy()
            ep[VEL][:] = [vx, 0.0, 0.0]
            w.add_episode(ep, {"terrain": "flat", "terrain_level": 0,
                               "source": "teacher", "round": 0, "policy": "synthetic",
                               "policy_revision": "", "seed": i})
    cfg = parse_cli(TrainConfig, [
        f"--dataset={tmp_path / 'ds'}", f"--output_dir={tmp_path / 'out'}",
        "--policy.preset=tiny", "--policy.input_sensors=[command,joint_pos,gravity]",
        "--policy.history=5", "--policy.aux_target=base_lin_vel", "--batch_size=32",
        "--steps=150", "--lr=3e-3", "--warmup_steps=2", "--progress=false", "--device=cpu",
        "--eval_every=0", "--save_every=0"], prog="msta-train")
    final = train(cfg)
    policy = load_policy(final)
    assert policy.config.aux_target == "base_lin_vel"
    windows = load_windows(tmp_path / "ds", policy, list(range(12)))
    batch = windows.get_batch(np.arange(0, len(windows), 7))
    with torch.no_grad():
        _, metrics = policy.eval().loss(batch, mask_ratio=0.0)
    variance = float(np.var(batch[VEL][:, 0]))  # ~1/3: a uniform command in [-1, 1]
    assert metrics["aux_mse"] < 0.2 * variance, (metrics, variance)
