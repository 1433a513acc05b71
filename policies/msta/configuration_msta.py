"""MSTA config: a draccus dataclass registered as ``msta`` (``--policy.type=msta``) here, no
torch, and paired with :class:`~msta.policies.msta.modeling_msta.MSTAPolicy` by
:func:`msta.policies.registry.register_policy`.

Defaults are the ``paper`` preset. The paper fixes d = 128, 256 bins, T = 15 and MLP
ratio 2.0; it does not state layer or head counts: we use 4 layers and 4 heads
(see docs/msta_model.md). The fields every student has (sensors, history, mask ratio,
action target, presets) are :class:`msta.policies.config.PolicyConfig`'s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

from msta.data.sensors import PRIVILEGED_SENSORS, SENSORS, get
from msta.policies.config import PolicyConfig, check_fraction, check_positive

#: Choices of ``value_embedding``.
VALUE_EMBEDDINGS = ("shared", "sensor", "channel")
#: Choices of ``value_init``.
VALUE_INITS = ("sincos", "linear", "arc")
#: Choices of ``attention``.
ATTENTIONS = ("full", "step", "axial")
#: Choices of ``tokens``.
TOKENS = ("scalar", "sensor")

#: Preset name -> field overrides of the (paper) defaults.
PRESETS: dict[str, dict[str, Any]] = {
    # The paper: d = 128, 256 bins, T = 15, MLP ratio 2; 4 layers x 4 heads is our choice.
    "paper": {},
    # The CPU demo: a quarter of the width-depth compute and one token per sensor and step
    # (removal still per reading), which walks as well as the paper's scalar tokens at a
    # fraction of a step's cost. A 256-wide head and sin-cos base 10 fit better at the same
    # time per step (docs/msta_model.md).
    "cpu": {"dim": 64, "num_layers": 2, "num_heads": 4, "head_hidden_dim": 256, "state_tokens": 8,
            "pos_base": 10.0, "tokens": "sensor", "complete_share": 0.25},
    # Unit tests only.
    "tiny": {"dim": 32, "num_layers": 1, "num_heads": 2, "head_hidden_dim": 32},
}


@PolicyConfig.register_subclass("msta")
@dataclass
class MSTAConfig(PolicyConfig):
    """Masked Sensory-Temporal Attention student (registered as ``msta`` with its policy).
    Fields every student has are :class:`msta.policies.config.PolicyConfig`'s.

    Args:
        history: window length T used in training (inference accepts any T).
        num_bins: discretization bins per scalar.
        clip_std: bins cover z-scores in [-clip_std, clip_std]; values beyond are clipped.
        dim: token width d.
        num_layers: transformer blocks.
        num_heads: attention heads (dim must be divisible by it).
        mlp_ratio: hidden width of each block's MLP relative to dim.
        head_hidden_dim: hidden width of the action head on <S> (0: a linear head).
        dropout: dropout in attention and MLPs.
        mask_ratio: fraction of tokens removed per sample during training.
        learnable_mask: ablation: replace masked tokens by a learnable embedding
            (the sequence keeps all N tokens) instead of removing them.
        pos_base: base of the sin-cos frequencies.
        value_embedding: which scalars share a bin-embedding table: ``shared`` (one table
            for every scalar), ``sensor`` (one per sensor type) or ``channel`` (one per
            sensor channel, so a token's value embedding already says whose value it is).
        sensor_embed_std: initial std of the learnable sensor-type embeddings.
        value_init: initial bin embeddings: ``arc`` (bin centre z-score z mapped to
            cos(z/2) u + sin(z/2) v with random directions u, v per table: constant norm,
            monotone, bound to its table), ``linear`` (z times a random direction per table)
            or ``sincos`` (a 1-D sin-cos code of the bin index, the same in every table).
        init_std: std of the initial weights of every linear layer (0: 1/sqrt(fan-in)).
        state_tokens: learnable readout tokens appended to the sequence; the head reads them
            all, concatenated (1: the paper's single <S>; more widen what the attention can
            gather into the head; docs/msta_model.md measures them).
        aux_target: a privileged sensor (e.g. ``base_lin_vel``) that training also asks the
            readout tokens to predict, through a linear head of its own, from the dataset's
            column of it (raw units): an auxiliary loss for estimating what the teacher
            reads directly. Empty: none. Acting never uses it.
        aux_weight: weight of that auxiliary MSE beside the action's.
        attention: ``full`` (the paper: every token attends to every token in every block)
            or ``step``: the first ``num_layers - readout_layers`` blocks attend only within
            one step's tokens (which carry no age), then ``readout_layers`` blocks update
            only the readout tokens, which attend to every token with its age added to its
            key and value. A step's tokens then depend on that step alone, so a robot
            encodes only the newest step each control step and reuses the rest
            (:class:`~msta.policies.msta.step_attention.StepStream`). Or ``axial``: blocks
            alternate between attending within one step's tokens and within one channel's
            over the window, and the readout tokens attend to every token in every block
            (:mod:`~msta.policies.msta.axial_attention`).
        readout_layers: with ``attention`` = ``step``: how many of the ``num_layers``
            blocks are readout blocks (1 to ``num_layers``).
        tokens: ``scalar`` (the paper: one token per scalar reading) or ``sensor``: one
            token per sensor and step, an MLP of the step's readings of that sensor (each
            reading's bin centre, 0 where removed, beside a presence bit per reading);
            removal still acts on single readings, at the same ratio, and a token goes
            only when every one of its readings is removed
            (:mod:`~msta.policies.msta.sensor_tokens`). Full attention only.
        complete_share: with sensor tokens: the share of training samples that keep every
            reading (the others lose ``mask_ratio`` of theirs), so the encoders also learn
            complete tokens; test-time removal is unaffected. 0 = none; scalar tokens
            ignore it (each is one reading, complete or removed).
    """

    PRESETS: ClassVar[dict[str, dict[str, Any]]] = PRESETS  # the module's PRESETS above
    LEGACY_DEFAULTS: ClassVar[dict[str, Any]] = {
        "value_embedding": "shared", "value_init": "sincos", "init_std": 0.02}

    mask_ratio: float = 0.75
    num_bins: int = 256
    dim: int = 128
    num_layers: int = 4
    num_heads: int = 4
    mlp_ratio: float = 2.0
    dropout: float = 0.0
    learnable_mask: bool = False
    pos_base: float = 10000.0
    value_embedding: str = "channel"
    sensor_embed_std: float = 0.02
    value_init: str = "arc"
    init_std: float = 0.0
    state_tokens: int = 1
    aux_target: str = ""
    aux_weight: float = 1.0
    attention: str = "full"
    readout_layers: int = 1
    tokens: str = "scalar"
    complete_share: float = 0.0

    def __post_init__(self) -> None:
        super().__post_init__()
        check_positive(num_bins=self.num_bins, dim=self.dim, num_layers=self.num_layers,
                       num_heads=self.num_heads, mlp_ratio=self.mlp_ratio,
                       pos_base=self.pos_base, state_tokens=self.state_tokens)
        if self.num_bins < 2:
            raise ValueError(f"num_bins must be >= 2, got {self.num_bins}")
        if self.dim % self.num_heads:
            raise ValueError(f"dim {self.dim} is not divisible by num_heads {self.num_heads}")
        if self.dim % 4:
            raise ValueError(f"dim {self.dim} must be divisible by 4 (2-D sin-cos embedding)")
        check_fraction(dropout=self.dropout)
        if self.attention not in ATTENTIONS:
            raise ValueError(f"attention must be one of {ATTENTIONS}, got {self.attention!r}")
        if not 1 <= self.readout_layers <= self.num_layers:
            raise ValueError(f"readout_layers must be in [1, num_layers={self.num_layers}], "
                             f"got {self.readout_layers}")
        self._check_tokens()
        if self.value_embedding not in VALUE_EMBEDDINGS:
            raise ValueError(f"value_embedding must be one of {VALUE_EMBEDDINGS}, "
                             f"got {self.value_embedding!r}")
        if self.value_init not in VALUE_INITS:
            raise ValueError(f"value_init must be one of {VALUE_INITS}, got {self.value_init!r}")
        if self.aux_target and (self.aux_target not in SENSORS
                                or SENSORS[self.aux_target].group != "privileged"):
            raise ValueError(f"aux_target {self.aux_target!r} is not a privileged sensor; "
                             f"one of {sorted(PRIVILEGED_SENSORS)}")
        for name in ("init_std", "sensor_embed_std", "aux_weight"):  # NaN: every weight NaN
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a finite number >= 0, got {value}")

    def _check_tokens(self) -> None:
        """``tokens``: a known choice; ``sensor`` tokens only with what they support."""
        if self.tokens not in TOKENS:
            raise ValueError(f"tokens must be one of {TOKENS}, got {self.tokens!r}")
        if not 0.0 <= self.complete_share < 1.0:
            raise ValueError(f"complete_share must be in [0, 1), got {self.complete_share}")
        if self.tokens == "scalar":
            return
        if self.attention != "full" or self.learnable_mask:
            raise ValueError("tokens='sensor' works with attention='full' and "
                             "learnable_mask=false only (set tokens='scalar' for the others)")
        coded = [n for n in self.input_sensors if get(n).encoder_tokens]
        if coded:
            raise ValueError(f"tokens='sensor' encodes every input itself; {coded[0]!r} has "
                             "its own encoder (encoder_tokens): use tokens='scalar'")
