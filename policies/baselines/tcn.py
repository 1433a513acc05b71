"""RMA baseline: the adaptation module of RMA (Kumar et al. 2021) as a student.

Each step's input vector x_t is embedded by a small MLP, then 1-D temporal convolutions run
over the window (RMA: 32 channels, kernels 8/5/5, strides 4/1/1 over 50 steps; for the
paper's T = 15 we use kernels 4/3/3, strides 2/1/1: 15 -> 6 -> 4 -> 2 steps). RMA flattens
the convolution output, which ties the weights to one window length: with
``readout = "flatten"`` (default) a window of another T raises. ``readout = "mean"``
averages over the remaining steps instead and accepts any T that the convolutions fit
(at least :attr:`TCNConfig.min_steps`). The action head maps straight to the 12 joint
targets (RMA's module predicts the teacher's latent; here every student predicts actions).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

from torch import Tensor, nn

from msta.policies.baselines.common import (
    TimestepConfig,
    TimestepPolicy,
    TimestepProcessor,
    action_head,
)
from msta.policies.factory import register_policy

READOUTS = ("flatten", "mean")


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


@register_policy("rma_tcn")
class TCNPolicy(TimestepPolicy):
    """RMA TCN student.

    Args:
        config: a :class:`TCNConfig`.
        processor: a :class:`TimestepProcessor`.
    """

    config_class = TCNConfig

    def __init__(self, config: TCNConfig, processor: TimestepProcessor) -> None:
        super().__init__(config, processor)
        self.embed = nn.Sequential(
            nn.Linear(self.num_inputs, config.embed_hidden_dim),
            nn.ReLU(),
            nn.Linear(config.embed_hidden_dim, config.embed_dim),
            nn.ReLU(),
        )
        convs: list[nn.Module] = []
        width = config.embed_dim
        for k, s in zip(config.conv_kernels, config.conv_strides):
            convs += [nn.Conv1d(width, config.conv_channels, k, stride=s), nn.ReLU()]
            width = config.conv_channels
        self.convs = nn.Sequential(*convs)
        features = config.conv_channels
        if config.readout == "flatten":
            features *= config.out_steps(config.history)
        self.head = action_head(features, config.head_hidden_dim, config.action_dim)

    def encode(self, x: Tensor, pad: Tensor | None) -> Tensor:
        cfg: TCNConfig = self.config
        T = x.shape[1]
        if cfg.readout == "flatten" and T != cfg.history:
            raise ValueError(
                f"rma_tcn with readout='flatten' (RMA's design) flattens the convolution output "
                f"over time, so it only runs on windows of its training length T={cfg.history}; "
                f"got T={T}. Use readout='mean' for other window lengths."
            )
        if T < cfg.min_steps:
            raise ValueError(f"rma_tcn needs windows of at least {cfg.min_steps} steps, got T={T}")
        h = self.embed(x).transpose(1, 2)  # (B, embed_dim, T)
        h = self.convs(h)  # (B, channels, L)
        h = h.flatten(1) if cfg.readout == "flatten" else h.mean(2)  # (B, features)
        return self.head(h)  # (B, A)
