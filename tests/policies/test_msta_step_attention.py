"""MSTA with per-step attention (``--policy.attention=step``): the cached control step equals the
whole window's action, ages matter, removal and training work, bad settings are one line."""

from __future__ import annotations

import pytest
import torch
from msta_test_helpers import random_batch, tiny_msta  # registered by tests/conftest.py

from msta.policies.msta import MSTAConfig
from msta.policies.msta.axial_attention import axial_features
from msta.policies.msta.step_attention import step_features
from msta.policies.msta.step_stream import StepStream

T = 5


def sequence(policy, steps: int, batch: int = 2, seed: int = 1) -> dict[str, torch.Tensor]:
    return random_batch(batch, steps, seed, policy.config.input_sensors)


@pytest.mark.parametrize(("layers", "runtime"), [
    ((3, 1), "eager"), ((2, 2), "eager"), ((3, 1), "torchscript"), ((3, 1), "onnxruntime")],
    ids=["2step-1readout", "0step-2readout", "torchscript", "onnxruntime"])
def test_the_stream_acts_as_the_window_from_the_first_step_on(layers, runtime):
    """Each control step of StepStream (newest step encoded, older ones cached; in each
    runtime) gives the policy's action on the window ending there: shorter
    windows at the episode's start, then the last T steps; reset starts a new episode."""
    num_layers, readout = layers
    policy = tiny_msta(T, attention="step", num_layers=num_layers, readout_layers=readout,
                       state_tokens=2).eval()
    seq = sequence(policy, 2 * T + 1)
    stream = StepStream(policy, batch=2, runtime=runtime)
    actions = []
    for t in range(2 * T + 1):
        got = stream.step({n: v[:, t] for n, v in seq.items()})
        with torch.no_grad():
            want = policy({n: v[:, max(0, t - T + 1):t + 1] for n, v in seq.items()})
        torch.testing.assert_close(got, want, atol=1e-5, rtol=0)
        actions.append(got)
    assert not torch.allclose(actions[-1], actions[-2], atol=1e-4)  # it reads its inputs
    stream.reset()
    first = stream.step({n: v[:, 0] for n, v in seq.items()})
    torch.testing.assert_close(first, actions[0], atol=1e-6, rtol=0)


def test_the_int8_stream_is_close_to_the_window_but_not_equal():
    """``onnxruntime-int8`` runs the stream's two parts with int8 weights: its actions move
    by a little (quantization), and still follow the inputs."""
    policy = tiny_msta(T, attention="step", num_layers=3, readout_layers=1).eval()
    seq = sequence(policy, T + 2)
    stream = StepStream(policy, batch=2, runtime="onnxruntime-int8")
    for t in range(T + 2):
        got = stream.step({n: v[:, t] for n, v in seq.items()})
    with torch.no_grad():
        want = policy({n: v[:, -T:] for n, v in seq.items()})
    diff = float((got - want).abs().max())
    assert 0 < diff < 0.2 * float(want.abs().max()), diff


def test_the_readout_tells_steps_apart_by_their_age():
    """Steps' tokens carry no age, the readout adds it: the same readings in another order
    give another action (a window read as a bag of steps would give the same one)."""
    policy = tiny_msta(T, attention="step", num_layers=2).eval()
    seq = sequence(policy, T)
    with torch.no_grad():
        a = policy(seq)
        b = policy({n: v.flip(1) for n, v in seq.items()})
    assert not torch.allclose(a, b, atol=1e-4)


@pytest.mark.parametrize(("attention", "num_layers"), [("step", 2), ("axial", 3)])
def test_training_with_removal_and_dummy_tokens_reaches_every_weight(attention, num_layers):
    """Random removal (the training mask), dummy tokens and per-sample absent channels go
    through the masked blocks (per-step, or axial: a step's and a channel's tokens): finite
    loss, a gradient on every weight of the blocks and on step attention's age maps."""
    policy = tiny_msta(T, attention=attention, num_layers=num_layers, state_tokens=2).train()
    seq = sequence(policy, T, batch=4)
    absent = {"joint_pos": torch.zeros(4, 12, dtype=torch.bool)}
    absent["joint_pos"][0, :6] = True
    out = policy(seq, mask_ratio=0.5, generator=torch.Generator().manual_seed(0),
                 dummy_tokens=3, absent=absent)
    assert out.shape == (4, 12) and torch.isfinite(out).all()
    out.square().mean().backward()
    for name, p in policy.model.named_parameters():
        if name.startswith(("blocks.", "age_proj.")) and "mlp.3" not in name:
            assert p.grad is not None and p.grad.abs().sum() > 0, name


@pytest.mark.parametrize(("attention", "features"), [("step", step_features),
                                                     ("axial", axial_features)])
def test_the_whole_window_and_the_masked_path_agree(attention, features):
    """Without removal the token blocks run on reshaped groups (step: T groups of a step's
    tokens; axial: those, then n groups of a channel's); the masked path (all tokens, each
    kept to its group by a mask: the one training's removal takes) gives the same action
    on the same tokens."""
    policy = tiny_msta(T, attention=attention, num_layers=3, state_tokens=2).eval()
    seq = sequence(policy, T, batch=3)
    with torch.no_grad():
        grouped = policy(seq)
        inputs = policy.processor.discretize(policy.as_tensors(seq))
        x, mask, ages, whole = policy.model.embed_steps(inputs, 0.0)
        assert whole == T and mask is None
        masked = policy.model.head(features(policy.model, x, mask, ages, 0))
    torch.testing.assert_close(masked, grouped, atol=1e-5, rtol=0)


@pytest.mark.parametrize(("kw", "message"), [
    ({"attention": "local"}, "attention must be one of"),
    ({"readout_layers": 5}, "readout_layers must be in [1, num_layers=4]"),
    ({"readout_layers": 0}, "readout_layers must be in"),
])
def test_bad_settings_are_one_line(kw, message):
    with pytest.raises(ValueError, match=message.replace("[", r"\[")) as err:
        MSTAConfig(**kw)
    assert "\n" not in str(err.value)


def test_a_stream_needs_step_attention_and_a_known_runtime():
    with pytest.raises(ValueError, match="attention='step'"):
        StepStream(tiny_msta(T))
    with pytest.raises(ValueError, match="runtime must be one of"):
        StepStream(tiny_msta(T, attention="step", num_layers=2), runtime="tensorrt")


def test_a_stream_reads_a_sensor_subset():
    """A stream built for some sensors acts as the policy does on windows of those alone."""
    policy = tiny_msta(T, attention="step", num_layers=2).eval()
    names = ("joint_pos", "gravity", "command")
    seq = {n: v for n, v in sequence(policy, T).items() if n in names}
    stream = StepStream(policy, sensors=names, batch=2)
    for t in range(T):
        got = stream.step({n: v[:, t] for n, v in seq.items()})
    with torch.no_grad():
        torch.testing.assert_close(got, policy(seq), atol=1e-5, rtol=0)
