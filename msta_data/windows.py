"""In-memory windowed reader: T-step sensor histories with per-step padding flags.

``WindowDataset`` loads the chosen columns of the chosen episodes once into contiguous
float32 arrays and serves batches with one numpy gather per batch — no per-sample Parquet
or Python work (lerobot's ``delta_timestamps`` path fetches whole rows per query).

Sample ``i`` is the dataset row ``i`` of the selected episodes (episode order) and its
window is rows ``i-T+1 .. i``. Steps before the episode's first frame do not exist: they
are *filled by repeating the episode's first frame* and flagged ``pad[t] = True`` (the
model should mask them; lerobot clamps the same way and calls the flag ``*_is_pad``).

Everything is validated when the dataset is opened (schema version, fps, column presence,
Arrow type and width, nulls, NaN/Inf, index consistency, Parquet page checksums), then every
committed file is checked against the size and sha256 recorded at commit
(:mod:`msta.data.integrity`; a changed byte that still decodes is caught there); errors name
the file and column. Nothing is skipped or filled silently.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa

from msta.data import features as F
from msta.data import integrity as I
from msta.data import layout as L
from msta.data import sensors as registry
from msta.data.errors import DatasetFormatError
from msta.data.integrity import fixed_size

_INDEX_COLUMNS = ("index", "episode_index", "frame_index", "timestamp")


def load_episode_table(root: str | Path) -> pd.DataFrame:
    """Committed episodes' metadata (no stats): indices, lengths, tasks and the
    ``provenance/*`` columns, one row per episode in ``episode_index`` order."""
    info = F.load_info(root)
    return F.read_episode_table(root, info).to_pandas()


def episode_split(root: str | Path, val_fraction: float = 0.1,
                  seed: int = 0) -> tuple[list[int], list[int]]:
    """Random train/validation split of a dataset's episode indices.

    Args:
        root: dataset root.
        val_fraction: share of episodes for validation, in [0, 1).
        seed: RNG seed (the split is a pure function of it and the episode count).

    Returns:
        (train episode indices, validation episode indices), both sorted.
    """
    if not 0.0 <= val_fraction < 1.0:
        raise ValueError(f"val_fraction must be in [0, 1), got {val_fraction}")
    n = int(F.load_info(root)["total_episodes"])
    n_val = min(n - 1, max(1, round(val_fraction * n))) if val_fraction > 0 and n > 1 else 0
    perm = np.random.default_rng(seed).permutation(n)
    return sorted(perm[n_val:].tolist()), sorted(perm[:n_val].tolist())


def _column_to_numpy(table: pa.Table, col: str, ft: dict[str, Any], path: Path) -> np.ndarray:
    """Arrow column -> ``(N, dim)`` (vectors) or ``(N,)`` (scalars), type-checked."""
    want = F.arrow_type(ft)
    arr = table.column(col)
    if pa.types.is_fixed_size_list(want) and arr.type in (pa.list_(want.value_type),
                                                           pa.large_list(want.value_type)):
        arr = pa.chunked_array([fixed_size(arr.combine_chunks(), want.list_size,
                                           f"{path}: column {col!r}")])
    same = arr.type == want or (pa.types.is_fixed_size_list(arr.type)
                                and pa.types.is_fixed_size_list(want)
                                and arr.type.list_size == want.list_size
                                and arr.type.value_type == want.value_type)
    if not same:
        raise DatasetFormatError(f"{path}: column {col!r} has Arrow type {arr.type}, "
                                 f"expected {want}")
    arr = arr.combine_chunks()
    if pa.types.is_fixed_size_list(arr.type):
        flat = arr.flatten()
        if arr.null_count or flat.null_count:
            raise DatasetFormatError(f"{path}: column {col!r} contains nulls")
        return flat.to_numpy(zero_copy_only=False).reshape(len(arr), want.list_size)
    if arr.null_count:
        raise DatasetFormatError(f"{path}: column {col!r} contains nulls")
    return arr.to_numpy(zero_copy_only=False)


class WindowDataset:
    """T-step windows of sensor columns, fully in memory.

    Args:
        root: dataset root (LeRobot v3.0, written by :class:`~msta.data.writer.DatasetWriter`).
        sensors: registry names whose columns to load, e.g. ``STUDENT_SENSORS``.
        T: history length (window = current step and the ``T-1`` before it).
        extra_columns: other columns returned at the current step only (``"action"``,
            ``"executed_action"``, ``"next.reward"``, ...).
        episodes: episode indices to load; ``None`` = all committed episodes.
        fps: expected dataset fps (checked against ``info.json`` and the timestamps).
        verify: check the committed files against ``meta/msta_checksums.json`` after
            loading: ``"full"`` (sha256, cached per process), ``"sizes"``, or ``None``.

    ``get_batch(indices)`` returns ``{sensor: (B, T, dim) float32, extra: (B, dim) or (B,),
    "pad": (B, T) bool}``.
    """

    def __init__(self, root: str | Path, sensors: Sequence[str], T: int = 15,
                 extra_columns: Sequence[str] = ("action",),
                 episodes: Sequence[int] | None = None, fps: int = F.DEFAULT_FPS,
                 verify: I.VerifyMode | None = "full") -> None:
        if isinstance(sensors, str) or not sensors:
            raise ValueError(f"sensors must be a non-empty sequence of names, got {sensors!r}")
        if T < 1:
            raise ValueError(f"T must be >= 1, got {T}")
        self.root = Path(root)
        self.T = int(T)
        self.sensors = tuple(sensors)
        self.extra_columns = tuple(extra_columns)
        self.info = F.load_info(self.root, fps=fps)
        self.fps = int(self.info["fps"])
        specs = [registry.get(s) for s in self.sensors]
        for col in [s.column for s in specs] + list(self.extra_columns):
            F.check_column_feature(self.info, col, self.root)
        self._slices: dict[str, slice] = {}
        start = 0
        for s in specs:
            self._slices[s.name] = slice(start, start + s.dim)
            start += s.dim
        self._columns = {s.column: s.name for s in specs}
        table = F.read_episode_table(self.root, self.info)
        self.episodes = self._select(table, episodes)
        if not self.episodes:
            raise ValueError(f"{self.root}: no episodes selected (dataset has "
                             f"{self.info['total_episodes']})")
        meta = table.to_pandas().set_index("episode_index").loc[self.episodes]
        self.lengths = meta["length"].to_numpy(np.int64)
        self.starts = np.concatenate([[0], np.cumsum(self.lengths)[:-1]]).astype(np.int64)
        n = int(self.lengths.sum())
        self._obs = np.empty((n, start), np.float32)
        self._extra: dict[str, np.ndarray] = {}
        self._load(meta, n)
        self._ep_start = np.repeat(self.starts, self.lengths)
        self._offsets = np.arange(-self.T + 1, 1, dtype=np.int64)
        if verify is not None:  # after the structural checks, whose errors name the column
            I.verify_dataset(self.root, verify)

    def _select(self, table: pa.Table, episodes: Sequence[int] | None) -> list[int]:
        total = int(self.info["total_episodes"])
        if episodes is None:
            return list(range(total))
        eps = [int(e) for e in episodes]
        bad = [e for e in eps if not 0 <= e < total]
        if bad or len(set(eps)) != len(eps):
            raise ValueError(f"episodes must be distinct indices in [0, {total}); bad: "
                             f"{bad or 'duplicates'}")
        return eps

    def _load(self, meta: pd.DataFrame, n: int) -> None:
        cs = self.info["chunks_size"]
        feats = self.info["features"]
        cols = list(self._columns) + [c for c in self.extra_columns if c not in self._columns]
        for c in self.extra_columns:
            shape = (n,) if tuple(feats[c]["shape"]) == (1,) else (n, feats[c]["shape"][0])
            self._extra[c] = np.empty(shape, np.dtype(feats[c]["dtype"]))
        position = {ep: i for i, ep in enumerate(self.episodes)}
        files = meta.groupby(["data/chunk_index", "data/file_index"], sort=True)
        for (chunk, file), group in files:
            path = self.root / F.numbered_path(L.DATA_PATH, F.file_number(chunk, file, cs), cs)
            table = F.read_parquet(path, cols + list(_INDEX_COLUMNS))
            idx = {c: _column_to_numpy(table, c, F.LEROBOT_DEFAULT_FEATURES[c], path)
                   for c in _INDEX_COLUMNS}
            data = {c: _column_to_numpy(table, c, feats[c], path) for c in cols}
            for c, arr in data.items():
                if arr.dtype.kind == "f" and not np.isfinite(arr).all():
                    row = int(np.argwhere(~np.isfinite(arr.reshape(len(arr), -1)))[0, 0])
                    raise DatasetFormatError(
                        f"{path}: column {c!r} has NaN/Inf at episode "
                        f"{idx['episode_index'][row]}, frame {idx['frame_index'][row]}")
            for ep, row in group.iterrows():
                rows = self._locate(path, idx, int(ep), row)
                lo = int(self.starts[position[int(ep)]])
                dst = slice(lo, lo + int(row["length"]))
                for c, arr in data.items():
                    if c in self._columns:
                        self._obs[dst, self._slices[self._columns[c]]] = arr[rows].reshape(
                            int(row["length"]), -1)
                    if c in self._extra:
                        self._extra[c][dst] = arr[rows]

    def _locate(self, path: Path, idx: dict[str, np.ndarray], ep: int, row: pd.Series) -> slice:
        """Rows of episode ``ep`` in a data file, after checking its index columns."""
        lo, hi = int(row["dataset_from_index"]), int(row["dataset_to_index"])
        if hi - lo != int(row["length"]) or len(idx["index"]) == 0:
            raise DatasetFormatError(f"{path}: episode {ep} metadata is inconsistent")
        first = int(np.searchsorted(idx["index"], lo))
        rows = slice(first, first + hi - lo)
        length = hi - lo
        checks = {
            "index": np.arange(lo, hi),
            "episode_index": np.full(length, ep),
            "frame_index": np.arange(length),
        }
        for col, want in checks.items():
            got = idx[col][rows]
            if len(got) != length or not np.array_equal(got, want):
                raise DatasetFormatError(
                    f"{path}: column {col!r} does not match meta/episodes for episode {ep} "
                    f"(rows {lo}..{hi - 1} missing or out of order; truncated file?)")
        ts = idx["timestamp"][rows].astype(np.float64)
        if np.abs(ts - np.arange(length) / self.fps).max() > 1e-4:
            raise DatasetFormatError(
                f"{path}: column 'timestamp' of episode {ep} is not frame_index / {self.fps}"
                " (wrong fps?)")
        return rows

    # ----- access -------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self._obs)

    def get_batch(self, indices: np.ndarray) -> dict[str, np.ndarray]:
        """Windows ending at the given sample indices.

        Args:
            indices: ``(B,)`` integer sample indices in ``[0, len(self))``.

        Returns:
            ``{sensor: (B, T, dim) float32}`` (views into one gathered array), each extra
            column at the current step (``(B, dim)``, scalars ``(B,)``), and ``"pad"``
            ``(B, T)`` bool, True for steps before the episode start (those steps repeat
            the episode's first frame).
        """
        idx = np.asarray(indices, dtype=np.int64)
        windows, pad = self.windows(idx)
        out: dict[str, np.ndarray] = {name: windows[..., sl] for name, sl in self._slices.items()}
        for c, arr in self._extra.items():
            out[c] = arr[idx]
        out["pad"] = pad
        return out

    def windows(self, indices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(B, T, D)`` float32 windows of every sensor, concatenated in ``sensors`` order,
        and their ``(B, T)`` pad flags (what :meth:`get_batch` splits per sensor)."""
        idx = np.asarray(indices, dtype=np.int64)
        if idx.ndim != 1:
            raise ValueError(f"indices must be 1-D, got shape {idx.shape}")
        if len(idx) and (idx.min() < 0 or idx.max() >= len(self)):
            raise IndexError(f"sample index out of range [0, {len(self)})")
        offsets = idx[:, None] + self._offsets  # (B, T)
        start = self._ep_start[idx][:, None]  # (B, 1)
        return self._obs[np.maximum(offsets, start)], offsets < start

    def __getitem__(self, i: int) -> dict[str, np.ndarray]:
        """One sample (no batch axis), for ``torch.utils.data.DataLoader``."""
        if not -len(self) <= i < len(self):
            raise IndexError(f"sample index {i} out of range [0, {len(self)})")
        batch = self.get_batch(np.array([i % len(self)]))
        return {k: v[0] for k, v in batch.items()}

    def episode_of(self, indices: np.ndarray) -> np.ndarray:
        """Dataset episode index of each sample index."""
        pos = np.searchsorted(self.starts, np.asarray(indices), side="right") - 1
        return np.asarray(self.episodes)[pos]
