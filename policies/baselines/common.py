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
Placeholders only learn if training masks inputs (``mask_ratio`` > 0, e.g. ``tert_mask``);
otherwise they stay at 0.

Padding (steps before the episode start): they are overwritten with the first real frame
of the window (the data convention), so whatever a caller put there has no effect; TERT also
hides those steps from attention.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, ClassVar, Self

import torch
from torch import Tensor, nn

from msta_data import sensors
from policies.base import Batch, Channels, PolicyConfig, StudentPolicy
from policies.msta.processor_msta import PAD_KEY, MSTAProcessor

FORMAT = "timestep-processor/1"


@dataclass
class TimestepConfig(PolicyConfig):
    """Fields shared by the timestep-level baselines (not registered itself).

    Args:
        input_sensors: registry names the student reads, in input-vector order.
        history: window length T used in training.
        clip_std: normalized inputs are clipped to [-clip_std, clip_std].
        mask_ratio: fraction of input scalars replaced by their placeholder per sample
            during training (0: placeholders are never trained).
        head_hidden_dim: hidden width of the action MLP head (0: a linear head).
        action_key: dataset column of the target action.
        action_dim: number of joint targets.
        normalize_action: train on z-scored actions (the processor maps back).
    """

    PRESETS: ClassVar[dict[str, dict[str, Any]]] = {"paper": {}}

    input_sensors: tuple[str, ...] = sensors.STUDENT_SENSORS
    history: int = 15
    clip_std: float = 4.0
    mask_ratio: float = 0.0
    head_hidden_dim: int = 128
    action_key: str = "action"
    action_dim: int = sensors.ACTION_DIM
    normalize_action: bool = True

    def __post_init__(self) -> None:
        self.input_sensors = tuple(self.input_sensors)
        if not self.input_sensors:
            raise ValueError("input_sensors is empty")
        if len(set(self.input_sensors)) != len(self.input_sensors):
            raise ValueError(f"input_sensors has duplicates: {self.input_sensors}")
        for name in self.input_sensors:
            if not sensors.get(name).is_student_input:  # get(): KeyError lists known sensors
                raise ValueError(
                    f"sensor {name!r} is privileged (teacher only), not a student input"
                )
        for key in ("history", "clip_std", "action_dim"):
            if not getattr(self, key) > 0:
                raise ValueError(f"{key} must be > 0, got {getattr(self, key)}")
        if self.head_hidden_dim < 0:
            raise ValueError(f"head_hidden_dim must be >= 0, got {self.head_hidden_dim}")
        if not 0.0 <= self.mask_ratio < 1.0:
            raise ValueError(f"mask_ratio must be in [0, 1), got {self.mask_ratio}")

    @classmethod
    def from_preset(cls, name: str, **overrides: Any) -> Self:
        """A named preset (``paper``, ``cpu``, ``tiny``) with optional field overrides.

        Args:
            name: a key of the class's ``PRESETS``.
            overrides: field values replacing the preset's.
        """
        if name not in cls.PRESETS:
            raise KeyError(f"unknown {cls.__name__} preset {name!r}; known: {sorted(cls.PRESETS)}")
        return replace(cls(**cls.PRESETS[name]), **overrides)


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


