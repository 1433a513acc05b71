"""MSTA config registry, presets, save -> load and the policy factory."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import draccus
import pytest
import torch
from msta_test_helpers import random_batch  # registered by tests/conftest.py

from msta.data import sensors
from msta.policies.base import Policy
from msta.policies.config import PolicyConfig
from msta.policies.factory import load_policy, make_policy
from msta.policies.msta import PRESETS, MSTAConfig, MSTAPolicy
from msta.policies.registry import get_config_class, make_config, registered_policies


def stats_for(cfg: MSTAConfig) -> dict:
    g = torch.Generator().manual_seed(0)
    stats = {
        sensors.get(n).column: {
            "mean": torch.randn(sensors.get(n).dim, generator=g).tolist(),
            "std": (torch.rand(sensors.get(n).dim, generator=g) + 0.1).tolist(),
        }
        for n in cfg.input_sensors
    }
    stats["action"] = {"mean": torch.randn(12, generator=g).tolist(), "std": [0.3] * 12}
    return stats


#: ``make_batch(B=3, steps=5)``: seeded readings of every student input
make_batch = partial(random_batch, B=3, steps=5, seed=2)


def trained_policy(**overrides) -> MSTAPolicy:
    """A tiny policy after a few optimizer steps (weights differ from their init)."""
    torch.manual_seed(0)
    cfg = MSTAConfig.from_preset("tiny", **overrides)
    policy = make_policy(cfg, stats_for(cfg)).train()
    opt = torch.optim.AdamW(policy.parameters(), lr=1e-2)
    batch = {**make_batch(), "action": torch.randn(3, 12)}
    for _ in range(3):
        loss, _ = policy.loss(batch)
        opt.zero_grad()
        loss.backward()
        opt.step()
    return policy.eval()


@pytest.mark.parametrize("learnable_mask", [False, True])
def test_save_load_is_bit_identical(tmp_path: Path, learnable_mask: bool) -> None:
    policy = trained_policy(learnable_mask=learnable_mask)
    out = policy.save_pretrained(tmp_path / "ckpt")
    assert sorted(p.name for p in out.iterdir()) == [
        "config.json",
        "model.safetensors",
        "processor.json",
    ]
    loaded = load_policy(out)
    assert isinstance(loaded, MSTAPolicy) and isinstance(loaded, Policy)
    assert loaded.config == policy.config and loaded.required_sensors == sensors.STUDENT_SENSORS
    batch = make_batch()
    assert torch.equal(loaded.act(batch), policy.act(batch))
    masked = [
        p.act(batch, mask_ratio=0.5, generator=torch.Generator().manual_seed(1))
        for p in (policy, loaded)
    ]
    assert torch.equal(masked[0], masked[1])
    again = MSTAPolicy.from_pretrained(str(out), revision=None)
    assert torch.equal(again.act(batch), policy.act(batch))


def test_config_json_is_readable_and_typed(tmp_path: Path) -> None:
    trained_policy().save_pretrained(tmp_path)
    data = json.loads((tmp_path / "config.json").read_text())
    assert data["type"] == "msta" and data["dim"] == 32 and data["input_sensors"][0] == "joint_pos"
    proc = json.loads((tmp_path / "processor.json").read_text())
    assert set(proc["stats"]) == {
        "observation.joint_pos",
        "observation.joint_vel",
        "observation.ang_vel",
        "observation.gravity",
        "observation.command",
        "observation.last_action",
        "action",
    }


def test_loading_errors(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="does-not-exist"):
        load_policy(tmp_path / "does-not-exist")
    trained_policy().save_pretrained(tmp_path)
    data = json.loads((tmp_path / "config.json").read_text())
    (tmp_path / "config.json").write_text(json.dumps({**data, "num_layer": 3}))
    with pytest.raises(ValueError, match="num_layer"):
        load_policy(tmp_path)
    (tmp_path / "config.json").write_text(json.dumps({**data, "type": "gpt"}))
    with pytest.raises(ValueError, match="'gpt'"):
        load_policy(tmp_path)


def test_registry_and_draccus_cli() -> None:
    assert "msta" in registered_policies() and get_config_class("msta") is MSTAConfig
    with pytest.raises(KeyError, match="'nope'"):
        get_config_class("nope")
    assert make_config("msta", dim=64).dim == 64
    with pytest.raises(ValueError, match="dimm"):
        make_config("msta", dimm=64)

    @dataclass
    class TrainArgs:
        policy: PolicyConfig = field(default_factory=MSTAConfig)

    args = draccus.parse(
        TrainArgs,
        args=["--policy.type=msta", "--policy.num_layers=3", "--policy.learnable_mask=true"],
    )
    assert (
        isinstance(args.policy, MSTAConfig)
        and args.policy.num_layers == 3
        and args.policy.learnable_mask
    )


def test_presets_and_validation() -> None:
    paper = MSTAConfig.from_preset("paper")
    assert (paper.dim, paper.num_bins, paper.history, paper.mlp_ratio, paper.mask_ratio) == (
        128,
        256,
        15,
        2.0,
        0.75,
    )
    assert paper.num_layers == 4 and paper.num_heads == 4
    cpu = MSTAConfig.from_preset("cpu", history=7)
    assert cpu.dim < paper.dim and cpu.history == 7
    assert set(PRESETS) >= {"paper", "cpu"}
    with pytest.raises(KeyError, match="'gpu'"):
        MSTAConfig.from_preset("gpu")
    for bad, match in [
        ({"dim": 30, "num_heads": 4}, "divisible"),
        ({"mask_ratio": 1.0}, "mask_ratio"),
        ({"input_sensors": ("joint_pos", "height_scan")}, "height_scan"),
        ({"input_sensors": ("joint_pos", "jointpos")}, "jointpos"),
        ({"num_bins": 1}, "num_bins"),
    ]:
        with pytest.raises((ValueError, KeyError), match=match):
            MSTAConfig(**bad)


def test_processor_must_match_config() -> None:
    cfg = MSTAConfig.from_preset("tiny")
    small = MSTAConfig.from_preset("tiny", input_sensors=("joint_pos", "command"))
    processor = MSTAPolicy.processor_class.from_stats(small, stats_for(small))
    with pytest.raises(ValueError, match="processor sensors"):
        MSTAPolicy(cfg, processor)
