"""The timestep-level baselines' configs (GRU, RMA's TCN, TERT, the window MLP), apart from
their models so that a command line knows every ``--policy.type`` without torch: each
registered class is registered with draccus here under its policy's name, and
:func:`msta.policies.registry.register_policy` on the model (``policies/baselines/<name>.py``)
pairs the name with the same class."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

from msta.policies.config import PolicyConfig, check_fraction, check_positive


@dataclass
class TimestepConfig(PolicyConfig):
    """Base of the timestep-level baselines' configs (not registered itself); its fields
    are :class:`msta.policies.config.PolicyConfig`'s (``mask_ratio``: fraction of the input
    scalars replaced by their placeholder per sample during training; 0: placeholders are
    never trained)."""


@PolicyConfig.register_subclass("gru")
@dataclass
class GRUConfig(TimestepConfig):
    """GRU student (the paper's GRU baseline; sizes are not stated there, ours below;
    shared fields: :class:`msta.policies.config.PolicyConfig`'s).

    Args:
        hidden_dim: GRU state width.
        num_layers: stacked GRU layers.
        dropout: dropout between GRU layers (only used when num_layers > 1).
    """

    PRESETS: ClassVar[dict[str, dict[str, Any]]] = {
        "paper": {},
        "cpu": {"hidden_dim": 128, "num_layers": 1, "head_hidden_dim": 64},
        "tiny": {"hidden_dim": 32, "num_layers": 1, "head_hidden_dim": 32},
    }

    hidden_dim: int = 256
    num_layers: int = 2
    dropout: float = 0.0

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.hidden_dim < 1 or self.num_layers < 1:
            raise ValueError(
                f"hidden_dim and num_layers must be >= 1, got {self.hidden_dim}, {self.num_layers}"
            )
        check_fraction(dropout=self.dropout)


@PolicyConfig.register_subclass("mlp")
@dataclass
class MLPConfig(TimestepConfig):
    """Window MLP student (shared fields: :class:`msta.policies.config.PolicyConfig`'s;
    ``head_hidden_dim`` is unused).

    Args:
        hidden_dims: widths of the hidden ELU layers.
    """

    PRESETS: ClassVar[dict[str, dict[str, Any]]] = {
        "paper": {},
        "cpu": {},
        "tiny": {"hidden_dims": (32,)},
    }

    hidden_dims: tuple[int, ...] = (256, 256)

    def __post_init__(self) -> None:
        super().__post_init__()
        self.hidden_dims = tuple(int(h) for h in self.hidden_dims)
        if not self.hidden_dims or min(self.hidden_dims) < 1:
            raise ValueError(f"hidden_dims must be one or more widths >= 1, got {self.hidden_dims}")


#: How the TCN reads its last convolution out: RMA's flatten (one window length) or a mean.
READOUTS = ("flatten", "mean")


@PolicyConfig.register_subclass("rma_tcn")
@dataclass
class TCNConfig(TimestepConfig):
    """RMA's TCN adaptation module as a student (shared fields:
    :class:`msta.policies.config.PolicyConfig`'s).

    Args:
        embed_hidden_dim: hidden width of the per-step embedding MLP.
        embed_dim: per-step embedding width (RMA: 32).
        conv_channels: channels of every convolution (RMA: 32).
        conv_kernels: kernel size of each convolution.
        conv_strides: stride of each convolution (same length as conv_kernels).
        readout: "flatten" (RMA; fixed T = history) or "mean" (any T >= min_steps).
    """

    PRESETS: ClassVar[dict[str, dict[str, Any]]] = {
        "paper": {},
        "cpu": {"head_hidden_dim": 64},
        "tiny": {
            "embed_hidden_dim": 32,
            "embed_dim": 16,
            "conv_channels": 16,
            "head_hidden_dim": 32,
        },
    }

    embed_hidden_dim: int = 128
    embed_dim: int = 32
    conv_channels: int = 32
    conv_kernels: tuple[int, ...] = (4, 3, 3)
    conv_strides: tuple[int, ...] = (2, 1, 1)
    readout: str = "flatten"

    def __post_init__(self) -> None:
        super().__post_init__()
        self.conv_kernels = tuple(int(k) for k in self.conv_kernels)
        self.conv_strides = tuple(int(s) for s in self.conv_strides)
        if len(self.conv_kernels) != len(self.conv_strides) or not self.conv_kernels:
            raise ValueError(
                f"conv_kernels {self.conv_kernels} and conv_strides {self.conv_strides} must be "
                "non-empty and of equal length"
            )
        if min(self.conv_kernels + self.conv_strides) < 1:
            raise ValueError("conv kernels and strides must be >= 1")
        for key in ("embed_hidden_dim", "embed_dim", "conv_channels"):
            if getattr(self, key) < 1:
                raise ValueError(f"{key} must be >= 1, got {getattr(self, key)}")
        if self.readout not in READOUTS:
            raise ValueError(f"readout must be one of {READOUTS}, got {self.readout!r}")
        if self.history < self.min_steps:
            raise ValueError(
                f"history {self.history} is shorter than the convolutions need ({self.min_steps}); "
                "choose smaller conv_kernels / conv_strides (e.g. kernels (3, 3, 3), strides "
                "(1, 1, 1) need 7 steps)"
            )

    def out_steps(self, T: int) -> int:
        """Steps left after the convolutions for a window of T (< 1: too short)."""
        for k, s in zip(self.conv_kernels, self.conv_strides):
            T = (T - k) // s + 1 if T >= k else 0
        return T

    @property
    def min_steps(self) -> int:
        """Shortest window the convolutions accept."""
        T = 1
        while self.out_steps(T) < 1:
            T += 1
        return T


#: The sensor ``tert_separate`` gives a token of its own at every step.
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


@PolicyConfig.register_subclass("tert_concat")
@dataclass
class TERTConcatConfig(TERTConfig):
    """TERT with one token per step (concatenated observation and last action)."""


@PolicyConfig.register_subclass("tert_separate")
@dataclass
class TERTSeparateConfig(TERTConfig):
    """TERT with separate observation and action tokens per step (2T tokens)."""

    SEPARATE_ACTION: ClassVar[bool] = True


@PolicyConfig.register_subclass("tert_mask")
@dataclass
class TERTMaskConfig(TERTConfig):
    """The paper's "TERT w/ learnable mask": tert_concat trained with masked inputs replaced
    by learnable per-channel placeholders (default 75 % of the scalars, MSTA's stage-1 ratio)."""

    mask_ratio: float = 0.75