class TimestepProcessor(MSTAProcessor):
    """Statistics owner of the baselines: raw windows -> (B, T, C) normalized vectors.

    Validation (unknown / non-input sensors, channel declarations, NaN, pad) and action
    normalization are MSTA's, so every student rejects bad input the same way.

    Args:
        input_sensors: registry names, in input-vector order.
        stats: column -> {"mean", "std"} for every non-binary input sensor and, when
            ``normalize_action``, for ``action_key``; a missing column raises KeyError.
        clip_std: z-score clip.
        action_key: column of the target action.
        normalize_action: z-score actions for the loss.
    """

    def __init__(
        self,
        input_sensors: tuple[str, ...] | list[str],
        stats: Any,
        clip_std: float = 4.0,
        action_key: str = "action",
        normalize_action: bool = True,
    ) -> None:
        super().__init__(input_sensors, stats, 2, clip_std, action_key, normalize_action)
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

    @classmethod
    def from_stats(cls, config: TimestepConfig, stats: Any) -> Self:
        """Processor for ``config`` from dataset statistics (lerobot stats.json layout)."""
        return cls(
            config.input_sensors, stats, config.clip_std, config.action_key, config.normalize_action
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "format": FORMAT,
            "input_sensors": list(self.input_sensors),
            "clip_std": self.clip_std,
            "action_key": self.action_key,
            "normalize_action": self.normalize_action,
            "stats": self.stats,
        }

    @classmethod
    def from_dict(cls, data: Any) -> Self:
        if data.get("format") != FORMAT:
            raise ValueError(f"processor format {data.get('format')!r} is not {FORMAT!r}")
        return cls(
            data["input_sensors"],
            data["stats"],
            data["clip_std"],
            data["action_key"],
            data["normalize_action"],
        )

    def normalize(self, batch: Batch, channels: Channels | None = None) -> TimestepInputs:
        """Validate a raw batch and assemble the normalized per-step input vectors.

        Args:
            batch: sensor name -> (B, T, c) raw tensors (any subset of the inputs, in any
                order), optional "pad" (B, T) bool; the action key is ignored.
            channels: sensor name -> channel indices present in that sensor's tensor.
        """
        channels = dict(channels or {})
        present = [k for k in batch if k not in (PAD_KEY, self.action_key)]
        for name in present + list(channels):
            self._check_input_sensor(name)
        for name in channels:
            if name not in batch:
                raise ValueError(f"channels given for sensor {name!r}, which is not in the batch")
        if not present:
            raise ValueError(
                f"batch holds no input sensor; expected some of {list(self.input_sensors)}"
            )
        x: Tensor | None = None
        missing: Tensor | None = None
        for name in self.input_sensors:  # canonical order: the dict order never matters
            if name not in batch:
                continue
            v = batch[name]
            idx = self._channel_index(name, channels.get(name), v)
            if x is None:
                x = torch.zeros(*v.shape[:2], self.num_channels, device=v.device)  # (B, T, C)
                missing = torch.ones(self.num_channels, dtype=torch.bool, device=v.device)
            elif v.shape[:2] != x.shape[:2]:
                raise ValueError(
                    f"sensor {name!r} has (B, T) = {tuple(v.shape[:2])}, others {tuple(x.shape[:2])}"
                )
            if not torch.isfinite(v).all():
                bad = (~torch.isfinite(v)).nonzero()[0].tolist()
                raise ValueError(f"sensor {name!r} has a non-finite value (NaN/inf) at index {bad}")
            cols = idx + self.offsets[name]
            x[:, :, cols] = self._zscore(name, v, idx)
            missing[cols] = False
        pad = self._pad(batch, x.shape[:2])
        if pad is not None and (pad[:, 1:] & ~pad[:, :-1]).any():
            raise ValueError(
                "'pad' must mark a prefix of each window (steps before the episode start)"
            )
        return TimestepInputs(x, missing, pad)

    def _zscore(self, name: str, v: Tensor, idx: Tensor) -> Tensor:
        spec = sensors.get(name)
        if spec.binary:
            return (v > 0.5).float() * 2.0 - 1.0  # (B, T, c) in {-1, +1}
        mean, std = self._tensors(spec.column, v.device)
        return ((v.float() - mean[idx]) / std[idx]).clamp(-self.clip_std, self.clip_std)


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
    present = (~missing).nonzero().squeeze(1)  # (Cp,)
    n = T * present.numel()
    k = round(ratio * n)
    out = torch.zeros(B, T, C, dtype=torch.bool, device=missing.device)
    if k == 0:
        return out
    scores = torch.rand(B, n, generator=generator, device=missing.device)  # (B, T*Cp)
    drop = torch.zeros(B, n, dtype=torch.bool, device=missing.device)
    drop.scatter_(1, scores.topk(k, dim=1, largest=False).indices, True)
    out[:, :, present] = drop.view(B, T, present.numel())
    return out


class TimestepPolicy(StudentPolicy):
    """Base of the baselines: processor -> placeholders -> ``encode`` -> action.

    Subclasses build their network in ``__init__`` and implement
    ``encode(x (B, T, C), pad (B, T) | None) -> (B, action_dim)``.

    Args:
        config: the subclass's config.
        processor: a :class:`TimestepProcessor` built from the dataset statistics.
    """

    processor_class = TimestepProcessor

    def __init__(self, config: TimestepConfig, processor: TimestepProcessor) -> None:
        super().__init__(config, processor)
        if tuple(processor.input_sensors) != tuple(config.input_sensors):
            raise ValueError(
                f"processor sensors {processor.input_sensors} != config {config.input_sensors}"
            )
        self.num_inputs = processor.num_channels
        #: learnable value per input channel (normalized units) used where a scalar is missing
        self.placeholder = nn.Parameter(torch.zeros(self.num_inputs))

    @property
    def required_sensors(self) -> tuple[str, ...]:
        return self.config.input_sensors

    def encode(self, x: Tensor, pad: Tensor | None) -> Tensor:
        raise NotImplementedError

    def forward(
        self,
        batch: Batch,
        channels: Channels | None = None,
        mask_ratio: float | None = None,
        generator: torch.Generator | None = None,
    ) -> Tensor:
        """Raw batch -> model-space action (B, A); mask_ratio defaults to the config's in
        training mode and 0 in eval mode."""
        mask_ratio = self.resolve_mask_ratio(mask_ratio)
        inputs = self.processor.normalize(self.as_tensors(batch), channels)
        B, T, _ = inputs.x.shape
        x = fill_padding(inputs.x, inputs.pad)  # (B, T, C)
        hide = random_input_mask(inputs.missing, B, T, mask_ratio, generator)  # (B, T, C)
        hide |= inputs.missing
        x = torch.where(hide, self.placeholder, x)  # (B, T, C)
        return self.encode(x, inputs.pad)
