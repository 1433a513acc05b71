"""Windows of several datasets as one (``msta-train --more_datasets``): datasets of robots with
different sensor sets train one student, each sample's unrecorded sensors removed.

A sensor one dataset does not record reaches the batch as zeros, and :meth:`WindowUnion.absent_of`
marks those channels removed for those samples, so a student that removes channels per sample
(``supports_absent``: MSTA) sees exactly the readings its robot has.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from msta.data.sensors import get
from msta.data.windows import WindowDataset


class WindowUnion:
    """The windows of several :class:`WindowDataset` parts, indexed one after the other.

    Args:
        parts: the datasets' windows, each of the sensors its dataset records (a subset of
            ``sensors``), of one window length and the same extra columns.
        sensors: the sensors every batch holds (the student's inputs).
    """

    def __init__(self, parts: Sequence[WindowDataset], sensors: Sequence[str]) -> None:
        if not parts:
            raise ValueError("WindowUnion needs at least one dataset")
        self.parts = list(parts)
        self.sensors = tuple(sensors)
        self.T = self.parts[0].T
        extra = self.parts[0].extra_columns
        for p in self.parts:
            if p.T != self.T or p.extra_columns != extra:
                raise ValueError(f"{p.root}: window {p.T} and columns {p.extra_columns} differ "
                                 f"from {self.parts[0].root}'s ({self.T}, {extra})")
            unknown = set(p.sensors) - set(self.sensors)
            if unknown:
                raise ValueError(f"{p.root}: sensors {sorted(unknown)} are not among {self.sensors}")
        self.extra_columns = extra
        self.starts = np.cumsum([0] + [len(p) for p in self.parts])

    def __len__(self) -> int:
        return int(self.starts[-1])

    def _split(self, indices: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """(positions in the batch, indices in the part) of every part."""
        idx = np.asarray(indices, dtype=np.int64)
        if len(idx) and (idx.min() < 0 or idx.max() >= len(self)):
            raise IndexError(f"sample index out of range [0, {len(self)})")
        which = np.searchsorted(self.starts, idx, side="right") - 1
        return [(np.nonzero(which == k)[0], idx[which == k] - self.starts[k])
                for k in range(len(self.parts))]

    def get_batch(self, indices: np.ndarray) -> dict[str, np.ndarray]:
        """As :meth:`WindowDataset.get_batch`, every sensor of ``sensors`` present: zeros for
        the samples of a dataset that does not record it (:meth:`absent_of` marks them)."""
        B = len(indices)
        out: dict[str, np.ndarray] = {
            s: np.zeros((B, self.T, get(s).dim), np.float32) for s in self.sensors}
        out["pad"] = np.zeros((B, self.T), bool)
        for part, (pos, local) in zip(self.parts, self._split(indices)):
            if not len(pos):
                continue
            for k, v in part.get_batch(local).items():
                if k not in out:
                    out[k] = np.zeros((B,) + v.shape[1:], v.dtype)
                out[k][pos] = v
        return out

    def absent_of(self, indices: np.ndarray) -> dict[str, np.ndarray] | None:
        """Sensor -> (B, dim) bool: True for the channels of the samples whose dataset does not
        record the sensor; None when every sample's dataset records every sensor."""
        B = len(indices)
        out: dict[str, np.ndarray] = {}
        for k, (pos, _) in enumerate(self._split(indices)):
            for s in self.sensors:
                if len(pos) and s not in self.parts[k].sensors:
                    mask = out.setdefault(s, np.zeros((B, get(s).dim), bool))
                    mask[pos] = True
        return out or None
