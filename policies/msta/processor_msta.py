"""MSTA processor: raw sensor windows -> bin indices; z-scored actions <-> raw actions.

Binning (the paper only says "normalized, discretized to 256 bins"):
each channel is z-scored with the dataset's per-channel mean and std, clipped to
``[-clip_std, clip_std]`` and cut into ``num_bins`` equal-width bins; binary sensors
(``SensorSpec.binary``, e.g. foot_contact) use only the two end bins (0 and num_bins - 1,
threshold 0.5). A sensor the registry marks ``encoder_tokens`` > 0 (e.g. the ``height_map``
extension) is not binned: its clipped z-scores go to the model's MLP encoder. The
processor is saved with the weights as processor.json; a statistics
column it needs but cannot find raises (it never skips normalization silently).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from torch import Tensor

from msta.data import sensors
from msta.policies.processor import Batch, Channels, StudentProcessor

FORMAT = "msta-processor/1"
__all__ = ["FORMAT", "MSTAInputs", "MSTAProcessor"]


@dataclass
class MSTAInputs:
    """Model-ready inputs.

    Args:
        bins: sensor name -> bin indices (B, T, c), long.
        channels: sensor name -> channel indices present (c,), long.
        pad: (B, T) bool, True where the step lies before the episode start; or None.
        encoded: sensor name -> clipped z-scores (B, T, dim) of the sensors an MLP encodes
            into tokens (``SensorSpec.encoder_tokens`` > 0), all channels; not in ``bins``.
        absent: sensor name -> (B, dim) bool over the sensor's full channels, True = removed
            for that sample at every step (:mod:`msta.policies.msta.removal`); or None.
    """

    bins: dict[str, Tensor]
    channels: dict[str, Tensor]
    pad: Tensor | None
    encoded: dict[str, Tensor] = field(default_factory=dict)
    absent: dict[str, Tensor] | None = None


class MSTAProcessor(StudentProcessor):
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

    FORMAT = FORMAT
    SETTINGS = ("num_bins",)

    def __init__(
        self,
        input_sensors: Sequence[str],
        stats: Mapping[str, Mapping[str, Any]],
        num_bins: int = 256,
        clip_std: float = 4.0,
        action_key: str = "action",
        normalize_action: bool = True,
    ) -> None:
        super().__init__(input_sensors, stats, clip_std=clip_std, action_key=action_key,
                         normalize_action=normalize_action)
        self.num_bins = int(num_bins)

    def discretize(self, batch: Batch, channels: Channels | None = None) -> MSTAInputs:
        """Validate a raw batch and turn every present sensor into bin indices.

        Args:
            batch: sensor name -> (B, T, c) raw values (c = dim, or len(channels[name]));
                optional "pad" (B, T) bool; the action target key is ignored here.
            channels: sensor name -> channel indices present in that sensor's tensor.
        """
        bins, chans, encoded = {}, {}, {}
        present = self.present_inputs(batch, channels)
        for name, x, idx in present:
            spec = sensors.get(name)
            if spec.encoder_tokens:
                if idx.numel() != spec.dim:
                    raise ValueError(f"sensor {name!r} is encoded as a whole (an MLP reads all "
                                     f"{spec.dim} channels of a step); got {idx.numel()} channels")
                encoded[name] = self.zscore(name, x, idx).clamp(-self.clip_std, self.clip_std)
                continue
            bins[name] = self._bin(name, x, idx)
            chans[name] = idx
        return MSTAInputs(bins, chans, self.pad_mask(batch, present[0][1].shape[:2]), encoded)

    def _bin(self, name: str, x: Tensor, idx: Tensor) -> Tensor:
        top = self.num_bins - 1
        if sensors.get(name).binary:
            return self.binary(x).long() * top  # (B, T, c) in {0, top}
        z = self.zscore(name, x, idx)  # (B, T, c)
        u = (z + self.clip_std) * (self.num_bins / (2.0 * self.clip_std))
        return u.floor().clamp_(0, top).long()
