"""Sensor tokens (``MSTAConfig.tokens`` = ``sensor``): one token per sensor and step, while
removal still acts on single readings.

Sensor a's token at step t is an MLP of all its readings at that step:

    token = enc[a]([v_{a,t} * m_{a,t}, m_{a,t}]) + sincos2d(0, age_t) + sensor_embed[a]   # (d,)

v the readings' bin centres (z-scores in [-clip_std, clip_std]; a binary reading is -1 or
1), m a presence bit per reading (0 = removed: by test-time or training removal, by
``channels`` leaving it out, by ``absent`` for that sample, or a padded step). Removal draws
single readings exactly as the scalar tokenization removes tokens (round(α·n_b) of sample
b's n_b present readings, padded steps first, :func:`~msta.policies.msta.removal.keep_per_sample`);
a token none of whose readings is left is hidden from attention. In training a share of the
samples (``complete_share``) keeps every reading instead: trained only on tokens that lack
three quarters of their readings, the encoders met complete ones first at test mask 0 (the
unmasked validation loss stayed well above the scalar tokens'). A window of T steps with
S sensors is S·T tokens (7 · 15 = 105 where scalar tokens are 47 · 15 = 705), so a step
costs a fraction of the scalar layout's attention and MLPs; any subset of sensors, readings
and any T still work, since identity comes from the encoder, the sensor type and the age.

Dummy tokens (the stress test) take the value part of a random token of the same sample,
the position of another random slot and a random present sensor's type.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor, nn

from msta.data.sensors import get
from msta.policies.base import uniform
from msta.policies.msta.dummy import dummy_draw
from msta.policies.msta.processor_msta import MSTAInputs
from msta.policies.msta.removal import additive_mask, keep_per_sample
from msta.policies.transformer import sincos_2d

__all__ = ["draw_readings", "kept_readings", "make_encoders", "sensor_embed_steps"]


def make_encoders(names: tuple[str, ...], dim: int) -> nn.ModuleDict:
    """Sensor name -> its MLP (2 · readings -> 2d -> d): readings and presence bits in."""
    return nn.ModuleDict({
        n: nn.Sequential(nn.Linear(2 * get(n).dim, 2 * dim), nn.GELU(approximate="tanh"),
                         nn.Linear(2 * dim, dim))
        for n in names})


def _readings(inputs: MSTAInputs, num_bins: int, clip: float
              ) -> tuple[list[Tensor], list[Tensor]]:
    """Per present sensor: its readings over all channels (B, T, dim) (bin centres, binary
    ones -1 / 1, 0 where the input lacks the channel) and which are missing (B, T, dim)
    bool (left out by ``channels`` or ``absent`` for that sample; padding not counted)."""
    values, gone = [], []
    width = 2.0 * clip / num_bins
    for name, bins in inputs.bins.items():
        spec = get(name)
        ch = inputs.channels[name].to(bins.device)
        v = (bins > 0).float() * 2 - 1 if spec.binary else -clip + (bins.float() + 0.5) * width
        full = torch.zeros_like(v[..., :1]).expand(-1, -1, spec.dim)  # (B, T, dim)
        values.append(full.index_copy(2, ch, v))
        have = (torch.arange(spec.dim, device=bins.device)[:, None] == ch[None]).any(1)
        miss = ~have[None, None].expand_as(full)  # (B, T, dim)
        if inputs.absent is not None and name in inputs.absent:
            miss = miss | inputs.absent[name].to(bins.device)[:, None, :]
        gone.append(miss)
    return values, gone


def kept_readings(gone: Tensor, pad: Tensor | None, mask_ratio: float,
                  generator: torch.Generator | None, complete_share: float = 0.0) -> Tensor:
    """(B, T, M) bool, the readings each sample keeps: all present unpadded ones at
    ``mask_ratio`` 0, else the scalar tokenization's draw over single readings; with
    ``complete_share`` > 0 each sample keeps all of them with that probability instead
    (training's complete tokens, drawn after the removal from the same ``generator``)."""
    B, T, M = gone.shape
    pad_r = pad[:, :, None].expand(B, T, M) if pad is not None else None
    every = ~gone if pad_r is None else ~gone & ~pad_r
    if not mask_ratio:
        return every
    flat_pad = pad_r.reshape(B, T * M) if pad_r is not None else None
    keep, key_pad = keep_per_sample(gone.reshape(B, T * M), flat_pad, mask_ratio, generator)
    kept = torch.zeros(B, T * M + 1, dtype=torch.bool, device=gone.device)
    kept.scatter_(1, keep.masked_fill(key_pad, T * M), True)  # slots beyond r_b: a spare column
    kept = kept[:, :T * M].view(B, T, M)
    if complete_share:
        whole = uniform(B, 1, generator, gone.device) < complete_share  # (B, 1)
        kept = torch.where(whole[..., None], every, kept)
    return kept


def draw_readings(model: Any, inputs: MSTAInputs, mask_ratio: float,
                  generator: torch.Generator | None) -> Tensor:
    """(B, T, M) bool, the readings the model keeps (M: every channel of the present sensors,
    ``inputs.bins`` order): :func:`kept_readings` with the model's ``complete_share`` in
    training (none in eval mode, so test-time removal stays exact). The forward's own draw:
    a deployment graph fed these acts as the model does from the same ``generator``."""
    gone = _readings(inputs, model.cfg.num_bins, model.cfg.clip_std)[1]
    return _draw(model, torch.cat(gone, -1), inputs.pad, mask_ratio, generator)


def _draw(model: Any, gone: Tensor, pad: Tensor | None, mask_ratio: float,
          generator: torch.Generator | None) -> Tensor:
    """:func:`kept_readings` with the model's ``complete_share`` in training mode only."""
    share = model.cfg.complete_share if model.training else 0.0
    return kept_readings(gone, pad, mask_ratio, generator, share)


def sensor_embed_steps(model: Any, inputs: MSTAInputs, mask_ratio: float,
                       generator: torch.Generator | None, dummy_tokens: int | Tensor,
                       kept: Tensor | None = None) -> tuple[Tensor, Tensor | None, None, int]:
    """:meth:`MSTATransformer.embed_steps` with sensor tokens: the tokens, D dummies and the
    readout tokens (B, S·T + D + R, d), the key mask (B, 1, 1, ·) or None, no ages, 0;
    ``kept`` (B, T, M) bool fixes the readings kept (else :func:`draw_readings`)."""
    cfg = model.cfg
    names = list(inputs.bins)
    B, T = inputs.bins[names[0]].shape[:2]
    values, gone = _readings(inputs, cfg.num_bins, cfg.clip_std)
    if kept is None:
        kept = _draw(model, torch.cat(gone, -1), inputs.pad, mask_ratio, generator)
    kept = kept.split([v.shape[-1] for v in values], -1)
    tokens, present = [], []
    for name, v, k in zip(names, values, kept, strict=True):
        m = k.to(v.dtype)
        tokens.append(model.encoders[name](torch.cat([v * m, m], -1)))  # (B, T, d)
        present.append(k.any(-1))  # (B, T)
    x = torch.cat(tokens, 1)  # (B, S*T, d) sensor-major, time-major within a sensor
    visible = torch.cat(present, 1)  # (B, S*T)
    sensor = torch.stack([model.sensor_embed[n] for n in names])  # (S, d)
    age = torch.arange(T - 1, -1, -1, device=x.device, dtype=x.dtype)  # (T,) oldest first
    pos = sincos_2d(torch.zeros_like(age), age, cfg.dim, cfg.pos_base).repeat(len(names), 1)
    static = pos + sensor.repeat_interleave(T, 0)  # (S*T, d)
    parts = [x + static]
    D = dummy_tokens.shape[1] if isinstance(dummy_tokens, Tensor) else dummy_tokens
    if D:
        parts.append(_dummies(x, pos, sensor, dummy_tokens, generator))
    parts.append(model.readout_tokens().expand(B, -1, -1))
    x = torch.cat(parts, 1)  # (B, S*T + D + R, d)
    traced = torch.jit.is_tracing()
    if not traced and bool(visible.all()):
        return x, None, None, 0
    keys = torch.cat([visible, visible.new_ones(B, D + cfg.state_tokens)], 1)[:, None, None, :]
    return x, (additive_mask(keys, x.dtype) if traced else keys), None, 0


def _dummies(x: Tensor, pos: Tensor, sensor: Tensor, dummy: int | Tensor,
             generator: torch.Generator | None) -> Tensor:
    """D dummy tokens per sample (B, D, d): a random token's value (of ``x``, (B, N, d)),
    a random slot's position, a random sensor's type; ``dummy`` = D or (B, D, 4) uniforms
    that fix the draws (the fourth unused)."""
    B, N, d = x.shape
    draw = dummy_draw(B, dummy, generator, x.device)
    with torch.no_grad():
        value = torch.gather(x, 1, draw(N, 0)[..., None].expand(-1, -1, d))  # (B, D, d)
        return value + pos[draw(N, 1)] + sensor[draw(len(sensor), 2)]
