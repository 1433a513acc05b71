"""MSTA with sensor tokens (``--policy.tokens=sensor``): one token per sensor and step, while
removal still acts on single readings; a removed reading is the same as one left out, a
padded step the same as a shorter window, and the model trains, copies and saves."""

from __future__ import annotations

import pytest
import torch
from msta_test_helpers import tiny_msta  # registered by tests/conftest.py

from msta.data import sensors
from msta.policies.msta import MSTAConfig, MSTAPolicy
from msta.policies.msta.removal import num_kept
from msta.policies.msta.sensor_tokens import kept_readings

T = 5
pytestmark = pytest.mark.usefixtures("one_thread")


def windows(policy, batch: int = 3, steps: int = T, seed: int = 1) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return {n: torch.randn(batch, steps, sensors.get(n).dim, generator=g)
            for n in policy.config.input_sensors}


@pytest.fixture(scope="module")
def policy() -> MSTAPolicy:
    return tiny_msta(T, tokens="sensor").eval()


def test_a_window_is_one_token_per_sensor_and_step(policy):
    seq = windows(policy)
    inputs = policy.processor.discretize(policy.as_tensors(seq))
    x, mask, ages, _ = policy.model.embed_steps(inputs, 0.0)
    S = len(policy.config.input_sensors)
    assert x.shape == (3, S * T + policy.config.state_tokens, policy.config.dim)
    assert mask is None and ages is None  # nothing removed, nothing hidden
    assert not hasattr(policy.model, "bin_embed") or policy.model.bin_embed.weight.numel() == 0


def test_a_removed_reading_is_one_left_out(policy):
    """A sensor absent for every sample acts as the sensor left out; channels absent for a
    sample act as ``channels`` leaving them out; one removed reading moves only its sample."""
    seq = windows(policy)
    everyone = {"ang_vel": torch.ones(3, 3, dtype=torch.bool)}
    with torch.no_grad():
        left_out = policy({n: v for n, v in seq.items() if n != "ang_vel"})
        torch.testing.assert_close(policy(seq, absent=everyone), left_out, atol=1e-6, rtol=0)
        half = torch.zeros(3, 12, dtype=torch.bool)
        half[:, 6:] = True
        subset = {**seq, "joint_pos": seq["joint_pos"][..., :6]}
        torch.testing.assert_close(
            policy(seq, absent={"joint_pos": half}),
            policy(subset, channels={"joint_pos": torch.arange(6)}), atol=1e-6, rtol=0)
        one = torch.zeros(3, 12, dtype=torch.bool)
        one[0, 0] = True
        full, moved = policy(seq), policy(seq, absent={"joint_pos": one})
    assert not torch.allclose(full[0], moved[0], atol=1e-4)  # the token reads each reading
    torch.testing.assert_close(full[1:], moved[1:], atol=1e-6, rtol=0)


def test_a_padded_step_is_a_shorter_window(policy):
    seq = windows(policy)
    pad = torch.zeros(3, T, dtype=torch.bool)
    pad[:, :2] = True
    with torch.no_grad():
        padded = policy({**seq, "pad": pad})
        shorter = policy({n: v[:, 2:] for n, v in seq.items()})
    torch.testing.assert_close(padded, shorter, atol=1e-6, rtol=0)


