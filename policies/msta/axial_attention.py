"""MSTA with attention factorized over sensors and over time (``MSTAConfig.attention`` =
``axial``).

The paper's MSTA lets every token attend to every token of the window in every block:
O((T·n)²) scores per block for n readings per step. Here the tokens are the paper's (one per
scalar reading, its age in its position code, removed one by one) and the blocks alternate
what a token attends to:

- even blocks (0, 2, ...): the tokens of the **same step** (n of them per step);
- odd blocks (1, 3, ...): the tokens of the **same channel** over the window (T of them);

so a block costs O(T·n² + n·T²) scores. The readout tokens (<S> and the R - 1 others) attend
to every token of the window and to each other in every block, with the block's own keys
and values, and only the readout tokens go through the last block. Tokens never attend to
the readout tokens. Removal, any sensor subset and any window length work as in the paper's
model: a removed token is in no group.

With removal (training, test-time masking) the groups are masks over the kept tokens; on a
whole window (nothing removed) they are reshaped into T groups of n, or n groups of T, which
is where a control step saves its time. Both give the same actions up to float rounding
(``tests/policies/test_msta_axial_attention.py``).
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor

from msta.policies.msta.step_attention import readout_block, token_kv

__all__ = ["KEY", "axial_features", "token_keys"]

#: A token's key is ``age * KEY + channel``: same step <=> same ``key // KEY``, same channel
#: <=> same ``key % KEY`` (channels are numbered over every input sensor, far below KEY).
KEY = 1 << 16


def token_keys(step: Tensor, chan: Tensor, T: int) -> Tensor:
    """(N,) keys of a layout's tokens from their step (0 = oldest) and channel number."""
    return (T - 1 - step) * KEY + chan


def axial_features(model: Any, x: Tensor, attn_mask: Tensor | None, keys: Tensor,
                   steps: int = 0) -> Tensor:
    """Readout features (B, R·d) of an ``MSTATransformer`` in ``axial`` mode from ``embed``'s
    tokens ``x`` (B, L + R, d; readout tokens last), key mask and the keys (B, L) of the L
    tokens before the readout tokens (:func:`token_keys`). ``steps`` = T > 0 says those are
    the whole layout of a T-step window (nothing removed, no dummy): the token blocks then
    run on reshaped groups; otherwise on all L tokens with a mask per group."""
    R = model.cfg.state_tokens
    L = x.shape[1] - R
    tokens, readout = x[:, :L], x[:, L:]
    visible = None
    if attn_mask is not None:
        visible = attn_mask[:, 0, 0, :L]
        visible = visible if visible.dtype == torch.bool else visible == 0
    axes = [_Grouped(keys[0], axis, steps, visible) if steps else _Masked(keys, axis, visible)
            for axis in ("step", "channel")]
    last = len(model.blocks) - 1
    for i, block in enumerate(model.blocks):
        new_readout = readout_block(block, token_kv(block, tokens), readout, visible)
        if i < last:  # the last block's tokens are read by nobody
            tokens = axes[i % 2](block, tokens)
        readout = new_readout
    return model.ln_f(readout).flatten(1)


def _group_of(keys: Tensor, axis: str) -> Tensor:
    return keys // KEY if axis == "step" else keys % KEY


class _Masked:
    """One axis's groups as a mask over all L tokens (B, 1, L, L); a hidden token attends to
    itself only."""

    def __init__(self, keys: Tensor, axis: str, visible: Tensor | None) -> None:
        group = _group_of(keys, axis)  # (B, L)
        same = group[:, :, None] == group[:, None, :]
        if visible is not None:
            same = same & visible[:, None, :]
        eye = torch.eye(keys.shape[1], dtype=torch.bool, device=keys.device)
        self.mask = (same | eye)[:, None]

    def __call__(self, block: Any, tokens: Tensor) -> Tensor:
        return block(tokens, self.mask)


class _Grouped:
    """One axis's groups of a whole window: the tokens sorted by group, reshaped to
    (B · groups, size, d), run, and put back in layout order."""

    def __init__(self, keys: Tensor, axis: str, steps: int, visible: Tensor | None) -> None:
        L = keys.shape[0]
        group = _group_of(keys, axis)
        other = keys % KEY if axis == "step" else keys // KEY
        self.order = torch.argsort(group * KEY + other)  # (L,) grouped, then by the other axis
        self.back = torch.argsort(self.order)
        self.size = L // steps if axis == "step" else steps
        self.mask = None
        if visible is not None:
            B = visible.shape[0]
            vis = visible[:, self.order].reshape(B * (L // self.size), 1, self.size)
            eye = torch.eye(self.size, dtype=torch.bool, device=keys.device)
            self.mask = (vis | eye)[:, None]  # (B · groups, 1, size, size)

    def __call__(self, block: Any, tokens: Tensor) -> Tensor:
        B, L, D = tokens.shape
        groups = tokens[:, self.order].reshape(B * (L // self.size), self.size, D)
        return block(groups, self.mask).reshape(B, L, D)[:, self.back]
