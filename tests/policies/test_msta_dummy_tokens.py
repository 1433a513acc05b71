"""The paper's dummy-token stress test on the MSTA student: random tokens appended at test
time pass through attention like real ones and never change a parameter."""

from __future__ import annotations

import hashlib
from functools import partial

import numpy as np
import pytest
import torch
from msta_test_helpers import random_batch, tiny_msta  # registered by tests/conftest.py

from msta.policies.actor import StudentActor
from msta.policies.input_spec import InputSpec
from msta.policies.msta import MSTAPolicy

pytestmark = pytest.mark.usefixtures("one_thread")

T = 6


def make(**overrides) -> MSTAPolicy:
    """A tiny random-weight MSTA student (seeded) with unit-scale statistics."""
    return tiny_msta(T, mean=0.1, action_std=0.5, **overrides)


#: ``make_batch(B=4, seed=1)``: seeded readings of every student input (foot contacts 0/1)
make_batch = partial(random_batch, B=4, steps=T)


def param_hash(policy) -> str:
    h = hashlib.sha256()
    for name, p in sorted(policy.state_dict().items()):
        h.update(name.encode() + p.detach().cpu().numpy().tobytes())
    return h.hexdigest()


def block_lengths(policy, batch, **kwargs) -> list[int]:
    """The sequence length every block's keys see (L of its input x)."""
    seen: list[int] = []
    hooks = [b.register_forward_pre_hook(lambda m, args: seen.append(args[0].shape[1]))
             for b in policy.model.blocks]
    try:
        policy.act(batch, generator=torch.Generator().manual_seed(0), **kwargs)
    finally:
        for h in hooks:
            h.remove()
    return seen


def test_zero_dummy_tokens_is_bit_identical_and_draws_nothing() -> None:
    policy = make().eval()
    batch = make_batch()
    g0, g1 = torch.Generator().manual_seed(3), torch.Generator().manual_seed(3)
    plain = policy.act(batch, generator=g0)
    zero = policy.act(batch, generator=g1, dummy_tokens=0)
    assert torch.equal(plain, zero)
    assert torch.equal(g0.get_state(), g1.get_state())


@pytest.mark.parametrize("overrides", [{}, {"learnable_mask": True},
                                       {"value_embedding": "shared"}])
def test_dummy_tokens_are_attended_change_output_and_leave_weights(overrides) -> None:
    policy = make(**overrides).eval()
    batch = make_batch()
    before = param_hash(policy)
    base = block_lengths(policy, batch)
    more = block_lengths(policy, batch, dummy_tokens=256)
    assert len(base) == len(more) == len(policy.model.blocks)     # present in every layer
    assert [m - b for b, m in zip(base, more, strict=True)] == [256] * len(base)
    plain = policy.act(batch, generator=torch.Generator().manual_seed(0))
    noisy = policy.act(batch, generator=torch.Generator().manual_seed(0), dummy_tokens=256)
    again = policy.act(batch, generator=torch.Generator().manual_seed(0), dummy_tokens=256)
    assert torch.isfinite(noisy).all() and not torch.equal(noisy, plain)
    assert torch.equal(noisy, again)                               # seeded
    assert param_hash(policy) == before


def test_dummy_tokens_with_masking_and_padding_stay_visible() -> None:
    """Dummy tokens are appended after masking and are never hidden by the key mask."""
    policy = make().eval()
    batch = make_batch(B=3)
    pad = torch.zeros(3, T, dtype=torch.bool)
    pad[0, :2] = True                                   # sample 0 has 2 padded steps
    batch["pad"] = pad
    inputs = policy.processor.discretize(batch)
    x0, _ = policy.model.embed(inputs, 0.25, torch.Generator().manual_seed(0))
    x, mask = policy.model.embed(inputs, 0.25, torch.Generator().manual_seed(0), dummy_tokens=17)
    assert x.shape[1] == x0.shape[1] + 17
    R = policy.config.state_tokens
    assert mask is not None and mask[:, 0, 0, -(17 + R):].all()
    assert torch.equal(x[:, -R:], x0[:, -R:])                      # readout tokens last


def test_student_actor_passes_dummy_tokens_and_rejects_negative() -> None:
    policy = make().eval()
    obs = {k: v[:, -1].numpy() for k, v in make_batch(B=2).items()}
    plain = StudentActor(policy, 2, InputSpec(seed=1)).act(obs)
    zero = StudentActor(policy, 2, InputSpec(dummy_tokens=0, seed=1)).act(obs)
    noisy = StudentActor(policy, 2, InputSpec(dummy_tokens=256, seed=1)).act(obs)
    assert np.array_equal(plain, zero) and not np.array_equal(plain, noisy)
    assert np.isfinite(noisy).all()
    with pytest.raises(ValueError, match="dummy_tokens=-1 must be >= 0"):
        InputSpec(dummy_tokens=-1)


def test_given_uniforms_fix_every_samples_dummy_tokens() -> None:
    """A (B, D, 4) tensor of uniforms in place of D: per sample, the same draws give the
    same action whatever the rest of the batch holds (what PPO's re-evaluation needs)."""
    policy = make().eval()
    batch = make_batch(B=4)
    u = torch.rand(4, 9, 4, generator=torch.Generator().manual_seed(3))
    with torch.no_grad():
        out = policy(batch, dummy_tokens=u)
        plain = policy(batch)
        other = policy(batch, dummy_tokens=torch.rand(4, 9, 4))
        sub = policy({k: v[[2, 0]] for k, v in batch.items()}, dummy_tokens=u[[2, 0]])
        x, _ = policy.model.embed(policy.processor.discretize(batch), 0.0, dummy_tokens=u)
    assert x.shape[1] == policy.model.embed(policy.processor.discretize(batch), 0.0)[0].shape[1] + 9
    assert not torch.allclose(out, plain) and not torch.allclose(out, other)
    torch.testing.assert_close(sub, out[[2, 0]])
    # u = 0 picks the first table's first bin, the first slot and the first present sensor
    zero = policy.model.embed(policy.processor.discretize(batch), 0.0,
                              dummy_tokens=torch.zeros(4, 1, 4))[0][:, -1 - policy.config.state_tokens]
    m = policy.model
    want = m.bin_embed.weight[0] + m.layout(policy.processor.discretize(batch).channels, T)[0][0] \
        + m.sensor_embed[policy.config.input_sensors[0]]
    torch.testing.assert_close(zero, want.expand(4, -1))
    with pytest.raises(ValueError, match=r"\(batch=4, D, 4\)"):
        policy(batch, dummy_tokens=torch.rand(4, 9, 3))