def test_removal_draws_single_readings_at_the_scalar_ratio():
    """Sample b keeps num_kept(n_b) of its n_b present readings (padded ones removed first);
    at 90 % most sensor-step tokens keep some readings and lose others."""
    B, steps, M = 4, 6, 47
    gone = torch.zeros(B, steps, M, dtype=torch.bool)
    gone[1, :, :12] = True  # sample 1 lacks a 12-channel sensor
    pad = torch.zeros(B, steps, dtype=torch.bool)
    pad[2, :3] = True  # sample 2 starts 3 steps in
    kept = kept_readings(gone, pad, 0.9, torch.Generator().manual_seed(0))
    for b in range(B):
        n = int((~gone[b]).sum())
        want = min(num_kept(n, 0.9), int((~gone[b] & ~pad[b, :, None]).sum()))
        assert int(kept[b].sum()) == want
    assert not (kept & gone).any() and not (kept & pad[:, :, None]).any()
    tokens = kept[0, :, :12]  # one 12-reading sensor of sample 0: per step, some kept
    assert tokens.any(-1).any() and not tokens.all(-1).any()
    everything = kept_readings(gone, None, 0.0, None)
    assert torch.equal(everything, ~gone)
    # training's complete tokens: about that share of samples keeps every reading
    many = torch.zeros(400, 2, 10, dtype=torch.bool)
    mixed = kept_readings(many, None, 0.75, torch.Generator().manual_seed(1), 0.25)
    whole = mixed.flatten(1).all(1)
    assert 60 < int(whole.sum()) < 140  # ~100 of 400
    assert (mixed[~whole].flatten(1).sum(1) == num_kept(20, 0.75)).all()


def test_complete_tokens_are_trained_only(policy):
    """``complete_share`` acts in training mode only: test-time removal stays exact."""
    seq = windows(policy)
    shared = tiny_msta(T, tokens="sensor", complete_share=0.9).eval()
    plain = tiny_msta(T, tokens="sensor").eval()
    with torch.no_grad():
        a = shared(seq, mask_ratio=0.5, generator=torch.Generator().manual_seed(3))
        b = plain(seq, mask_ratio=0.5, generator=torch.Generator().manual_seed(3))
    torch.testing.assert_close(a, b, atol=0, rtol=0)


def test_training_with_removal_and_dummy_tokens_reaches_every_weight():
    policy = tiny_msta(T, tokens="sensor").train()
    seq = windows(policy, batch=4)
    absent = {"joint_pos": torch.zeros(4, 12, dtype=torch.bool)}
    absent["joint_pos"][0, :6] = True
    out = policy(seq, mask_ratio=0.75, generator=torch.Generator().manual_seed(0),
                 dummy_tokens=3, absent=absent)
    assert out.shape == (4, 12) and torch.isfinite(out).all()
    out.square().mean().backward()
    for name, p in policy.model.named_parameters():
        if p.numel():
            assert p.grad is not None and p.grad.abs().sum() > 0, name


def test_given_dummy_draws_give_the_same_action(policy):
    seq = windows(policy)
    draws = torch.rand(3, 4, 4, generator=torch.Generator().manual_seed(2))
    with torch.no_grad():
        a, b = policy(seq, dummy_tokens=draws), policy(seq, dummy_tokens=draws)
        clean = policy(seq)
    torch.testing.assert_close(a, b, atol=0, rtol=0)
    assert not torch.allclose(a, clean, atol=1e-4)  # the dummies are attended to


def test_a_copy_on_fewer_inputs_acts_the_same_and_a_saved_one_loads(policy, tmp_path):
    names = ("joint_pos", "gravity", "command")
    seq = {n: v for n, v in windows(policy).items() if n in names}
    copy = policy.with_inputs(names, T)
    policy.save_pretrained(tmp_path)
    loaded = MSTAPolicy.from_pretrained(tmp_path).eval()
    with torch.no_grad():
        torch.testing.assert_close(copy.eval()(seq), policy(seq), atol=1e-6, rtol=0)
        full = windows(policy)
        torch.testing.assert_close(loaded(full), policy(full), atol=0, rtol=0)
    assert loaded.config.tokens == "sensor"


@pytest.mark.parametrize(("kw", "message"), [
    ({"tokens": "scalars"}, "tokens must be one of"),
    ({"tokens": "sensor", "attention": "step"}, "attention='full'"),
    ({"tokens": "sensor", "learnable_mask": True}, "learnable_mask=false"),
    ({"tokens": "sensor", "input_sensors": ("joint_pos", "height_map")}, "'height_map'"),
    ({"tokens": "sensor", "complete_share": 1.0}, r"complete_share must be in \[0, 1\)"),
])
def test_bad_settings_are_one_line(kw, message):
    with pytest.raises(ValueError, match=message) as err:
        MSTAConfig(**kw)
    assert "\n" not in str(err.value)
