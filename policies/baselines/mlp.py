"""Window MLP: the cheapest honest student, a plain MLP on the flattened window.

The T per-step input vectors x_t (C normalized scalars, placeholders where missing) are
concatenated into one T * C vector -> ``hidden_dims`` ELU layers -> 12 joint targets. It
is not one of the paper's baselines; it is the reference a learner has to beat offline
(docs/msta_model.md) and a fast learner for checking stage 2 (docs/training.md). The
weights are tied to one window length: a window of another T raises.
"""

from __future__ import annotations

from torch import Tensor, nn

from msta.policies.baselines.common import TimestepPolicy, TimestepProcessor
from msta.policies.baselines.configs import MLPConfig
from msta.policies.registry import register_policy


@register_policy("mlp", kind="reference")
class MLPPolicy(TimestepPolicy):
    """Window MLP student.

    Args:
        config: an :class:`MLPConfig`.
        processor: a :class:`TimestepProcessor`.
    """

    config_class = MLPConfig

    def __init__(self, config: MLPConfig, processor: TimestepProcessor) -> None:
        super().__init__(config, processor)
        layers: list[nn.Module] = []
        width = config.history * self.num_inputs
        for h in config.hidden_dims:
            layers += [nn.Linear(width, h), nn.ELU()]
            width = h
        layers.append(nn.Linear(width, config.action_dim))
        self.net = nn.Sequential(*layers)

    def encode(self, x: Tensor, pad: Tensor | None) -> Tensor:
        T = x.shape[1]
        if T != self.config.history:
            raise ValueError(
                f"mlp flattens its window, so it only runs on windows of its training length "
                f"T={self.config.history}; got T={T}")
        return self.net(x.flatten(1))  # (B, T*C) -> (B, A)
