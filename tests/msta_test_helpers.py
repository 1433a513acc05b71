"""Builders shared by the tests of several packages (holds no tests). ``tests/conftest.py``
registers it as the module ``msta_test_helpers``: with --import-mode=importlib the tests
folder is not on sys.path.

- :func:`random_batch`: seeded sensor readings for a student, ``{sensor: (B, steps, dim)}``.
- :func:`random_episode`: one episode's frames with random but finite values in every input
  column of a dataset.
- :func:`overfit`: a student's loss on one batch before and after 150 AdamW steps on it.
- :func:`running_hub`: a real msta hub server on 127.0.0.1 for the duration of a fixture.
- :func:`record_gait`: a few gait-controller episodes recorded in the real simulator.
- :func:`tiny_student`: a tiny student with large seeded random weights.
- :func:`tiny_msta`: a tiny seeded MSTA student with flat statistics.
- :func:`write_robot_spec`: a second robot for tests, the A1's spec under another name.
- :func:`as_before_robots`: a dataset's metadata as msta wrote it before datasets recorded
  their robot.
"""

from __future__ import annotations

import json
import tomllib
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import torch

from msta.data import features as F
from msta.data import integrity as I
from msta.data import layout as L
from msta.data import sensors
from msta.data.robot import A1, RobotDescription


def random_batch(B: int, steps: int, seed: int = 1, names: Sequence[str] | None = None
                 ) -> dict[str, torch.Tensor]:
    """Standard-normal readings ``{name: (B, steps, dim)}`` of the sensors ``names`` (None:
    every student input), drawn in that order from a generator seeded ``seed``; a binary
    sensor's (foot_contact) are then 0/1 (positive draws: 1)."""
    g = torch.Generator().manual_seed(seed)
    names = names or sensors.STUDENT_SENSORS
    batch = {n: torch.randn(B, steps, sensors.get(n).dim, generator=g) for n in names}
    for n, x in batch.items():
        if sensors.get(n).binary:
            batch[n] = (x > 0).float()
    return batch


def random_episode(length: int, rng: np.random.Generator, recorded: Sequence[str] | None = None,
                   scale: float = 1.0, offset: float = 0.0) -> dict[str, np.ndarray]:
    """Frames of one episode of ``length`` steps for a dataset recording ``recorded`` (None:
    the default sensors): every input column drawn from ``rng`` in column order, vectors
    ``scale * N(0, 1) + offset``, scalars N(0, 1), all float32; ``next.done`` only at the end.
    """
    feats = F.build_features(recorded)
    out: dict[str, np.ndarray] = {}
    for col in F.input_columns(feats):
        ft = feats[col]
        if ft["dtype"] == "bool":
            out[col] = np.arange(length) == length - 1
        elif tuple(ft["shape"]) == (1,):
            out[col] = rng.standard_normal(length).astype(np.float32)
        else:
            out[col] = (rng.standard_normal((length, ft["shape"][0])) * scale + offset).astype(
                np.float32)
    return out


def overfit(policy: torch.nn.Module, batch: dict[str, torch.Tensor], steps: int = 150,
            **loss_kw) -> tuple[float, float]:
    """(the loss at the first step, the eval-mode loss after ``steps`` AdamW steps at lr 1e-2
    on ``batch``); ``loss_kw`` go to the training ``policy.loss``."""
    opt = torch.optim.AdamW(policy.parameters(), lr=1e-2, weight_decay=0.0)
    first = None
    for _ in range(steps):
        loss, _ = policy.loss(batch, **loss_kw)
        opt.zero_grad()
        loss.backward()
        opt.step()
        first = first if first is not None else loss.item()
    final, _ = policy.eval().loss(batch)
    return first, final.item()


@contextmanager
def running_hub(root: Path, *tokens: str) -> Iterator[object]:
    """A started ``HubServer`` on 127.0.0.1 storing under ``root`` with the ``user:secret``
    ``tokens``; stopped on exit."""
    from msta.data.hub_server import HubServer, ServerConfig

    srv = HubServer(ServerConfig(root=root, tokens=list(tokens))).start()
    try:
        yield srv
    finally:
        srv.stop()


