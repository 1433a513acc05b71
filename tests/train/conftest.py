"""Fixtures for the training tests: a small synthetic dataset with a learnable target."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from msta_test_helpers import random_episode  # registered by tests/conftest.py

from msta.data import sensors
from msta.data.writer import DatasetWriter

#: action = command_vx * W (the same for every step of an episode): learnable even when
#: 75 % of the tokens are removed, because the command repeats over the window.
W = np.linspace(-1.0, 1.0, 12).astype(np.float32)
TERRAINS = ("flat", "stairs_up")


def synthetic_episode(length: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Random inputs, then a command and the action it determines (``W``)."""
    out = random_episode(length, rng)
    vx = rng.uniform(-1, 1)
    out[sensors.get("command").column][:] = [vx, 0.0, 0.0]
    out["action"] = (vx * W)[None].repeat(length, 0) + 0.01 * rng.standard_normal(
        (length, 12)).astype(np.float32)
    out["executed_action"] = out["action"].copy()
    return out


def write_synthetic(root: Path, episodes: int = 12, length: int = 40, seed: int = 0) -> Path:
    rng = np.random.default_rng(seed)
    with DatasetWriter.create(root, "local/train_test") as w:
        for i in range(episodes):
            w.add_episode(synthetic_episode(length, rng), {
                "terrain": TERRAINS[i % 2], "terrain_level": 0, "source": "teacher",
                "round": 0, "policy": "synthetic", "policy_revision": "", "seed": i})
    return root


@pytest.fixture(scope="session")
def synthetic_dataset(tmp_path_factory) -> Path:
    """12 episodes x 40 frames, built once per session (read-only for the tests)."""
    return write_synthetic(tmp_path_factory.mktemp("train_data") / "ds")
