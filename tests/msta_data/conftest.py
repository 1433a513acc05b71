"""Fixtures for the data-layer tests: tiny random (finite) synthetic episodes."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import pytest
from msta_test_helpers import random_episode  # registered by tests/conftest.py

from msta.data.writer import DatasetWriter

TERRAINS = ("smooth_slope", "rough_slope", "stairs_up", "stairs_down", "discrete")


def make_episode(length: int, seed: int, sensors: Sequence[str] | None = None
                 ) -> dict[str, np.ndarray]:
    """Random but finite values for every input column (vectors 2 N(0, 1) + ``seed``, so
    episodes differ in their means); ``next.done`` only at the end."""
    return random_episode(length, np.random.default_rng(seed), sensors, scale=2.0, offset=seed)


def make_provenance(i: int, source: str = "teacher", round_: int = 0) -> dict:
    return {"terrain": TERRAINS[i % len(TERRAINS)], "terrain_level": i % 10, "source": source,
            "round": round_, "policy": "gait" if source == "teacher" else "msta",
            "policy_revision": f"rev{i}", "seed": 1000 + i}


WriteFn = Callable[..., list[dict[str, np.ndarray]]]


@pytest.fixture(scope="session")
def write_dataset() -> WriteFn:
    """``write_dataset(root, lengths, seed0=0, append=False, **writer_kwargs)`` writes one
    episode per length and returns the episodes' frames (in order)."""

    def _write(root: Path, lengths: Sequence[int], seed0: int = 0, append: bool = False,
               sensors: Sequence[str] | None = None, **kw) -> list[dict[str, np.ndarray]]:
        eps = [make_episode(n, seed0 + i, sensors) for i, n in enumerate(lengths)]
        if append:
            writer = DatasetWriter.open(root, **kw)
        else:
            writer = DatasetWriter.create(root, "local/test", sensors=sensors, **kw)
        with writer as w:
            for i, ep in enumerate(eps):
                w.add_episode(ep, make_provenance(seed0 + i))
        return eps

    return _write


@pytest.fixture(scope="session")
def synth():
    """Access to the episode/provenance builders from test modules."""

    class _Synth:
        episode = staticmethod(make_episode)
        provenance = staticmethod(make_provenance)

    return _Synth
