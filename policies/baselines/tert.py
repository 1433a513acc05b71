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

import torch
from torch import Tensor, nn

from msta.policies.baselines.common import TimestepPolicy, TimestepProcessor, action_head
from msta.policies.baselines.configs import (
    ACTION_SENSOR,
    TERTConcatConfig,
    TERTConfig,
    TERTMaskConfig,
    TERTSeparateConfig,
)
from msta.policies.registry import register_policy
from msta.policies.transformer import init_linears, make_blocks, scale_residuals, sincos_1d


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
