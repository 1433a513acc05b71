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

from torch import Tensor, nn

from msta.policies.baselines.common import TimestepPolicy, TimestepProcessor, action_head
from msta.policies.baselines.configs import TCNConfig
from msta.policies.registry import register_policy


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
