"""MSTA processor: binning, channel subsets, statistics and input errors."""

from __future__ import annotations

from functools import partial

import pytest
import torch
from msta_test_helpers import random_batch  # registered by tests/conftest.py

from msta.data import sensors
from msta.policies.msta import MSTAConfig, MSTAProcessor

CFG = MSTAConfig.from_preset("tiny")


def make_stats(seed: int = 0) -> dict[str, dict[str, list[float]]]:
    g = torch.Generator().manual_seed(seed)
    stats = {}
    for name in CFG.input_sensors:
        spec = sensors.get(name)
        stats[spec.column] = {
            "mean": torch.randn(spec.dim, generator=g).tolist(),
            "std": (torch.rand(spec.dim, generator=g) + 0.5).tolist(),
            "min": [-9.0] * spec.dim,
            "max": [9.0] * spec.dim,
        }
    stats["action"] = {
        "mean": torch.randn(12, generator=g).tolist(),
        "std": (torch.rand(12, generator=g) + 0.5).tolist(),
    }
    return stats


#: ``make_batch(B=3, steps=5, seed=1)``: seeded readings of ``CFG``'s inputs
make_batch = partial(random_batch, B=3, steps=5, names=CFG.input_sensors)


def test_bins_follow_zscore_and_clip() -> None:
    stats = make_stats()
    proc = MSTAProcessor.from_stats(CFG, stats)
    mean = torch.tensor(stats["observation.joint_pos"]["mean"])
    std = torch.tensor(stats["observation.joint_pos"]["std"])
    x = torch.stack([mean, mean + 0.1 * std, mean + 100 * std, mean - 100 * std])[
        None
    ]  # (1, 4, 12)
    bins = proc.discretize({"joint_pos": x}).bins["joint_pos"][0]  # (4, 12)
    half = CFG.num_bins // 2
    assert (bins[0] == half).all()  # z = 0 sits at the start of the upper middle bin
    expected = int(half + 0.1 * CFG.num_bins / (2 * CFG.clip_std))  # 0.1 std -> 3.2 bins up
    assert (bins[1] == expected).all()
    assert (bins[2] == CFG.num_bins - 1).all() and (bins[3] == 0).all()


def test_binary_sensor_uses_two_end_bins() -> None:
    proc = MSTAProcessor.from_stats(CFG, make_stats())
    x = torch.tensor([[[0.0, 1.0, 1.0, 0.0]]])
    bins = proc.discretize({"foot_contact": x}).bins["foot_contact"]
    assert bins.tolist() == [[[0, CFG.num_bins - 1, CFG.num_bins - 1, 0]]]


def test_channel_subset_uses_that_channels_statistics() -> None:
    proc = MSTAProcessor.from_stats(CFG, make_stats())
    batch = make_batch()
    full = proc.discretize(batch).bins["joint_vel"]
    idx = [5, 0, 11, 3]
    sub = proc.discretize({"joint_vel": batch["joint_vel"][..., idx]}, channels={"joint_vel": idx})
    assert torch.equal(sub.bins["joint_vel"], full[..., idx])
    assert sub.channels["joint_vel"].tolist() == idx


def test_action_roundtrip() -> None:
    proc = MSTAProcessor.from_stats(CFG, make_stats())
    a = torch.randn(4, 12)
    z = proc.normalize_target(a)
    assert not torch.allclose(z, a)
    torch.testing.assert_close(proc.unnormalize_action(z), a)


def test_dict_roundtrip_is_exact() -> None:
    proc = MSTAProcessor.from_stats(CFG, make_stats())
    again = MSTAProcessor.from_dict(proc.to_dict())
    batch = make_batch()
    a, b = proc.discretize(batch), again.discretize(batch)
    assert all(torch.equal(a.bins[k], b.bins[k]) for k in a.bins)


def test_missing_statistics_column_is_named() -> None:
    stats = make_stats()
    del stats["observation.joint_vel"]
    with pytest.raises(KeyError, match="observation.joint_vel"):
        MSTAProcessor.from_stats(CFG, stats)
    stats = make_stats()
    del stats["action"]
    with pytest.raises(KeyError, match="'action'"):
        MSTAProcessor.from_stats(CFG, stats)
    stats = make_stats()
    del stats["observation.gravity"]["std"]
    with pytest.raises(KeyError, match="observation.gravity.*'std'"):
        MSTAProcessor.from_stats(CFG, stats)


def test_statistics_of_wrong_length_raise() -> None:
    stats = make_stats()
    stats["observation.ang_vel"]["mean"] = [0.0, 0.0]
    with pytest.raises(ValueError, match="observation.ang_vel"):
        MSTAProcessor.from_stats(CFG, stats)


def test_unknown_and_non_input_sensors_raise() -> None:
    proc = MSTAProcessor.from_stats(CFG, make_stats())
    batch = make_batch()
    with pytest.raises(KeyError, match="joint_posiiton"):
        proc.discretize({**batch, "joint_posiiton": batch["joint_pos"]})
    with pytest.raises(ValueError, match="'base_lin_vel' is not an input"):
        proc.discretize({**batch, "base_lin_vel": torch.zeros(3, 5, 3)})


def test_nan_input_names_the_sensor() -> None:
    proc = MSTAProcessor.from_stats(CFG, make_stats())
    batch = make_batch()
    batch["gravity"][1, 2, 0] = float("nan")
    with pytest.raises(ValueError, match="'gravity'.*NaN"):
        proc.discretize(batch)


@pytest.mark.parametrize(
    "bad",
    [
        {"channels": {"joint_pos": [0, 1]}},  # 12 channels supplied, 2 declared
        {"channels": {"joint_pos": [0] * 12}},  # duplicates
        {"channels": {"joint_pos": list(range(1, 13))}},  # index 12 out of range
    ],
)
def test_bad_channel_declarations_raise(bad: dict) -> None:
    proc = MSTAProcessor.from_stats(CFG, make_stats())
    with pytest.raises(ValueError, match="joint_pos"):
        proc.discretize(make_batch(), **bad)


def test_mismatched_windows_and_bad_pad_raise() -> None:
    proc = MSTAProcessor.from_stats(CFG, make_stats())
    batch = make_batch()
    with pytest.raises(ValueError, match="'command'"):
        proc.discretize({**batch, "command": torch.zeros(3, 4, 3)})
    pad = torch.zeros(3, 5, dtype=torch.bool)
    pad[0, -1] = True
    with pytest.raises(ValueError, match="newest step"):
        proc.discretize({**batch, "pad": pad})
    with pytest.raises(ValueError, match="'pad'"):
        proc.discretize({**batch, "pad": torch.zeros(3, 5)})
