"""TERT baselines: a transformer over timestep tokens (one linear projection per step).

``tert_concat``: token_t = W [x_t] + b + pos(age_t), T tokens, where x_t is the normalized
concatenation of all observations including the last action. ``tert_separate``: per step an
action token W_a a_{t-1} and an observation token W_o o_t (in that order: a_{t-1} precedes
o_t), 2T tokens, each also carrying a learnable token-type embedding. ``tert_mask`` (the
paper's "TERT w/ learnable mask"): ``tert_concat`` trained with random input masking, the
masked scalars replaced by their channel's learnable placeholder before the projection.

pos(age) is a fixed 1-D sin-cos code of age_t = T - 1 - t (0 = newest step), so any window
length works and the newest steps keep their codes. A learnable state token <S> is appended;
pre-norm transformer blocks (policies/transformer.py, shared with MSTA) and an
MLP head on <S> give the 12 joint targets. Padded steps (before the episode start) are hidden
from attention, so a padded window acts exactly like its shorter unpadded one.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import torch
from torch import Tensor, nn

from msta.policies.baselines.common import (
    TimestepConfig,
    TimestepPolicy,
    TimestepProcessor,
    action_head,
)
from msta.policies.config import check_fraction, check_positive
from msta.policies.factory import register_policy
from msta.policies.transformer import init_linears, make_blocks, scale_residuals, sincos_1d

ACTION_SENSOR = "last_action"


@dataclass
class TERTConfig(TimestepConfig):
    """Transformer over timestep tokens (base of the TERT configs; not registered itself;
    shared fields: :class:`msta.policies.config.PolicyConfig`'s).

    Args:
        dim: token width d.
        num_layers: transformer blocks.
        num_heads: attention heads (dim must be divisible by it).
        mlp_ratio: hidden width of each block's MLP relative to dim.
        dropout: dropout in attention and MLPs.
        pos_base: base of the sin-cos frequencies.
    """

    #: one action token and one observation token per step (2T tokens) instead of one
    SEPARATE_ACTION: ClassVar[bool] = False
    PRESETS: ClassVar[dict[str, dict[str, Any]]] = {
        "paper": {},
        "cpu": {"dim": 64, "num_layers": 2, "num_heads": 4, "head_hidden_dim": 64},
        "tiny": {"dim": 32, "num_layers": 1, "num_heads": 2, "head_hidden_dim": 32},
    }

    dim: int = 128
    num_layers: int = 4
    num_heads: int = 4
    mlp_ratio: float = 2.0
    dropout: float = 0.0
    pos_base: float = 10000.0

    def __post_init__(self) -> None:
        super().__post_init__()
        check_positive(dim=self.dim, num_layers=self.num_layers, num_heads=self.num_heads,
                       mlp_ratio=self.mlp_ratio, pos_base=self.pos_base)
        if self.dim % self.num_heads:
            raise ValueError(f"dim {self.dim} is not divisible by num_heads {self.num_heads}")
        if self.dim % 2:
            raise ValueError(f"dim {self.dim} must be even (sin-cos positions)")
        check_fraction(dropout=self.dropout)
        if self.SEPARATE_ACTION and (
            ACTION_SENSOR not in self.input_sensors or len(self.input_sensors) < 2
        ):
            raise ValueError(
                f"{self.type} needs {ACTION_SENSOR!r} and at least one observation sensor in "
                f"input_sensors, got {self.input_sensors}"
            )


@dataclass
class TERTConcatConfig(TERTConfig):
    """TERT with one token per step (concatenated observation and last action)."""


@dataclass
class TERTSeparateConfig(TERTConfig):
    """TERT with separate observation and action tokens per step (2T tokens)."""

    SEPARATE_ACTION: ClassVar[bool] = True


@dataclass
class TERTMaskConfig(TERTConfig):
    """The paper's "TERT w/ learnable mask": tert_concat trained with masked inputs replaced
    by learnable per-channel placeholders (default 75 % of the scalars, MSTA's stage-1 ratio)."""

    mask_ratio: float = 0.75


class TERTPolicy(TimestepPolicy):
    """Transformer over timestep tokens; the registered subclasses only set the config class.

    Args:
        config: a :class:`TERTConfig` subclass.
        processor: a :class:`TimestepProcessor`.
    """

    def __init__(self, config: TERTConfig, processor: TimestepProcessor) -> None:
        super().__init__(config, processor)
        d = config.dim
        groups = [list(range(self.num_inputs))]
        if config.SEPARATE_ACTION:
            act = processor.columns(ACTION_SENSOR)
            groups = [act, [c for c in range(self.num_inputs) if c not in act]]
        for i, cols in enumerate(groups):
            self.register_buffer(f"group{i}", torch.tensor(cols), persistent=False)
        self.proj = nn.ModuleList(nn.Linear(len(cols), d) for cols in groups)
        self.type_embed = nn.Parameter(torch.zeros(len(groups), d))
        self.state_token = nn.Parameter(torch.zeros(d))
        self.blocks = make_blocks(config)
        self.ln_f = nn.LayerNorm(d)
        self.head = action_head(d, config.head_hidden_dim, config.action_dim)
        self._init_weights()

    def _init_weights(self) -> None:
        init_linears([*self.proj, *self.blocks], 0.02)
        scale_residuals(self.blocks, 0.02)  # GPT-2: residual projections scaled by depth
        nn.init.normal_(self.type_embed, std=0.02)
        nn.init.normal_(self.state_token, std=0.02)

    def tokens(self, x: Tensor) -> Tensor:
        """x (B, T, C) -> tokens (B, T * G, d), time-major, G tokens per step."""
        T = x.shape[1]
        cfg: TERTConfig = self.config
        G = len(self.proj)
        tok = torch.stack(
            [self.proj[i](x[..., getattr(self, f"group{i}")]) for i in range(G)], dim=2
        )  # (B, T, G, d)
        age = torch.arange(T - 1, -1, -1, device=x.device)  # (T,) newest step has age 0
        pos = sincos_1d(age, cfg.dim, cfg.pos_base)  # (T, d)
        tok = tok + pos[None, :, None] + self.type_embed  # (B, T, G, d)
        return tok.flatten(1, 2)  # (B, T * G, d)

    def encode(self, x: Tensor, pad: Tensor | None) -> Tensor:
        B = x.shape[0]
        h = self.tokens(x)  # (B, L, d), L = T * G
        h = torch.cat([h, self.state_token.expand(B, 1, -1)], dim=1)  # (B, L + 1, d)
        attn_mask = None
        if pad is not None:
            keep = (~pad).repeat_interleave(len(self.proj), dim=1)  # (B, L)
            keep = torch.cat([keep, keep.new_ones(B, 1)], dim=1)  # <S> is always visible
            attn_mask = keep[:, None, None, :]  # (B, 1, 1, L + 1)
        for block in self.blocks:
            h = block(h, attn_mask)
        return self.head(self.ln_f(h[:, -1]))  # (B, A) from <S>


@register_policy("tert_concat")
class TERTConcatPolicy(TERTPolicy):
    """TERT, concatenated tokens (T tokens)."""

    config_class = TERTConcatConfig


@register_policy("tert_separate")
class TERTSeparatePolicy(TERTPolicy):
    """TERT, separate observation and action tokens (2T tokens)."""

    config_class = TERTSeparateConfig


@register_policy("tert_mask")
class TERTMaskPolicy(TERTPolicy):
    """TERT with learnable-placeholder masking of its inputs (the paper's "TERT w/ mask")."""

    config_class = TERTMaskConfig
