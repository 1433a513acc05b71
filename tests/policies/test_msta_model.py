"""MSTA model: masking token counts, order invariance, flexible inputs, padding, learning."""

from __future__ import annotations

from functools import partial

import pytest
import torch
from msta_test_helpers import overfit, random_batch  # registered by tests/conftest.py

from msta.data import sensors
from msta.policies.factory import make_policy
from msta.policies.msta import MSTAConfig, MSTAPolicy

T = 6


pytestmark = pytest.mark.usefixtures("one_thread")


def stats_for(cfg: MSTAConfig) -> dict[str, dict[str, list[float]]]:
    g = torch.Generator().manual_seed(0)
    stats = {
        sensors.get(n).column: {
            "mean": (0.1 * torch.randn(sensors.get(n).dim, generator=g)).tolist(),
            "std": [1.0] * sensors.get(n).dim,
        }
        for n in cfg.input_sensors
    }
    stats["action"] = {"mean": [0.0] * 12, "std": [0.5] * 12}
    return stats


def make(**overrides) -> MSTAPolicy:
    torch.manual_seed(0)
    cfg = MSTAConfig.from_preset("tiny", history=T, **overrides)
    return make_policy(cfg, stats_for(cfg))


#: ``make_batch(B=4, steps=T, seed=1, names=None)``: seeded readings of the student inputs
make_batch = partial(random_batch, B=4, steps=T)


def tokens(policy: MSTAPolicy, batch, mask_ratio: float, channels=None, seed: int = 0):
    inputs = policy.processor.discretize(batch, channels)
    return policy.model.embed(inputs, mask_ratio, torch.Generator().manual_seed(seed))


@pytest.mark.parametrize("alpha", [0.0, 0.25, 0.5, 0.75, 0.9])
def test_masking_removes_round_alpha_n_tokens(alpha: float) -> None:
    policy = make()
    n = 49 * T
    x, attn_mask = tokens(policy, make_batch(), alpha)
    assert x.shape == (4, n - round(alpha * n) + 1, 32)
    assert attn_mask is None
    # the last token is <S>, the kept tokens differ from sample to sample
    assert torch.equal(x[:, -1], policy.model.state_token.expand(4, -1))
    if alpha > 0:
        assert not torch.allclose(x[0, :-1].sort(0).values, x[1, :-1].sort(0).values)


def test_learnable_mask_keeps_all_tokens() -> None:
    policy = make(learnable_mask=True)
    n, alpha = 49 * T, 0.75
    x, attn_mask = tokens(policy, make_batch(), alpha)
    assert x.shape == (4, n + 1, 32) and attn_mask is None
    unmasked, _ = tokens(policy, make_batch(), 0.0)
    replaced = (x[:, :-1] != unmasked[:, :-1]).any(-1)  # (B, N) tokens whose value was replaced
    assert replaced.sum(1).tolist() == [round(alpha * n)] * 4
    inputs = policy.processor.discretize(make_batch())
    static = unmasked[:, :-1] - policy.model.bin_embed(policy.model.rows(inputs))  # pos + type
    torch.testing.assert_close(
        x[:, :-1][replaced] - static[replaced],
        policy.model.mask_token.expand(int(replaced.sum()), -1),
    )


def test_learnable_mask_fills_removed_sensors_and_dead_joints_with_mask_tokens() -> None:
    """The paper's "w/ learnable mask" fallback: absent inputs become mask tokens."""
    policy = make(learnable_mask=True)
    n = 49 * T
    full, _ = tokens(policy, make_batch(), 0.0)
    keep = [j for j in range(12) if j not in (1, 5)]
    batch = {k: v for k, v in make_batch().items() if k != "joint_vel"}
    batch["joint_pos"] = batch["joint_pos"][..., keep]
    x, attn_mask = tokens(policy, batch, 0.0, channels={"joint_pos": keep})
    assert x.shape == (4, n + 1, 32) and attn_mask is None
    replaced = (x[:, :-1] != full[:, :-1]).any(-1)  # (B, N)
    # 12 joint_vel channels and 2 joint_pos channels at each of the T steps
    assert replaced.sum(1).tolist() == [(12 + 2) * T] * 4


def test_sensor_order_does_not_matter() -> None:
    policy = make().train()
    batch = make_batch()
    reordered = {k: batch[k] for k in reversed(list(batch))}
    assert list(reordered) != list(batch)
    for alpha in (0.0, 0.75):
        a = policy(batch, mask_ratio=alpha, generator=torch.Generator().manual_seed(3))
        b = policy(reordered, mask_ratio=alpha, generator=torch.Generator().manual_seed(3))
        assert torch.equal(a, b)


