"""MSTA with per-step attention (``MSTAConfig.attention`` = ``step``).

The paper's MSTA lets every token attend to every token of the window in every block, so a
control step costs O((T·n)²) attention and each new step changes every token. Here the
first ``num_layers - readout_layers`` blocks attend only among the tokens of one step (n of
them, T groups), and those tokens carry no age: their position code is the channel's alone.
A step's tokens therefore depend on that step's readings only. The last
``readout_layers`` blocks update only the readout tokens (<S> and the R - 1 others): they
attend to every token of the window and to each other, with the token's age added to its
key and value,

    key_j = W_k LN(x_j) + A_k sincos(age_j),   value_j = W_v LN(x_j) + A_v sincos(age_j)

(A_k, A_v one linear map per readout block, ``MSTATransformer.age_proj``). Removal acts per
scalar token exactly as in the paper's model (a removed token is absent from both stages),
and any sensor subset and any window length work the same way.

At deployment :class:`~msta.policies.msta.step_stream.StepStream` encodes only the newest
step each control step and keeps every past step's ``W_k LN(x_j)``, ``W_v LN(x_j)`` per
readout block: the ages move, the cached numbers do not, so the action equals the whole
window's (up to float rounding).
"""

from __future__ import annotations

from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from msta.policies.transformer import Block, sincos_1d

__all__ = ["age_code", "make_age_proj", "readout_block", "step_features", "token_kv"]


def age_code(model: Any, ages: Tensor) -> Tensor:
    """The fixed sin-cos code of token ages (any shape) -> (..., d)."""
    flat = sincos_1d(ages.reshape(-1).float(), model.cfg.dim, model.cfg.pos_base)
    return flat.view(*ages.shape, -1)


def token_kv(block: Block, tokens: Tensor) -> Tensor:
    """A readout block's keys and values of ``tokens`` (B, L, d) before their age: (B, L, 2d)."""
    D = tokens.shape[-1]
    w, b = block.attn.qkv.weight, block.attn.qkv.bias
    return F.linear(block.ln1(tokens), w[D:], b[D:])


def readout_block(block: Block, kv: Tensor, readout: Tensor, visible: Tensor | None) -> Tensor:
    """One readout block: the readout tokens (B, R, d) attend to tokens whose keys and values
    (age included) are ``kv`` (B, L, 2d), ``visible`` (B, L) or None (all), and to each other;
    then the block's MLP. Returns the updated readout tokens (B, R, d)."""
    B, R, D = readout.shape
    w, b = block.attn.qkv.weight, block.attn.qkv.bias
    h = block.ln1(readout)
    q = F.linear(h, w[:D], b[:D])  # (B, R, d)
    k, v = torch.cat([kv, F.linear(h, w[D:], b[D:])], dim=1).split(D, dim=2)  # (B, L + R, d)
    nh = block.attn.num_heads
    q, k, v = (z.view(B, -1, nh, D // nh).transpose(1, 2) for z in (q, k, v))  # (B, nh, *, hs)
    mask = None
    if visible is not None:
        mask = torch.cat([visible, visible.new_ones(B, R)], dim=1)[:, None, None, :]
    y = F.scaled_dot_product_attention(
        q, k, v, attn_mask=mask, dropout_p=block.attn.dropout if block.training else 0.0)
    readout = readout + block.attn.proj(y.transpose(1, 2).reshape(B, R, D))
    return readout + block.mlp(block.ln2(readout))


def _visible(attn_mask: Tensor | None, length: int) -> Tensor | None:
    """(B, length) True = may be attended to, from ``embed``'s key mask (bool or additive)."""
    if attn_mask is None:
        return None
    keys = attn_mask[:, 0, 0, :length]
    return keys if keys.dtype == torch.bool else keys == 0


def step_features(model: Any, x: Tensor, attn_mask: Tensor | None, ages: Tensor,
                  steps: int = 0) -> Tensor:
    """Readout features (B, R·d) of an ``MSTATransformer`` in ``step`` mode from ``embed``'s
    tokens ``x`` (B, L + R, d; readout tokens last), key mask and the ages (B, L) of the L
    tokens before the readout tokens. ``steps`` = T > 0 says those are the whole layout of
    a T-step window (no token removed, no dummy): every step then has L / T tokens and the
    per-step blocks run on T groups of them; otherwise (any removal) on all L tokens with
    a mask that keeps each step to itself."""
    cfg = model.cfg
    R = cfg.state_tokens
    L = x.shape[1] - R
    tokens, readout = x[:, :L], x[:, L:]
    visible = _visible(attn_mask, L)
    n_step = cfg.num_layers - cfg.readout_layers
    if n_step and steps:
        tokens, ages, visible = _grouped_steps(model.blocks[:n_step], tokens, ages, visible, steps)
    elif n_step:
        same = ages[:, :, None] == ages[:, None, :]  # (B, L, L): one step's tokens
        if visible is not None:
            same = same & visible[:, None, :]
        index = torch.arange(L, device=x.device)
        same = same | (index[:, None] == index[None, :])  # a hidden token attends to itself only
        for block in model.blocks[:n_step]:
            tokens = block(tokens, same[:, None])
    # each age's code and offsets once, then looked up per token (ages are small integers)
    code = age_code(model, torch.arange(int(ages.max()) + 1 if ages.numel() else 1,
                                        device=x.device))  # (ages, d)
    for block, proj in zip(model.blocks[n_step:], model.age_proj, strict=True):
        offset = F.embedding(ages, proj(code))  # (B, L, 2d)
        readout = readout_block(block, token_kv(block, tokens) + offset, readout, visible)
    return model.ln_f(readout).flatten(1)


def _grouped_steps(blocks: Any, tokens: Tensor, ages: Tensor, visible: Tensor | None,
                   steps: int) -> tuple[Tensor, Tensor, Tensor | None]:
    """The per-step blocks on a whole T-step layout as T·B groups of L / T tokens: returns
    the tokens, their ages and visibility, all in step order (oldest step first)."""
    B, L, D = tokens.shape
    n = L // steps
    index = torch.arange(L, device=tokens.device)
    order = torch.argsort(index - ages[0] * L)  # (L,) the layout's tokens, oldest step first
    tokens, ages = tokens[:, order], ages[:, order]
    mask = None
    if visible is not None:
        visible = visible[:, order]
        index = index[:n]
        keys = visible.reshape(B * steps, 1, n) | (index[:, None] == index[None, :])  # (B·T, n, n)
        mask = keys[:, None]  # (B·T, 1, n, n): a hidden token attends to itself only
    groups = tokens.reshape(B * steps, n, D)
    for block in blocks:
        groups = block(groups, mask)
    return groups.reshape(B, L, D), ages, visible


def make_age_proj(cfg: Any) -> nn.ModuleList | None:
    """One bias-free linear map (d -> 2d) of the age code per readout block in ``step``
    mode (None otherwise)."""
    if cfg.attention != "step":
        return None
    return nn.ModuleList(nn.Linear(cfg.dim, 2 * cfg.dim, bias=False)
                         for _ in range(cfg.readout_layers))
