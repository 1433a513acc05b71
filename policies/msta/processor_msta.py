"""MSTA processor: raw sensor windows -> bin indices; z-scored actions <-> raw actions.

Binning (the paper only says "normalized, discretized to 256 bins"):
each channel is z-scored with the dataset's per-channel mean and std, clipped to
``[-clip_std, clip_std]`` and cut into ``num_bins`` equal-width bins; binary sensors
(``SensorSpec.binary``, e.g. foot_contact) use only the two end bins (0 and num_bins - 1,
threshold 0.5). The processor is saved with the weights as processor.json; a statistics
column it needs but cannot find raises (it never skips normalization silently).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Self

import torch
from torch import Tensor

from msta_data import sensors
from policies.base import Batch, Channels
from policies.msta.configuration_msta import MSTAConfig

FORMAT = "msta-processor/1"
PAD_KEY = "pad"
#: std floor: a channel that never varied in the data still maps to finite z-scores.
MIN_STD = 1e-6


@dataclass
class MSTAInputs:
    """Model-ready inputs.

    Args:
        bins: sensor name -> bin indices (B, T, c), long.
        channels: sensor name -> channel indices present (c,), long.
        pad: (B, T) bool, True where the step lies before the episode start; or None.
    """

    bins: dict[str, Tensor]
    channels: dict[str, Tensor]
    pad: Tensor | None


class MSTAProcessor:
    """Owns the statistics: discretizes observations, (un)normalizes actions.

    Args:
        input_sensors: registry names the policy reads.
        stats: column -> {"mean": [...], "std": [...]} for every non-binary input sensor
            and, when ``normalize_action``, for ``action_key``.
        num_bins: bins per scalar.
        clip_std: z-score range covered by the bins.
        action_key: column of the target action.
        normalize_action: z-score actions for the loss.
    """

    def __init__(
        self,
        input_sensors: Sequence[str],
        stats: Mapping[str, Mapping[str, Sequence[float]]],
        num_bins: int = 256,
        clip_std: float = 4.0,
        action_key: str = "action",
        normalize_action: bool = True,
    ) -> None:
        self.input_sensors = tuple(input_sensors)
        self.num_bins = int(num_bins)
        self.clip_std = float(clip_std)
        self.action_key = action_key
        self.normalize_action = bool(normalize_action)
        self.stats: dict[str, dict[str, list[float]]] = {}
        for name in self.input_sensors:
            spec = sensors.get(name)
            if not spec.binary:
                self.stats[spec.column] = _read_stats(
                    stats, spec.column, spec.dim, f"sensor {name!r}"
                )
        if self.normalize_action:
            self.stats[action_key] = _read_stats(stats, action_key, None, "the action target")
        self._cache: dict[tuple[str, torch.device], tuple[Tensor, Tensor]] = {}

    # --- construction and persistence -------------------------------------------------
    @classmethod
    def from_stats(cls, config: MSTAConfig, stats: Mapping[str, Mapping[str, Any]]) -> Self:
        """Processor for ``config`` from dataset statistics (lerobot stats.json layout)."""
        return cls(
            config.input_sensors,
            stats,
            config.num_bins,
            config.clip_std,
            config.action_key,
            config.normalize_action,
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "format": FORMAT,
            "input_sensors": list(self.input_sensors),
            "num_bins": self.num_bins,
            "clip_std": self.clip_std,
            "action_key": self.action_key,
            "normalize_action": self.normalize_action,
            "stats": self.stats,
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Self:
        if data.get("format") != FORMAT:
            raise ValueError(f"processor format {data.get('format')!r} is not {FORMAT!r}")
        return cls(
            data["input_sensors"],
            data["stats"],
            data["num_bins"],
            data["clip_std"],
            data["action_key"],
            data["normalize_action"],
        )

    # --- observations -> bins ---------------------------------------------------------
    def discretize(self, batch: Batch, channels: Channels | None = None) -> MSTAInputs:
        """Validate a raw batch and turn every present sensor into bin indices.

        Args:
            batch: sensor name -> (B, T, c) raw values (c = dim, or len(channels[name]));
                optional "pad" (B, T) bool; the action target key is ignored here.
            channels: sensor name -> channel indices present in that sensor's tensor.
        """
        channels = dict(channels or {})
        present = [k for k in batch if k not in (PAD_KEY, self.action_key)]
        for name in list(present) + list(channels):
            self._check_input_sensor(name)
        for name in channels:
            if name not in batch:
                raise ValueError(f"channels given for sensor {name!r}, which is not in the batch")
        if not present:
            raise ValueError(
                f"batch holds no input sensor; expected some of {list(self.input_sensors)}"
            )
        shape = None
        bins, chans = {}, {}
        for name in self.input_sensors:  # canonical order: the dict order never matters
            if name not in batch:
                continue
            x = batch[name]
            idx = self._channel_index(name, channels.get(name), x)
            if shape is None:
                shape = x.shape[:2]
            elif x.shape[:2] != shape:
                raise ValueError(
                    f"sensor {name!r} has (B, T) = {tuple(x.shape[:2])}, others {tuple(shape)}"
                )
            if not torch.isfinite(x).all():
                bad = (~torch.isfinite(x)).nonzero()[0].tolist()
                raise ValueError(f"sensor {name!r} has a non-finite value (NaN/inf) at index {bad}")
            bins[name] = self._bin(name, x, idx)
            chans[name] = idx
        return MSTAInputs(bins, chans, self._pad(batch, shape))

    def _check_input_sensor(self, name: str) -> None:
        sensors.get(name)  # KeyError naming the unknown sensor and listing the known ones
        if name not in self.input_sensors:
            raise ValueError(
                f"sensor {name!r} is not an input of this policy (inputs: {list(self.input_sensors)})"
            )

    def _channel_index(self, name: str, chosen: Sequence[int] | None, x: Tensor) -> Tensor:
        dim = sensors.get(name).dim
        if x.dim() != 3:
            raise ValueError(
                f"sensor {name!r} must be (B, T, channels), got shape {tuple(x.shape)}"
            )
        if chosen is None:
            chosen = range(dim)
        idx = [int(i) for i in chosen]
        if not idx or len(set(idx)) != len(idx) or min(idx) < 0 or max(idx) >= dim:
            raise ValueError(
                f"channels for {name!r} must be distinct indices in [0, {dim}), got {idx}"
            )
        if x.shape[-1] != len(idx):
            raise ValueError(f"sensor {name!r} has {x.shape[-1]} channels, expected {len(idx)}")
        return torch.tensor(idx, dtype=torch.long, device=x.device)

    def _bin(self, name: str, x: Tensor, idx: Tensor) -> Tensor:
        top = self.num_bins - 1
        spec = sensors.get(name)
        if spec.binary:
            return (x > 0.5).long() * top  # (B, T, c) in {0, top}
        mean, std = self._tensors(spec.column, x.device)
        z = (x.float() - mean[idx]) / std[idx]  # (B, T, c)
        u = (z + self.clip_std) * (self.num_bins / (2.0 * self.clip_std))
        return u.floor().clamp_(0, top).long()

    def _pad(self, batch: Batch, shape: torch.Size | None) -> Tensor | None:
        pad = batch.get(PAD_KEY)
        if pad is None:
            return None
        if pad.dtype != torch.bool or tuple(pad.shape) != tuple(shape):
            raise ValueError(
                f"'pad' must be a bool tensor of shape {tuple(shape)}, got {pad.dtype} {tuple(pad.shape)}"
            )
        if pad[:, -1].any():
            raise ValueError(
                "'pad' marks the newest step as padding; every window needs a real last step"
            )
        return pad if pad.any() else None

    # --- actions ----------------------------------------------------------------------
    def normalize_target(self, action: Tensor) -> Tensor:
        """Raw action (B, A) -> the model's target space."""
        if not self.normalize_action:
            return action.float()
        mean, std = self._tensors(self.action_key, action.device)
        _check_action_dim(action, mean)
        return (action.float() - mean) / std

    def unnormalize_action(self, action: Tensor) -> Tensor:
        """Model output (B, A) -> raw desired joint positions."""
        if not self.normalize_action:
            return action
        mean, std = self._tensors(self.action_key, action.device)
        _check_action_dim(action, mean)
        return action * std + mean

    def _tensors(self, column: str, device: torch.device) -> tuple[Tensor, Tensor]:
        key = (column, device)
        if key not in self._cache:
            s = self.stats[column]
            mean = torch.tensor(s["mean"], dtype=torch.float32, device=device)
            std = torch.tensor(s["std"], dtype=torch.float32, device=device).clamp(min=MIN_STD)
            self._cache[key] = (mean, std)
        return self._cache[key]


