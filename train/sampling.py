"""Seeded, resumable streams of training-window indices."""

from __future__ import annotations

import numpy as np


class WindowSampler:
    """Batches of sample indices in ``[0, n)``, as a resumable stream.

    Unweighted: every epoch is a fresh permutation of all windows. Weighted: every epoch is
    ``n`` draws with replacement with probabilities ``weights``. Epoch ``e`` depends only
    on ``(seed, e)``, so the position ``(epoch, offset)`` is the whole state.

    Args:
        n: number of windows.
        batch_size: indices per batch (batches may straddle epochs).
        seed: base seed.
        weights: optional per-window sampling weights (normalized here).
    """

    def __init__(self, n: int, batch_size: int, seed: int,
                 weights: np.ndarray | None = None) -> None:
        if n < 1:
            raise ValueError("no training windows to sample from")
        self.n, self.batch_size, self.seed = n, batch_size, seed
        self.p = None
        if weights is not None:
            w = np.asarray(weights, np.float64)
            if w.shape != (n,) or (w < 0).any() or not w.sum() > 0:
                raise ValueError(f"weights must be {n} non-negative values with a positive sum")
            self.p = w / w.sum()
        self.epoch, self.offset = 0, 0
        self._order = self._epoch_order(0)

    def _epoch_order(self, epoch: int) -> np.ndarray:
        rng = np.random.default_rng([self.seed, epoch])
        if self.p is None:
            return rng.permutation(self.n)
        return rng.choice(self.n, size=self.n, p=self.p)

    def next_batch(self) -> np.ndarray:
        parts, need = [], self.batch_size
        while need:
            take = self._order[self.offset:self.offset + need]
            parts.append(take)
            need -= len(take)
            self.offset += len(take)
            if self.offset == self.n:
                self.epoch, self.offset = self.epoch + 1, 0
                self._order = self._epoch_order(self.epoch)
        return np.concatenate(parts)

    def state_dict(self) -> dict[str, int]:
        return {"seed": self.seed, "epoch": self.epoch, "offset": self.offset, "n": self.n}

    def load_state_dict(self, state: dict[str, int]) -> None:
        if state["n"] != self.n or state["seed"] != self.seed:
            raise ValueError(f"sampler state is for n={state['n']}, seed={state['seed']}; "
                             f"this run has n={self.n}, seed={self.seed} (dataset changed?)")
        self.epoch, self.offset = int(state["epoch"]), int(state["offset"])
        self._order = self._epoch_order(self.epoch)
