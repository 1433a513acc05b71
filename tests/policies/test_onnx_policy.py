"""OnnxMSTA: an MSTA policy's network as one ONNX Runtime graph acts as the policy does."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from msta_test_helpers import tiny_msta

from msta.data import sensors
from msta.policies.msta.onnx_policy import OnnxMSTA

T = 3


def _batch(policy, n: int = 6, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    batch = {s: rng.standard_normal((n, T, sensors.get(s).dim)).astype(np.float32)
             for s in policy.required_sensors}
    if "foot_contact" in batch:
        batch["foot_contact"] = (batch["foot_contact"] > 0).astype(np.float32)
    pad = np.zeros((n, T), dtype=bool)
    pad[1, :2] = True  # an episode's first step: two padded steps
    pad[2, :1] = True
    batch["pad"] = pad
    return batch


DESIGNS = [{"attention": "full"}, {"attention": "step"}, {"attention": "axial"},
           {"tokens": "sensor"}]


@pytest.mark.parametrize("design", DESIGNS, ids=["full", "step", "axial", "sensor_tokens"])
@pytest.mark.parametrize("mask_ratio", [0.0, 0.5])
def test_the_fp32_graph_acts_as_the_policy(design: dict, mask_ratio: float) -> None:
    policy = tiny_msta(T, **design).eval()
    graph = OnnxMSTA(policy, num_threads=1)
    batch = _batch(policy)
    want = policy.act(batch, mask_ratio=mask_ratio, generator=torch.Generator().manual_seed(3))
    got = graph.act(batch, mask_ratio=mask_ratio, generator=torch.Generator().manual_seed(3))
    assert torch.allclose(got, want, atol=1e-4), float((got - want).abs().max())
    other = graph.act(batch, mask_ratio=mask_ratio, generator=torch.Generator().manual_seed(4))
    if mask_ratio:  # another draw removes other tokens: the graph does read the mask
        assert not torch.allclose(other, want, atol=1e-4)


@pytest.mark.parametrize("design", DESIGNS[::2], ids=["scalar_tokens", "sensor_tokens"])
def test_the_int8_graph_is_close_but_not_equal(design: dict) -> None:
    policy = tiny_msta(T, **design).eval()
    batch = _batch(policy, n=32, seed=1)
    want = policy.act(batch)
    got = OnnxMSTA(policy, int8=True, num_threads=1).act(batch)
    diff = float((got - want).abs().max())
    assert 0 < diff < 0.2 * float(want.abs().max()), diff


def test_what_the_graph_cannot_do_is_refused() -> None:
    policy = tiny_msta(T).eval()
    graph = OnnxMSTA(policy, num_threads=1)
    with pytest.raises(NotImplementedError, match="every channel"):
        graph.act(_batch(policy), channels={"joint_pos": [0, 1]})
    short = {k: v[:, 1:] for k, v in _batch(policy).items()}
    with pytest.raises(ValueError, match="windows of 3 steps, got 2"):
        graph.act(short)
    with pytest.raises(ValueError, match="learnable_mask"):
        OnnxMSTA(tiny_msta(T, learnable_mask=True))
