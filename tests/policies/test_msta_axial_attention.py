"""MSTA with attention factorized over sensors and time (``--policy.attention=axial``): each
token block attends within one step or within one channel, the whole-window path equals the
masked one (removal and training: the gradient test of test_msta_step_attention.py)."""

from __future__ import annotations

import pytest
import torch
from msta_test_helpers import random_batch, tiny_msta  # registered by tests/conftest.py

from msta.policies.msta.axial_attention import KEY
from msta.policies.msta.axial_attention import _Grouped as Grouped

T = 5


def sequence(policy, steps: int, batch: int = 2, seed: int = 1) -> dict[str, torch.Tensor]:
    return random_batch(batch, steps, seed, policy.config.input_sensors)


def first_block_tokens(policy, seq: dict, axis: str) -> tuple[torch.Tensor, ...]:
    """The window's tokens before and after block 0 run on ``axis``'s groups, and the
    tokens' keys."""
    inputs = policy.processor.discretize(policy.as_tensors(seq))
    x, _, keys, whole = policy.model.embed_steps(inputs, 0.0)
    assert whole == T
    tokens = x[:, :keys.shape[1]]
    return tokens, Grouped(keys[0], axis, T, None)(policy.model.blocks[0], tokens), keys[0]


@pytest.mark.parametrize("axis", ["step", "channel"])
def test_a_token_block_sees_only_its_step_or_its_channel(axis):
    """Changing one reading (joint_pos channel 3 at the newest step) changes, after one block,
    exactly the tokens of its group: that step's tokens, or that channel's over the window."""
    policy = tiny_msta(T, attention="axial", num_layers=3).eval()
    seq = sequence(policy, T, batch=1)
    other = {n: v.clone() for n, v in seq.items()}
    other["joint_pos"][0, -1, 3] += 3.0
    with torch.no_grad():
        x, a, keys = first_block_tokens(policy, seq, axis)
        y, b, _ = first_block_tokens(policy, other, axis)
    changed = ((x - y).abs().amax(-1)[0] > 0).nonzero()[:, 0]
    assert changed.numel() == 1 and int(keys[changed[0]] // KEY) == 0  # one token, newest step
    changed = int(changed[0])
    moved = (a - b).abs().amax(-1)[0] > 1e-6  # (L,)
    group = (keys // KEY if axis == "step" else keys % KEY)
    assert torch.equal(moved, group == group[changed])
    assert int(moved.sum()) == (keys.numel() // T if axis == "step" else T)


def test_the_window_is_more_than_a_bag_of_steps_and_differs_from_full_attention():
    """Tokens carry their age: the same readings in another order give another action; and
    the same weights under full attention give another action again."""
    policy = tiny_msta(T, attention="axial", num_layers=2).eval()
    seq = sequence(policy, T)
    full = tiny_msta(T, num_layers=2).eval()
    full.load_state_dict(policy.state_dict())
    with torch.no_grad():
        a = policy(seq)
        b = policy({n: v.flip(1) for n, v in seq.items()})
        c = full(seq)
    assert not torch.allclose(a, b, atol=1e-4)
    assert not torch.allclose(a, c, atol=1e-4)


def test_sensor_tokens_refuse_axial_attention_in_one_line():
    from msta.policies.msta import MSTAConfig

    with pytest.raises(ValueError, match="attention='full'") as err:
        MSTAConfig(tokens="sensor", attention="axial")
    assert "\n" not in str(err.value)
