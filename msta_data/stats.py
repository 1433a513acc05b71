"""Per-channel statistics in lerobot's format.

For every numeric column: ``min``, ``max``, ``mean``, ``std``, ``count`` and the quantiles
``q01``, ``q10``, ``q50``, ``q90``, ``q99`` (lerobot's ``DEFAULT_QUANTILES``), each an
array with one value per channel (``count`` has shape ``(1,)``).

* Per episode (:func:`episode_stats`): exact values, vectorised over channels (lerobot
  estimates the quantiles from 5000-bin histograms, one channel at a time, which is the
  slowest part of its writer; the format is the same).
* Across episodes (:func:`aggregate`): lerobot's own ``aggregate_stats`` — exact
  count-weighted mean and pooled variance, min/max, and count-weighted averages of the
  per-episode quantiles (an approximation, as in lerobot). Aggregation is associative, so
  appending episodes to a dataset gives the same ``meta/stats.json`` as writing them all
  at once, up to floating-point rounding.

The MSTA tokenizer normalises each scalar and discretises it into 256 bins; ``mean``/
``std`` (normalisation) and ``q01``/``q99`` or ``min``/``max`` (bin range) per channel
are all here.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from msta.data import layout as L

#: A channel whose std is below this never varied in the data (a constant channel, or
#: statistics that say so): it is z-scored with std 1 (``msta.policies.processor.effective_std``;
#: the sensor faults size themselves by the same std).
MIN_STD = 1e-6

QUANTILES: tuple[float, ...] = (0.01, 0.10, 0.50, 0.90, 0.99)
QUANTILE_KEYS: tuple[str, ...] = tuple(f"q{int(q * 100):02d}" for q in QUANTILES)
STAT_KEYS: tuple[str, ...] = ("min", "max", "mean", "std", "count", *QUANTILE_KEYS)

Stats = dict[str, dict[str, np.ndarray]]


def column_stats(values: np.ndarray) -> dict[str, np.ndarray]:
    """Statistics of one column of one episode.

    Args:
        values: ``(L,)`` for scalar columns or ``(L, D)`` for vector columns; bool and
            integer columns are treated as float (as lerobot does).

    Returns:
        stat name -> float64 array of shape ``(D,)`` (``(1,)`` for scalars), ``count``
        an int64 array of shape ``(1,)``.
    """
    return episode_stats({"x": values})["x"]


def episode_stats(columns: dict[str, np.ndarray]) -> Stats:
    """Statistics of every column of one episode (see :func:`column_stats`).

    All columns are stacked into one ``(D_total, L)`` float64 matrix and sorted once per
    channel; quantiles use numpy's default linear interpolation (``np.quantile``).
    """
    parts, dims = [], []
    length = None
    for col, v in columns.items():
        x = np.asarray(v)
        x = x[:, None] if x.ndim == 1 else x
        if x.ndim != 2 or x.shape[0] == 0 or (length is not None and x.shape[0] != length):
            raise ValueError(f"column {col!r}: expected a non-empty (L,) or (L, D) array with "
                             f"the episode's length, got shape {np.shape(v)}")
        length = x.shape[0]
        parts.append(x.T.astype(np.float64))
        dims.append(x.shape[1])
    if not parts:
        return {}
    xs = np.sort(np.concatenate(parts), axis=1)  # (D_total, L)
    assert length is not None
    mean = xs.mean(axis=1)
    std = np.sqrt(np.maximum(0.0, (xs * xs).mean(axis=1) - mean * mean))
    pos = np.asarray(QUANTILES) * (length - 1)
    lo = np.floor(pos).astype(np.int64)
    hi = np.minimum(lo + 1, length - 1)
    frac = pos - lo
    quant = xs[:, lo] + frac * (xs[:, hi] - xs[:, lo])  # (D_total, Q)
    out: Stats = {}
    start = 0
    for col, d in zip(columns, dims, strict=True):
        sl = slice(start, start + d)
        st = {"min": xs[sl, 0], "max": xs[sl, -1], "mean": mean[sl], "std": std[sl],
              "count": np.array([length], dtype=np.int64)}
        for j, key in enumerate(QUANTILE_KEYS):
            st[key] = quant[sl, j].copy()
        out[col] = {k: np.array(v) for k, v in st.items()}
        start += d
    return out


def aggregate(stats_list: Iterable[Stats]) -> Stats:
    """Aggregate statistics of several episodes or datasets.

    The same formulas as lerobot's ``compute_stats.aggregate_stats`` (a test checks they
    agree): count-weighted mean, pooled variance, min of mins, max of maxes, and
    count-weighted means of the quantiles. Re-implemented only to keep the ~15 s lerobot
    import out of the writer.
    """
    stats_list = [s for s in stats_list if s]
    keys = list(dict.fromkeys(k for s in stats_list for k in s))
    out: Stats = {}
    for key in keys:
        group = [s[key] for s in stats_list if key in s]
        counts = np.stack([np.asarray(g["count"], np.float64) for g in group])  # (n, 1)
        total = counts.sum(axis=0)
        means = np.stack([g["mean"] for g in group])  # (n, D)
        mean = (means * counts).sum(axis=0) / total
        var = ((np.stack([g["std"] for g in group]) ** 2 + (means - mean) ** 2)
               * counts).sum(axis=0) / total
        agg = {"min": np.min(np.stack([g["min"] for g in group]), axis=0),
               "max": np.max(np.stack([g["max"] for g in group]), axis=0),
               "mean": mean, "std": np.sqrt(var),
               "count": np.array([int(total[0])], dtype=np.int64)}
        for q in QUANTILE_KEYS:
            if all(q in g for g in group):
                agg[q] = (np.stack([g[q] for g in group]) * counts).sum(axis=0) / total
        out[key] = agg
    return out


def to_episode_columns(stats: Stats) -> dict[str, list]:
    """Flatten to lerobot's ``meta/episodes`` columns: ``stats/<column>/<stat>`` -> list."""
    out: dict[str, list] = {}
    for col, st in stats.items():
        for key in STAT_KEYS:
            value = st[key]
            out[f"stats/{col}/{key}"] = (
                [int(v) for v in value] if key == "count" else [float(v) for v in value])
    return out


def from_episode_columns(row: dict[str, list]) -> Stats:
    """Inverse of :func:`to_episode_columns` for one episode row (other keys ignored)."""
    out: Stats = {}
    for name, value in row.items():
        if not name.startswith("stats/"):
            continue
        col, key = name[len("stats/"):].rsplit("/", 1)
        dtype = np.int64 if key == "count" else np.float64
        out.setdefault(col, {})[key] = np.asarray(value, dtype=dtype)
    return out


def to_json(stats: Stats) -> dict[str, dict[str, list]]:
    """JSON-serialisable form, as lerobot's ``meta/stats.json``."""
    return {col: {k: np.asarray(v).tolist() for k, v in st.items()} for col, st in stats.items()}


def load_stats(root: str | Path) -> Stats:
    """Read ``meta/stats.json`` into float64 arrays (``count`` int64)."""
    raw = json.loads((Path(root) / L.STATS_PATH).read_text())
    return {col: {k: np.asarray(v, dtype=np.int64 if k == "count" else np.float64)
                  for k, v in st.items()} for col, st in raw.items()}
