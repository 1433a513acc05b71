"""Shared parts of the timestep-level baselines (GRU, RMA's TCN, TERT).

Input assembly: step t of a window becomes one vector x_t of the C scalars of the config's
input sensors (config order, registry channel order; C = 49 for the paper's sensors). Each
scalar is z-scored with the dataset statistics and clipped to ``[-clip_std, clip_std]``;
binary sensors (foot_contact) map 0/1 to -1/+1 and need no statistics. The processor owns
the statistics and is saved with the weights (processor.json).

Missing inputs (the paper's fallback for timestep-level encoders): every channel has a
learnable placeholder value (in normalized units, initialized to 0 = the dataset mean). A
scalar that is not available is replaced by its channel's placeholder before the model sees
it: a sensor absent from the batch, channels absent from ``channels`` (dead joint encoders),
and the scalars hidden by random masking (``mask_ratio``: exactly round(ratio * T * C_present)
per sample, in training when the config's ``mask_ratio`` > 0 and at test time when asked).
Per-sample removal (``absent``: a flagged faulty channel) replaces that sample's channels by
their placeholders at every step, exactly as ``channels`` does for the whole batch.
Placeholders only learn if training masks inputs (``mask_ratio`` > 0, e.g. ``tert_mask``);
otherwise they stay at 0.

Padding (steps before the episode start): they are overwritten with the first real frame
of the window (the data convention), so whatever a caller put there has no effect; TERT also
hides those steps from attention.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor, nn

from msta.data import sensors
from msta.policies.base import Absent, StudentPolicy, uniform
from msta.policies.baselines.configs import TimestepConfig
from msta.policies.processor import Batch, Channels, StudentProcessor

FORMAT = "timestep-processor/1"


@dataclass
class TimestepInputs:
    """Model-ready inputs.

    Args:
        x: (B, T, C) normalized scalars; 0 where a channel is missing.
        missing: (C,) bool, True for channels absent from the batch.
        pad: (B, T) bool, True before the episode start; or None.
    """

    x: Tensor
    missing: Tensor
    pad: Tensor | None


class TimestepProcessor(StudentProcessor):
    """Statistics owner of the baselines: raw windows -> (B, T, C) normalized vectors.

    Validation (unknown / non-input sensors, channel declarations, NaN, pad) and action
    normalization are the shared :class:`msta.policies.processor.StudentProcessor`'s, so every
    student rejects bad input the same way.

    Args:
        input_sensors: registry names, in input-vector order.
        stats: column -> {"mean", "std"} for every non-binary input sensor and, when
            ``normalize_action``, for ``action_key``; a missing column raises KeyError.
        clip_std: z-score clip.
        action_key: column of the target action.
        normalize_action: z-score actions for the loss.
    """

    FORMAT = FORMAT

    def __init__(
        self,
        input_sensors: tuple[str, ...] | list[str],
        stats: Any,
        clip_std: float = 4.0,
        action_key: str = "action",
        normalize_action: bool = True,
    ) -> None:
        super().__init__(input_sensors, stats, clip_std=clip_std, action_key=action_key,
                         normalize_action=normalize_action)
        self.offsets: dict[str, int] = {}
        start = 0
        for name in self.input_sensors:
            self.offsets[name] = start
            start += sensors.get(name).dim
        self.num_channels = start

    def columns(self, name: str) -> list[int]:
        """Positions of sensor ``name``'s channels in the input vector."""
        start = self.offsets[name]
        return list(range(start, start + sensors.get(name).dim))

    def normalize(self, batch: Batch, channels: Channels | None = None) -> TimestepInputs:
        """Validate a raw batch and assemble the normalized per-step input vectors.

        Args:
            batch: sensor name -> (B, T, c) raw tensors (any subset of the inputs, in any
                order), optional "pad" (B, T) bool; the action key is ignored.
            channels: sensor name -> channel indices present in that sensor's tensor.
        """
        present = self.present_inputs(batch, channels)
        ref = present[0][1]
        zero = torch.zeros_like(ref[..., :1], dtype=torch.float32)  # (B, T, 1)
        missing = torch.ones(self.num_channels, dtype=torch.bool, device=ref.device)  # (C,)
        given = {name: (v, idx) for name, v, idx in present}
        blocks = []  # one (B, T, dim) block per input sensor, in input-vector order
        for name in self.input_sensors:
            dim = sensors.get(name).dim
            if name not in given:
                blocks.append(zero.expand(-1, -1, dim))
                continue
            v, idx = given[name]
            missing[idx + self.offsets[name]] = False
            block = self._scaled(name, v, idx)  # (B, T, c)
            if channels and name in channels:  # a declared subset or order: scatter, absent 0
                block = zero.expand(-1, -1, dim).index_copy(2, idx, block)
            blocks.append(block)
        # built by concatenation, not by writing into a zeros tensor: traceable with any batch
        x = torch.cat(blocks, dim=2)  # (B, T, C)
        pad = self.pad_mask(batch, x.shape[:2])
        if pad is not None and (pad[:, 1:] & ~pad[:, :-1]).any():
            raise ValueError(
                "'pad' must mark a prefix of each window (steps before the episode start)"
            )
        return TimestepInputs(x, missing, pad)

    def _scaled(self, name: str, v: Tensor, idx: Tensor) -> Tensor:
        if sensors.get(name).binary:
            return self.binary(v).float() * 2.0 - 1.0  # (B, T, c) in {-1, +1}
        return self.zscore(name, v, idx).clamp(-self.clip_std, self.clip_std)  # (B, T, c)