@contextmanager
def hub_as(root: Path, monkeypatch, user: str = "alice",
           secret: str = "alice-secret-0001") -> Iterator[object]:
    """:func:`running_hub` with one ``user:secret`` token, and huggingface_hub pointed at it
    as that user (``HF_ENDPOINT``, ``HF_TOKEN`` set through ``monkeypatch``)."""
    with running_hub(root, f"{user}:{secret}") as srv:
        monkeypatch.setenv("HF_ENDPOINT", srv.url)
        monkeypatch.setenv("HF_TOKEN", secret)
        yield srv


def record_gait(root: Path, episodes: int, seconds: float) -> Path:
    """``episodes`` gait-teacher episodes of ``seconds`` recorded together in the real
    simulator (terrain curriculum off) into the dataset ``root``."""
    from msta.collect.record import CollectConfig, collect
    from msta.collect.sim.env_config import EnvConfig
    from msta.collect.sim.terrain import TerrainConfig
    from msta.policies.teacher.config import TeacherConfig

    collect(CollectConfig(teacher=TeacherConfig(type="gait"), episodes=episodes,
                          num_envs=episodes, root=str(root), episode_length_s=seconds,
                          progress=False, env=EnvConfig(terrain=TerrainConfig(curriculum=False))))
    return root


def tiny_student(name: str, overrides: dict, root: Path):
    """A tiny ``name`` student (``overrides`` on its preset) with the dataset ``root``'s
    statistics and large random weights (seeded): its actions vary with its inputs."""
    from msta.data.stats import load_stats
    from msta.policies.factory import make_policy
    from msta.policies.registry import get_config_class

    torch.manual_seed(0)
    cfg = get_config_class(name).from_preset("tiny", **overrides)
    policy = make_policy(cfg, load_stats(root))
    gen = torch.Generator().manual_seed(0)
    with torch.no_grad():
        for p in policy.parameters():
            p.add_(0.1 * torch.randn(p.shape, generator=gen))
    return policy.eval()


def tiny_msta(history: int, mean: float = 0.0, action_std: float = 1.0, **overrides):
    """A tiny MSTA student (``overrides`` on the ``tiny`` preset, window ``history``) with
    seeded random weights and flat statistics: every input channel's mean ``mean`` and std 1,
    the action's mean 0 and std ``action_std``."""
    from msta.policies.factory import make_policy
    from msta.policies.msta import MSTAConfig

    torch.manual_seed(0)
    cfg = MSTAConfig.from_preset("tiny", history=history, **overrides)
    stats = {sensors.get(n).column: {"mean": [mean] * sensors.get(n).dim,
                                     "std": [1.0] * sensors.get(n).dim}
             for n in cfg.input_sensors}
    stats["action"] = {"mean": [0.0] * 12, "std": [action_std] * 12}
    return make_policy(cfg, stats)


def write_robot_spec(folder: Path, name: str = "other", base: RobotDescription = A1,
                     sensors: tuple[str, ...] | None = None) -> Path:
    """A robot named ``name`` for tests: a copy of ``base``'s spec file (the A1's) with that
    ``name``, its ``mjcf`` made absolute (``base``'s MJCF) and, when given, ``sensors``,
    written as ``folder/<name>.toml``."""
    data = tomllib.loads(base.spec_file.read_text())
    data.update(name=name, mjcf=str(base.mjcf_path))
    if sensors is not None:
        data["sensors"] = list(sensors)
    path = folder / f"{name}.toml"
    path.write_text("".join(f"{k} = {json.dumps(v)}\n" for k, v in data.items()))
    return path


def as_before_robots(root: Path, robot_type: str = "a1") -> Path:
    """Rewrite the dataset ``root`` as msta wrote it before datasets recorded their robot:
    no ``robot`` in ``meta/msta.json``, ``info.json``'s ``robot_type`` ``robot_type``; the
    checksum manifest records the two files' new bytes (the dataset stays intact)."""
    for rel, key, value in ((L.MSTA_META_PATH, "robot", None),
                            (L.INFO_PATH, "robot_type", robot_type)):
        data = json.loads((root / rel).read_text())
        data.pop(key)
        if value is not None:
            data[key] = value
        (root / rel).write_text(json.dumps(data, indent=4))
    gen = I.Manifest.load(root).committed
    files = {**gen.files, **{rel: I.digest_file(root / rel, use_cache=False)
                             for rel in (L.MSTA_META_PATH, L.INFO_PATH)}}
    new = I.Generation(gen.total_episodes, gen.total_frames, files)
    (root / L.MANIFEST_PATH).write_bytes(I.Manifest(new).dumps())
    return root