def _read_stats(
    stats: Mapping[str, Mapping[str, Any]], column: str, dim: int | None, what: str
) -> dict:
    if column not in stats:
        raise KeyError(
            f"statistics have no column {column!r} (needed for {what}); "
            f"available columns: {sorted(stats)}"
        )
    out = {}
    for field in ("mean", "std"):
        if field not in stats[column]:
            raise KeyError(f"statistics of column {column!r} have no {field!r} entry")
        values = [float(v) for v in _flat(stats[column][field])]
        if dim is not None and len(values) != dim:
            raise ValueError(
                f"statistics {column!r}.{field} has {len(values)} values, sensor has {dim} channels"
            )
        if not all(math.isfinite(v) for v in values) or (field == "std" and min(values) < 0):
            raise ValueError(f"statistics {column!r}.{field} has invalid values: {values}")
        out[field] = values
    if len(out["mean"]) != len(out["std"]):
        raise ValueError(f"statistics {column!r}: mean and std differ in length")
    return out


def _flat(values: Any) -> list[float]:
    """Stats may come as lists, nested lists (lerobot keeps shape), numpy arrays or tensors."""
    if hasattr(values, "tolist"):
        values = values.tolist()
    if isinstance(values, (int, float)):
        return [values]
    out: list[float] = []
    for v in values:
        out.extend(_flat(v))
    return out


def _check_action_dim(action: Tensor, mean: Tensor) -> None:
    if action.dim() != 2 or action.shape[-1] != mean.numel():
        raise ValueError(f"action must be (B, {mean.numel()}), got shape {tuple(action.shape)}")
