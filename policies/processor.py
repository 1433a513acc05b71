"""The processor base every student builds on: statistics lookup, input validation,
z-scoring and action (un)normalization.

A processor owns the dataset statistics a student normalizes with and is saved next to the
weights as processor.json (no pickle). A statistics column it needs but cannot find raises:
normalization is never skipped silently. Subclasses turn the validated, z-scored windows
into their model's inputs (MSTA: bin indices; the timestep baselines: one vector per step)
and name their ``FORMAT`` and extra settings (``SETTINGS``).

Binary sensors (``SensorSpec.binary``, e.g. foot_contact) have no statistics: they are
thresholded at 0.5 (:meth:`StudentProcessor.binary`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, ClassVar, Self

import torch
from torch import Tensor

from msta.data import sensors
from msta.data.stats import MIN_STD  # the normalizer's floor (:func:`effective_std`)

#: Per-sensor channel subsets: ``{"joint_pos": [0, 1, 2, 4, ...]}`` lists the channel
#: indices present in the batch tensor (in that order). Sensors not listed carry all channels.
Channels = Mapping[str, Sequence[int]]
#: Sensor name -> (B, T, c) window; tensors or numpy arrays (converted on the policy's device).
Batch = Mapping[str, Any]

PAD_KEY = "pad"


def effective_std(std: Tensor) -> Tensor:
    """The std a normalizer divides by: ``std``, with 1 where it is below :data:`MIN_STD`.

    A constant channel is legitimate data, but dividing by its (near) zero std turns any
    later difference from the constant (a validation episode, the robot, statistics that
    do not match the data) into a z-score of 1e6 or more: an unclipped action target then
    gave training losses of 1e12. With 1 the z-score of such a channel is its offset from
    the mean in raw units, as scikit-learn's StandardScaler does for constant features.
    """
    return torch.where(std < MIN_STD, torch.ones_like(std), std)


class StudentProcessor:
    """Statistics owner of a student (subclassed by MSTA's and the baselines' processors).

    Args:
        input_sensors: registry names the policy reads.
        stats: column -> {"mean": [...], "std": [...]} for every non-binary input sensor and,
            when ``normalize_action``, for ``action_key``; a missing column raises KeyError.
        clip_std: z-score range the subclass clips to.
        action_key: column of the target action.
        normalize_action: z-score actions for the loss.
    """

    #: ``"format"`` entry of processor.json; from_dict refuses any other.
    FORMAT: ClassVar[str]
    #: Subclass settings: config fields, ``__init__`` keywords and processor.json keys at
    #: once (MSTA: ``("num_bins",)``).
    SETTINGS: ClassVar[tuple[str, ...]] = ()

    def __init__(
        self,
        input_sensors: Sequence[str],
        stats: Mapping[str, Mapping[str, Any]],
        clip_std: float = 4.0,
        action_key: str = "action",
        normalize_action: bool = True,
    ) -> None:
        self.input_sensors = tuple(input_sensors)
        self.clip_std = float(clip_std)
        self.action_key = action_key
        self.normalize_action = bool(normalize_action)
        self.stats: dict[str, dict[str, list[float]]] = {}
        for name in self.input_sensors:
            spec = sensors.get(name)
            if not spec.binary:
                self.stats[spec.column] = read_stats(
                    stats, spec.column, spec.dim, f"sensor {name!r}"
                )
        if self.normalize_action:
            self.stats[action_key] = read_stats(stats, action_key, None, "the action target")
        self._cache: dict[tuple[str, torch.device], tuple[Tensor, Tensor]] = {}

    # --- construction and persistence -------------------------------------------------
    @classmethod
    def from_stats(cls, config: Any, stats: Mapping[str, Mapping[str, Any]]) -> Self:
        """Processor for a policy ``config`` from dataset statistics (stats.json layout).

        Args:
            config: a :class:`msta.policies.config.PolicyConfig`.
            stats: ``{column: {"mean": [...], "std": [...], ...}}``.
        """
        return cls(config.input_sensors, stats, clip_std=config.clip_std,
                   action_key=config.action_key, normalize_action=config.normalize_action,
                   **{k: getattr(config, k) for k in cls.SETTINGS})

    def to_dict(self) -> dict[str, Any]:
        return {
            "format": self.FORMAT,
            "input_sensors": list(self.input_sensors),
            **{k: getattr(self, k) for k in self.SETTINGS},
            "clip_std": self.clip_std,
            "action_key": self.action_key,
            "normalize_action": self.normalize_action,
            "stats": self.stats,
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Self:
        """Rebuild from :meth:`to_dict` output (processor.json); another format raises."""
        if data.get("format") != cls.FORMAT:
            raise ValueError(f"processor format {data.get('format')!r} is not {cls.FORMAT!r}")
        return cls(data["input_sensors"], data["stats"], clip_std=data["clip_std"],
                   action_key=data["action_key"], normalize_action=data["normalize_action"],
                   **{k: data[k] for k in cls.SETTINGS})

    # --- validation -------------------------------------------------------------------
    def present_inputs(
        self, batch: Batch, channels: Channels | None = None
    ) -> list[tuple[str, Tensor, Tensor]]:
        """Validate a raw batch; (name, window (B, T, c), channel indices (c,)) of every
        input sensor present, in config order (the batch's dict order never matters).

        Args:
            batch: sensor name -> (B, T, c) raw values (c = dim, or len(channels[name]));
                optional "pad" (B, T) bool; the action target key is ignored here.
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
        shape = None
        out = []
        for name in self.input_sensors:
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
            if not torch.jit.is_tracing() and not torch.isfinite(x).all():  # (export: no check)
                bad = (~torch.isfinite(x)).nonzero()[0].tolist()
                raise ValueError(f"sensor {name!r} has a non-finite value (NaN/inf) at index {bad}")
            out.append((name, x, idx))
        return out

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

    def pad_mask(self, batch: Batch, shape: torch.Size | None) -> Tensor | None:
        """The batch's "pad" (B, T) checked against ``shape``; None when absent or all False."""
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

    # --- values -----------------------------------------------------------------------
    @staticmethod
    def binary(x: Tensor) -> Tensor:
        """A binary sensor's raw values -> bool (threshold 0.5). (B, T, c) -> (B, T, c)."""
        return x > 0.5

    def zscore(self, name: str, x: Tensor, idx: Tensor) -> Tensor:
        """Channels ``idx`` of non-binary sensor ``name`` -> z-scores (not clipped)."""
        mean, std = self._tensors(sensors.get(name).column, x.device)
        return (x.float() - mean[idx]) / std[idx]  # (B, T, c)

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

    @torch.inference_mode(False)  # cached: must stay usable by training after inference
    def _tensors(self, column: str, device: torch.device) -> tuple[Tensor, Tensor]:
        key = (column, device)
        if key not in self._cache:
            s = self.stats[column]
            mean = torch.tensor(s["mean"], dtype=torch.float32, device=device)
            std = effective_std(torch.tensor(s["std"], dtype=torch.float32, device=device))
            self._cache[key] = (mean, std)
        return self._cache[key]


def read_stats(
    stats: Mapping[str, Mapping[str, Any]], column: str, dim: int | None, what: str
) -> dict[str, list[float]]:
    """``{"mean": [...], "std": [...]}`` of ``column``, checked (present, finite, std >= 0,
    ``dim`` values when given); errors name the column and what needed it."""
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
