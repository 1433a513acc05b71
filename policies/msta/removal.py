"""Per-sample channel removal for MSTA (``absent``: e.g. the channels a fault guard flags).

A sample's absent channels lose their tokens at every step of its window, as if
``channels`` had left them out for that sample alone: the same tokens are removed as for
padding or missing inputs (dropped, or with ``learnable_mask`` replaced by the mask token),
per sample. Test-time random removal (``mask_ratio`` = α) then removes round(α·N_b) of
sample b's tokens, N_b counting only its present channels' tokens (padded steps first, as
:meth:`MSTATransformer._remove_masked` does), so every sample sees exactly what it would
see alone with those channels removed by ``channels``. Samples keep different numbers of
tokens; the batch keeps the most any sample needs and hides the rest with the key mask.

An encoded sensor (``SensorSpec.encoder_tokens``: an MLP reads all of a step's channels)
loses all its tokens for a sample when any of its channels is absent (with
``learnable_mask`` they are hidden from attention, as a sensor left out has no tokens).

With ``learnable_mask``, :func:`complete_inputs` first gives every configured sensor and
channel a token and flags the ones the input lacks, for the mask token to replace.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch
from torch import Tensor

from msta.data.sensors import get
from msta.policies.base import uniform
from msta.policies.msta.processor_msta import MSTAInputs

__all__ = ["absent_tokens", "additive_mask", "complete_inputs", "encoded_keys",
           "keep_per_sample", "num_kept", "visible_tokens"]


def num_kept(num_tokens: int, mask_ratio: float) -> int:
    """Tokens kept per sample after removing round(mask_ratio * N) (at least one)."""
    return max(1, num_tokens - round(mask_ratio * num_tokens))


def visible_tokens(model: Any, inputs: MSTAInputs, mask_ratio: float,
                   generator: torch.Generator | None) -> Tensor:
    """(B, N) bool over a window's whole token layout, True = the tokens an
    ``MSTATransformer`` (no mask token) keeps at test mask ``mask_ratio`` and does not hide
    as padding: the same draw from ``generator`` as its forward, so a graph that takes
    every token and hides the others from attention acts as the policy does."""
    first = next(iter((*inputs.bins.values(), *inputs.encoded.values())))
    B, T = first.shape[:2]
    step = model.layout(inputs.channels, T, tuple(inputs.encoded))[2]  # (N,)
    N = step.shape[0]
    pad = inputs.pad[:, step] if inputs.pad is not None else None  # (B, N)
    n_drop = N - num_kept(N, mask_ratio) if mask_ratio > 0 else 0
    if pad is not None:  # padding every sample shares is removed even beyond round(αN)
        n_drop = max(n_drop, int(pad.sum(1).min()))
    visible = torch.ones(B, N, dtype=torch.bool, device=step.device)
    if n_drop:
        visible = torch.zeros_like(visible).scatter_(
            1, model.keep_draw(B, N, pad, n_drop, generator), True)
    return visible if pad is None else visible & ~pad


def absent_tokens(inputs: MSTAInputs, B: int, T: int) -> Tensor | None:
    """(B, N) bool, True = the token's channel is absent for that sample, in the token layout
    (scalar sensors in ``inputs.bins`` order, time-major, then the encoded sensors); None
    when ``inputs.absent`` removes no token (e.g. only channels ``channels`` left out)."""
    if inputs.absent is None:
        return None
    device = next(iter((*inputs.bins.values(), *inputs.encoded.values()))).device
    parts = []
    for name in inputs.bins:
        ch = inputs.channels[name]
        gone = inputs.absent.get(name)
        if gone is None:
            parts.append(torch.zeros(B, T * len(ch), dtype=torch.bool, device=device))
        else:  # (B, dim) -> the present channels (B, c) -> every step (B, T * c)
            parts.append(gone.to(device)[:, ch.to(device)].repeat(1, T))
    for name in inputs.encoded:
        k = get(name).encoder_tokens
        gone = inputs.absent.get(name)
        any_gone = (gone.to(device).any(1, keepdim=True) if gone is not None
                    else torch.zeros(B, 1, dtype=torch.bool, device=device))
        parts.append(any_gone.expand(B, T * k))
    out = torch.cat(parts, dim=1)  # (B, N)
    return out if bool(out.any()) else None


def additive_mask(visible: Tensor, dtype: torch.dtype) -> Tensor:
    """A bool attention mask (True = may be attended to) as 0 / -inf added to the scores:
    the same attention, and an exported ONNX graph without the per-score NaN guard a bool
    mask brings (twice as fast at the full observation)."""
    zeros = torch.zeros(visible.shape, dtype=dtype, device=visible.device)
    return zeros.masked_fill(~visible, float("-inf"))


def encoded_keys(gone: Tensor | None, inputs: MSTAInputs, T: int) -> Tensor | None:
    """Learnable-mask variant: absent tokens become mask tokens, but a sensor left out of the
    input has no tokens at all, so an absent encoded sensor's are hidden from attention
    instead: (B, N) bool, True for those (the layout's last tokens), or None when none."""
    if gone is None or not inputs.encoded:
        return None
    n_enc = T * sum(get(n).encoder_tokens for n in inputs.encoded)
    keys = torch.zeros_like(gone)
    keys[:, -n_enc:] = gone[:, -n_enc:]
    return keys if bool(keys.any()) else None


def keep_per_sample(gone: Tensor, pad: Tensor | None, mask_ratio: float,
                    generator: torch.Generator | None) -> tuple[Tensor, Tensor]:
    """Which tokens each sample keeps when ``gone`` (B, N) are absent for it.

    Sample b keeps r_b of its present tokens: N_b - max(N_b - num_kept(N_b, α), padded_b)
    (:func:`num_kept`), chosen at random (``generator``) when
    α > 0, all of them in layout order when α = 0 (no random draw).

    Returns:
        keep: (B, K) token indices, K = max(1, max_b r_b), each sample's r_b kept tokens
            first.
        key_pad: (B, K) bool, True for the slots beyond r_b (hidden from attention).
    """
    B, N = gone.shape
    dev = gone.device
    n = (~gone).sum(1)  # (B,) tokens of the sample's present channels
    padded = (pad & ~gone).sum(1) if pad is not None else torch.zeros_like(n)
    if mask_ratio > 0:
        kept = (n - torch.round(mask_ratio * n.double()).long()).clamp(min=1)  # num_kept
        scores = uniform(B, N, generator, dev)  # (B, N) random keep scores in [0, 1)
    else:
        kept = n
        scores = torch.zeros(B, N, device=dev)
    r = (n - torch.maximum(n - kept, padded)).clamp(min=0)  # (B,) real tokens kept
    if pad is not None:
        scores = scores.masked_fill(pad, -1.0)  # padded before present, absent last
    scores = scores.masked_fill(gone, -2.0)
    K = max(1, int(r.max()))
    keep = torch.sort(scores, dim=1, descending=True, stable=True).indices[:, :K]  # (B, K)
    key_pad = torch.arange(K, device=dev)[None] >= r[:, None]  # (B, K)
    return keep, key_pad


def complete_inputs(inputs: MSTAInputs, scalar_sensors: Sequence[str]
                    ) -> tuple[MSTAInputs, dict[str, Tensor]]:
    """Learnable-mask variant: every configured scalar sensor (``scalar_sensors``) and
    channel gets a token; the ones absent from the input (a removed sensor, a dead joint
    encoder) are flagged missing (``{sensor: (dim,) bool}``) and later replaced by the mask
    token, as the paper's "w/ learnable mask" ablation does."""
    any_bins = next(iter(inputs.bins.values()), None)  # (B, T, c)
    if any_bins is None:  # only encoded sensors present: their (B, T), bins 0
        any_bins = torch.zeros_like(next(iter(inputs.encoded.values()))[..., :1],
                                    dtype=torch.long)
    dev = any_bins.device
    bins, channels, missing = {}, {}, {}
    for name in scalar_sensors:  # an absent encoded sensor simply has no tokens
        dim = get(name).dim
        # built from the input's own shape, not written into: traceable with any batch
        full = torch.zeros_like(any_bins[..., :1]).expand(-1, -1, dim)  # (B, T, dim)
        absent = torch.ones(dim, dtype=torch.bool, device=dev)
        if name in inputs.bins:
            ch = inputs.channels[name].to(dev)
            full = full.index_copy(2, ch, inputs.bins[name])
            absent[ch] = False
        bins[name], channels[name] = full, torch.arange(dim)
        missing[name] = absent  # (dim,) per channel, repeated over time by the caller
    return MSTAInputs(bins, channels, inputs.pad, inputs.encoded, inputs.absent), missing
