"""The starting rows of MSTA's value tables (``MSTAConfig.value_init``): smooth in the bin,
so neighbouring bins start similar; they are trained after."""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor

from msta.policies.transformer import sincos_1d

__all__ = ["initial_tables"]


def initial_tables(cfg: Any, tables: int) -> Tensor:
    """(tables · num_bins, dim) rows for ``tables`` value tables of ``cfg``'s bins:
    ``linear``: the bin centre's z-score times a random direction per table; ``arc``: constant
    norm, cos / sin of half the z-score on two random directions per table; ``sincos``: the
    bin index's sin-cos code, the same in every table."""
    nb, clip, d = cfg.num_bins, cfg.clip_std, cfg.dim
    bins = torch.arange(nb, dtype=torch.float32)
    z = -clip + (bins + 0.5) * (2 * clip / nb)  # (nb,) bin centres' z-scores
    if cfg.value_init == "linear":
        w = torch.randn(tables, 1, d)  # (tables, 1, d)
        return (z[None, :, None] * w).reshape(-1, d)
    if cfg.value_init == "arc":
        u, v = torch.randn(2, tables, 1, d)  # (tables, 1, d) each
        code = (0.5 * z).cos()[None, :, None] * u + (0.5 * z).sin()[None, :, None] * v
        return code.reshape(-1, d)
    return sincos_1d(bins, d, float(nb)).repeat(tables, 1)