def test_channel_identity_comes_from_embeddings() -> None:
    """Supplying joint_pos channels in another order (declared) gives the same action."""
    policy = make().eval()
    batch = make_batch()
    perm = [3, 7, 0, 11, 1, 2, 4, 5, 6, 8, 9, 10]
    shuffled = {**batch, "joint_pos": batch["joint_pos"][..., perm]}
    torch.testing.assert_close(
        policy.act(shuffled, channels={"joint_pos": perm}), policy.act(batch), rtol=1e-5, atol=1e-5
    )
    # ...while the same shuffled values without the declaration are a different input
    assert not torch.allclose(policy.act(shuffled), policy.act(batch), atol=1e-5)


@pytest.mark.parametrize("steps", [1, 7, 15, 20])
def test_any_window_length(steps: int) -> None:
    policy = make().eval()
    x, _ = tokens(policy, make_batch(steps=steps), 0.0)
    assert x.shape[1] == 49 * steps + 1
    action = policy.act(make_batch(steps=steps))
    assert action.shape == (4, 12) and torch.isfinite(action).all()


def test_newest_steps_keep_their_positions_when_the_window_grows() -> None:
    policy = make()
    chans = {"joint_pos": torch.arange(12)}
    pos15, _, _ = policy.model.layout(chans, 15)
    pos20, _, _ = policy.model.layout(chans, 20)
    assert torch.equal(pos20[-15 * 12 :], pos15)  # ages 0..14 match; T = 20 adds ages 15..19


def test_sensor_and_channel_subsets() -> None:
    policy = make().eval()
    minimal = make_batch(names=("command", "joint_pos", "gravity", "last_action"))
    x, _ = tokens(policy, minimal, 0.0)
    assert x.shape[1] == (3 + 12 + 3 + 12) * T + 1
    assert policy.act(minimal).shape == (4, 12)
    # dead encoder of joint 4: q_4 and q̇_4 disappear, no placeholders
    alive = [j for j in range(12) if j != 4]
    batch = make_batch()
    dead = {
        **batch,
        "joint_pos": batch["joint_pos"][..., alive],
        "joint_vel": batch["joint_vel"][..., alive],
    }
    channels = {"joint_pos": alive, "joint_vel": alive}
    x, _ = tokens(policy, dead, 0.5, channels)
    n = (49 - 2) * T
    assert x.shape[1] == n - round(0.5 * n) + 1
    out = policy.act(dead, channels=channels)
    assert out.shape == (4, 12) and torch.isfinite(out).all()
    assert not torch.allclose(out, policy.act(batch))


