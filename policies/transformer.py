"""Transformer pieces shared by MSTA and TERT: sin-cos codes, self-attention, the pre-norm
block and the GPT-2 style initialization.

Parameter names (``ln1``, ``attn.qkv``, ``attn.proj``, ``ln2``, ``mlp.0``, ``mlp.2``) are
part of every saved checkpoint's state dict: keep them when changing this file.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable

import torch
import torch.nn.functional as F
from torch import Tensor, nn


def sincos_1d(pos: Tensor, dim: int, base: float) -> Tensor:
    """Fixed sin-cos code. pos (n,) float -> (n, dim)."""
    half = dim // 2
    omega = 1.0 / base ** (
        torch.arange(half, dtype=torch.float64, device=pos.device) / half
    )  # (dim/2,)
    angle = pos.double()[:, None] * omega[None, :]  # (n, dim/2)
    return torch.cat([angle.sin(), angle.cos()], dim=1).float()  # (n, dim)


def sincos_2d(channel: Tensor, age: Tensor, dim: int, base: float) -> Tensor:
    """2-D sin-cos over (channel index, age): half the width each. -> (n, dim)."""
    return torch.cat([sincos_1d(channel, dim // 2, base), sincos_1d(age, dim // 2, base)], dim=1)


class SelfAttention(nn.Module):
    """Multi-head self-attention (PyTorch's scaled-dot-product kernel).

    Args:
        dim: token width d.
        num_heads: heads (d must be divisible by it).
        dropout: attention dropout in training.
    """

    def __init__(self, dim: int, num_heads: int, dropout: float = 0.0) -> None:
        super().__init__()
        self.num_heads, self.dropout = num_heads, dropout
        self.qkv = nn.Linear(dim, 3 * dim)
        self.proj = nn.Linear(dim, dim)

    def forward(self, x: Tensor, attn_mask: Tensor | None, queries: int | None = None) -> Tensor:
        """x (B, L, d) -> (B, L, d); with ``queries`` = n, only the last n tokens ask (keys and
        values still come from all L): (B, n, d), the same numbers as the last n rows."""
        B, D = x.shape[0], x.shape[2]  # x: (B, L, d)
        if queries is None:
            q, k, v = self.qkv(x).split(D, dim=2)  # (B, L, d) each
        else:
            w, b = self.qkv.weight, self.qkv.bias
            q = F.linear(x[:, -queries:], w[:D], b[:D])  # (B, n, d)
            k, v = F.linear(x, w[D:], b[D:]).split(D, dim=2)  # (B, L, d) each
        q, k, v = (
            z.view(B, -1, self.num_heads, D // self.num_heads).transpose(1, 2) for z in (q, k, v)
        )  # (B, nh, L or n, hs)
        y = F.scaled_dot_product_attention(
            q, k, v, attn_mask=attn_mask, dropout_p=self.dropout if self.training else 0.0
        )  # (B, nh, L or n, hs)
        return self.proj(y.transpose(1, 2).reshape(B, -1, D))  # (B, L or n, d)


class Block(nn.Module):
    """Pre-norm transformer block: x + attn(ln(x)), then x + mlp(ln(x)).

    Args:
        dim: token width d.
        num_heads: attention heads.
        mlp_ratio: hidden width of the MLP relative to d.
        dropout: dropout in attention and after the MLP.
    """

    def __init__(self, dim: int, num_heads: int, mlp_ratio: float = 2.0,
                 dropout: float = 0.0) -> None:
        super().__init__()
        hidden = round(mlp_ratio * dim)
        self.ln1, self.ln2 = nn.LayerNorm(dim), nn.LayerNorm(dim)
        self.attn = SelfAttention(dim, num_heads, dropout)
        self.mlp = nn.Sequential(
            nn.Linear(dim, hidden),
            nn.GELU(approximate="tanh"),
            nn.Linear(hidden, dim),
            nn.Dropout(dropout),
        )

    def forward(self, x: Tensor, attn_mask: Tensor | None, queries: int | None = None) -> Tensor:
        """x (B, L, d) -> (B, L, d); with ``queries`` = n, only the last n tokens are updated
        and returned, (B, n, d): a last block whose other outputs nobody reads skips them."""
        h = self.attn(self.ln1(x), attn_mask, queries)  # (B, L or n, d)
        x = (x if queries is None else x[:, -queries:]) + h
        return x + self.mlp(self.ln2(x))  # (B, L or n, d)

    @property
    def residual_projections(self) -> tuple[nn.Linear, nn.Linear]:
        """The two linears that write into the residual stream."""
        return self.attn.proj, self.mlp[2]


def make_blocks(cfg: object) -> nn.ModuleList:
    """``cfg.num_layers`` blocks from a config with dim, num_heads, mlp_ratio and dropout."""
    return nn.ModuleList(
        Block(cfg.dim, cfg.num_heads, cfg.mlp_ratio, cfg.dropout)  # type: ignore[attr-defined]
        for _ in range(cfg.num_layers)  # type: ignore[attr-defined]
    )


LinearStd = Callable[[nn.Linear], float]


def init_linears(modules: Iterable[nn.Module], std: float | LinearStd) -> None:
    """Every ``nn.Linear`` inside ``modules`` (in order): weight ~ N(0, std), bias (if any) 0.

    Args:
        modules: searched with ``.modules()`` each.
        std: a number, or a function of the layer (e.g. 1/sqrt(fan-in)).
    """
    for m in modules:
        for lin in m.modules():
            if isinstance(lin, nn.Linear):
                nn.init.normal_(lin.weight, std=std(lin) if callable(std) else std)
                if lin.bias is not None:
                    nn.init.zeros_(lin.bias)


def scale_residuals(stack: Iterable[Block], std: float | LinearStd) -> None:
    """GPT-2: re-draw the residual projections with std / sqrt(2 * number of blocks)."""
    stack = list(stack)
    for block in stack:
        for lin in block.residual_projections:
            base = std(lin) if callable(std) else std
            nn.init.normal_(lin.weight, std=base / math.sqrt(2 * len(stack)))
