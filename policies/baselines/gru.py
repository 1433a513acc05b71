"""GRU baseline: a recurrent encoder over the per-step input vectors -> action.

x_t (C normalized scalars, placeholders where missing) -> GRU (num_layers x hidden_dim)
-> hidden state after the newest step -> MLP head -> 12 joint targets. Any window length T
works (the GRU just runs more or fewer steps). Padded steps repeat the first real frame.
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
from msta.policies.config import check_fraction
from msta.policies.factory import register_policy


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


@register_policy("gru")
class GRUPolicy(TimestepPolicy):
    """GRU student.

    Args:
        config: a :class:`GRUConfig`.
        processor: a :class:`TimestepProcessor`.
    """

    config_class = GRUConfig

    def __init__(self, config: GRUConfig, processor: TimestepProcessor) -> None:
        super().__init__(config, processor)
        self.gru = nn.GRU(
            self.num_inputs,
            config.hidden_dim,
            config.num_layers,
            batch_first=True,
            dropout=config.dropout if config.num_layers > 1 else 0.0,
        )
        self.head = action_head(config.hidden_dim, config.head_hidden_dim, config.action_dim)

    def encode(self, x: Tensor, pad: Tensor | None) -> Tensor:
        out, _ = self.gru(x)  # (B, T, hidden)
        return self.head(out[:, -1])  # (B, A)