@pytest.mark.parametrize("state_tokens", [1, 3])
def test_padded_steps_are_ignored(state_tokens: int) -> None:
    """A sample padded at the start acts like its unpadded, shorter window, alone or batched."""
    policy = make(state_tokens=state_tokens).eval()
    batch = make_batch(B=2)
    pad = torch.zeros(2, T, dtype=torch.bool)
    pad[0, :2] = True  # sample 0 starts 2 steps into its window
    garbage = {k: v.clone() for k, v in batch.items()}
    for v in garbage.values():
        v[0, :2] = 7.0
    short = {k: v[:1, 2:] for k, v in batch.items()}
    reference = policy.act(short)  # (1, 12)
    alone = policy.act({**{k: v[:1] for k, v in garbage.items()}, "pad": pad[:1]})
    together = policy.act({**garbage, "pad": pad})
    torch.testing.assert_close(alone, reference, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(together[:1], reference, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(
        together[1:], policy.act({k: v[1:] for k, v in batch.items()}), rtol=1e-5, atol=1e-5
    )


def test_padding_is_masked_first_and_counts_stay_equal() -> None:
    policy = make()
    batch = make_batch(B=3)
    pad = torch.zeros(3, T, dtype=torch.bool)
    pad[0, :3] = True  # 3 * 49 padded tokens in sample 0
    n = 49 * T
    x, attn_mask = tokens(policy, {**batch, "pad": pad}, 0.75)  # drops 220 >= 147 padded tokens
    assert x.shape[1] == n - round(0.75 * n) + 1 and attn_mask is None
    x, attn_mask = tokens(policy, {**batch, "pad": pad}, 0.25)  # 74 < 147: the rest is key-masked
    assert x.shape[1] == n - round(0.25 * n) + 1
    assert attn_mask.shape == (3, 1, 1, x.shape[1])
    hidden = (~attn_mask[:, 0, 0]).sum(1).tolist()
    assert hidden == [3 * 49 - round(0.25 * n), 0, 0]
    assert attn_mask[:, 0, 0, -1].all()  # <S> is always visible


def test_readout_tokens_end_the_sequence_and_all_reach_the_head(tmp_path) -> None:
    """state_tokens = R appends R learnable tokens (<S> last), always visible; the head reads
    all R (each gets a gradient); a checkpoint restores them bit for bit."""
    policy = make(state_tokens=3)
    batch = make_batch(B=3)
    pad = torch.zeros(3, T, dtype=torch.bool)
    pad[0, :3] = True
    x, attn_mask = tokens(policy, {**batch, "pad": pad}, 0.25)
    n = 49 * T
    assert x.shape == (3, n - round(0.25 * n) + 3, 32)
    assert torch.equal(x[:, -1], policy.model.state_token.expand(3, -1))
    assert torch.equal(x[:, -3:-1], policy.model.extra_state_tokens.expand(3, -1, -1))
    assert attn_mask[:, 0, 0, -3:].all()
    loss, _ = policy.loss({**batch, "action": torch.randn(3, 12)})
    loss.backward()
    assert policy.model.extra_state_tokens.grad.abs().sum(1).min() > 0
    assert policy.model.state_token.grad.abs().sum() > 0
    with pytest.raises(ValueError, match="state_tokens"):
        MSTAConfig.from_preset("tiny", state_tokens=0)
    policy.eval()
    again = MSTAPolicy.from_pretrained(policy.save_pretrained(tmp_path / "ckpt"))
    assert again.config.state_tokens == 3
    assert torch.equal(again.act(batch), policy.act(batch))


@pytest.mark.parametrize("state_tokens", [1, 3])
def test_the_last_block_computes_only_the_readout_rows(state_tokens: int) -> None:
    """forward runs its last block for the R readout tokens only; every block run in full
    and then read at those R rows gives the same action (up to float rounding)."""
    policy = make(state_tokens=state_tokens, num_layers=2).eval()
    batch = make_batch(B=3)
    batch["pad"] = torch.zeros(3, T, dtype=torch.bool)
    batch["pad"][1, :2] = True  # a key mask in play
    m = policy.model
    inputs = policy.processor.discretize(batch)
    x, attn_mask = m.embed(inputs, 0.0)
    for block in m.blocks:
        x = block(x, attn_mask)  # (B, L, d): every row
    full = m.head(m.ln_f(x[:, -state_tokens:]).flatten(1))
    with torch.no_grad():
        torch.testing.assert_close(policy(batch), full, atol=1e-6, rtol=0)


def test_loss_and_gradients() -> None:
    policy = make().train()
    batch = {**make_batch(), "action": torch.randn(4, 12)}
    loss, metrics = policy.loss(batch)
    loss.backward()
    assert set(metrics) == {"loss", "action_mse"} and metrics["loss"] == pytest.approx(loss.item())
    assert policy.model.bin_embed.weight.grad.abs().sum() > 0
    assert all(p.grad is not None for n, p in policy.named_parameters() if "mask_token" not in n)
    with pytest.raises(KeyError, match="'action'"):
        policy.loss(make_batch())


def test_overfits_a_tiny_dataset() -> None:
    policy = make().train()
    g = torch.Generator().manual_seed(5)
    batch = make_batch(B=16, steps=3, seed=5)
    batch["action"] = torch.tanh(batch["joint_pos"][:, -1] @ torch.randn(12, 12, generator=g) / 3)
    first, final = overfit(policy, batch, mask_ratio=0.0)
    assert final < first / 10, (first, final)


def test_numpy_batches_are_accepted() -> None:
    """The window reader and the simulator hand over numpy arrays."""
    policy = make().eval()
    batch = {**make_batch(), "pad": torch.zeros(4, T, dtype=torch.bool)}
    as_numpy = {k: v.numpy() for k, v in batch.items()}
    assert torch.equal(policy.act(as_numpy), policy.act(batch))
    loss, _ = policy.loss({**as_numpy, "action": torch.zeros(4, 12).numpy()})
    assert torch.isfinite(loss)


def test_training_after_acting_in_inference_mode() -> None:
    """Stage 2 acts (under inference_mode) and then trains the same policy: cached layouts
    and statistics must stay usable by autograd."""
    policy = make()
    batch = make_batch()
    with torch.inference_mode():
        policy.act(batch, mask_ratio=0.5)
    loss, _ = policy.train().loss({**batch, "action": torch.zeros(4, 12)})
    loss.backward()
    assert policy.model.sensor_embed["joint_pos"].grad is not None


@pytest.mark.parametrize("tokens", ["scalar", "sensor"])
def test_gradients_are_the_same_on_every_run_with_two_threads(tokens) -> None:
    """The same batch, weights and removal seed give bit-identical gradients on 2 threads
    (the position rows of the kept tokens are gathered with index_select: the backward of
    ``static[keep]``, an accumulating index_put, summed rows in a varying order, so two runs
    of ``make demo`` diverged; cpu preset, where that showed)."""
    previous = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        torch.manual_seed(0)
        cfg = MSTAConfig.from_preset("cpu", history=4, mask_ratio=0.75, tokens=tokens)
        policy = make_policy(cfg, stats_for(cfg)).train()
        batch = {**make_batch(B=64, steps=4), "action": torch.randn(64, 12)}
        grads = []
        for _ in range(32):  # a race: one pair of runs often agrees
            policy.zero_grad(set_to_none=True)
            loss, _ = policy.loss(batch, None, None, torch.Generator().manual_seed(0))
            loss.backward()
            grads.append(torch.cat([p.grad.reshape(-1) for p in policy.parameters()
                                    if p.grad is not None]))
        for g in grads[1:]:
            assert torch.equal(g, grads[0])
    finally:
        torch.set_num_threads(previous)
