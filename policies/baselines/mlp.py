"""Window MLP: the cheapest honest student, a plain MLP on the flattened window.

The T per-step input vectors x_t (C normalized scalars, placeholders where missing) are
concatenated into one T * C vector -> ``hidden_dims`` ELU layers -> 12 joint targets. It
is not one of the paper's baselines; it is the reference a learner has to beat offline
(docs/msta_model.md) and a fast learner for checking stage 2 (docs/training.md). The
weights are tied to one window length: a window of another T raises.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

from torch import Tensor, nn

from msta.policies.baselines.common import TimestepConfig, TimestepPolicy, TimestepProcessor
from msta.policies.factory import register_policy


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