def action_head(width: int, hidden: int, action_dim: int) -> nn.Module:
    """MLP (or linear when ``hidden`` is 0) from features to actions."""
    if not hidden:
        return nn.Linear(width, action_dim)
    return nn.Sequential(nn.Linear(width, hidden), nn.ELU(), nn.Linear(hidden, action_dim))


def fill_padding(x: Tensor, pad: Tensor | None) -> Tensor:
    """Overwrite padded steps with each sample's first real step. x (B, T, C) -> (B, T, C)."""
    if pad is None:
        return x
    B, T, C = x.shape
    first = pad.sum(1)  # (B,) index of the first real step
    src = torch.maximum(torch.arange(T, device=x.device)[None], first[:, None])  # (B, T)
    return torch.gather(x, 1, src[..., None].expand(B, T, C))


def random_input_mask(
    missing: Tensor, B: int, T: int, ratio: float, generator: torch.Generator | None
) -> Tensor:
    """(B, T, C) bool: exactly round(ratio * T * C_present) present scalars per sample."""
    C = missing.numel()
    out = torch.zeros(B, T, C, dtype=torch.bool, device=missing.device)
    if ratio == 0:  # before round(): a traced shape is a tensor (TorchScript / ONNX export)
        return out
    present = (~missing).nonzero().squeeze(1)  # (Cp,)
    n = T * present.numel()
    k = round(ratio * n)
    if k == 0:
        return out
    scores = uniform(B, n, generator, missing.device)  # (B, T*Cp)
    drop = torch.zeros(B, n, dtype=torch.bool, device=missing.device)
    drop.scatter_(1, scores.topk(k, dim=1, largest=False).indices, True)
    out[:, :, present] = drop.view(B, T, present.numel())
    return out


def per_sample_input_mask(hidden: Tensor, T: int, ratio: float,
                          generator: torch.Generator | None) -> Tensor:
    """(B, T, C) bool: exactly round(ratio * T * C_b) of sample b's scalars, where C_b
    channels are not ``hidden`` (B, C) for it (the per-sample form of
    :func:`random_input_mask`, used with per-sample channel removal)."""
    B, C = hidden.shape
    n = T * (~hidden).sum(1, dtype=torch.float64)  # (B,) scalars present per sample
    k = torch.round(ratio * n).long()  # (B,) half to even, as round()
    scores = uniform(B, T * C, generator, hidden.device).view(B, T, C)
    scores = scores.masked_fill(hidden[:, None], 2.0).flatten(1)  # hidden: never drawn
    order = scores.argsort(dim=1)  # (B, T*C) smallest first
    ranks = torch.arange(T * C, device=hidden.device).expand(B, -1)
    drop = torch.zeros_like(scores, dtype=torch.bool).scatter(1, order, ranks < k[:, None])
    return drop.view(B, T, C)


class TimestepPolicy(StudentPolicy):
    """Base of the baselines: processor -> placeholders -> ``encode`` -> action.

    Subclasses build their network in ``__init__`` and implement
    ``encode(x (B, T, C), pad (B, T) | None) -> (B, action_dim)``.

    Args:
        config: the subclass's config.
        processor: a :class:`TimestepProcessor` built from the dataset statistics.
    """

    processor_class = TimestepProcessor
    supports_absent = True

    def __init__(self, config: TimestepConfig, processor: TimestepProcessor) -> None:
        super().__init__(config, processor)
        self.num_inputs = processor.num_channels
        #: learnable value per input channel (normalized units) used where a scalar is missing
        self.placeholder = nn.Parameter(torch.zeros(self.num_inputs))

    def encode(self, x: Tensor, pad: Tensor | None) -> Tensor:
        raise NotImplementedError

    def forward(
        self,
        batch: Batch,
        channels: Channels | None = None,
        mask_ratio: float | None = None,
        generator: torch.Generator | None = None,
        absent: Absent | None = None,
    ) -> Tensor:
        """Raw batch -> model-space action (B, A); mask_ratio defaults to the config's in
        training mode and 0 in eval mode. ``absent`` (sensor -> (B, dim) bool over the full
        channels) replaces a sample's channels by their placeholders at every step, as
        ``channels`` does for the whole batch; ``mask_ratio`` then hides its fraction of
        each sample's remaining scalars."""
        mask_ratio = self.resolve_mask_ratio(mask_ratio)
        inputs = self.processor.normalize(self.as_tensors(batch), channels)
        B, T, _ = inputs.x.shape
        x = fill_padding(inputs.x, inputs.pad)  # (B, T, C)
        hide = inputs.missing  # (C,), broadcast over (B, T)
        gone = self.absent_masks(absent, B)
        if gone is not None:  # per sample: (B, C), then (B, T, C)
            zeros = torch.zeros(B, 1, dtype=torch.bool, device=x.device)
            hide = hide | torch.cat([gone.get(n, zeros.expand(-1, sensors.get(n).dim))
                                     for n in self.processor.input_sensors], dim=1)
            hide = hide[:, None]  # (B, 1, C)
            if mask_ratio > 0:
                hide = hide | per_sample_input_mask(hide[:, 0], T, mask_ratio, generator)
        elif mask_ratio > 0:
            hide = random_input_mask(inputs.missing, B, T, mask_ratio, generator) | hide
        x = torch.where(hide, self.placeholder, x)  # (B, T, C)
        return self.encode(x, inputs.pad)
