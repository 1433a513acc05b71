"""GRU baseline: a recurrent encoder over the per-step input vectors -> action.

x_t (C normalized scalars, placeholders where missing) -> GRU (num_layers x hidden_dim)
-> hidden state after the newest step -> MLP head -> 12 joint targets. Any window length T
works (the GRU just runs more or fewer steps). Padded steps repeat the first real frame.
"""

from __future__ import annotations

from torch import Tensor, nn

from msta.policies.baselines.common import TimestepPolicy, TimestepProcessor, action_head
from msta.policies.baselines.configs import GRUConfig
from msta.policies.registry import register_policy


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
