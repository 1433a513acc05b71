"""Benchmark the data layer against lerobot's stock paths, measured in the same run.

    python -m msta.eval.bench.data [--episodes 20] [--frames 1000]

Write: ``DatasetWriter`` (all registry columns, 20 x 1000 frames) vs lerobot's
``LeRobotDataset.create / add_frame / save_episode / finalize`` on a subset of the same
frames (2 x 500), both in frames/s.
Read: ``WindowDataset.get_batch`` (batch 256, 7 student sensors) vs ``LeRobotDataset``
with ``delta_timestamps`` on the same 7 keys (~100 single samples), both in samples/s,
with the same window length (16 steps) for both.

The last two lines are ``write speed-up vs lerobot: <x>`` and ``read speed-up vs lerobot:
<x>``. Absolute numbers depend on the (shared, noisy) machine; the ratios are the result.
"""

from __future__ import annotations

import logging
import os
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from msta.data import features as F
from msta.data.cli import parse_config
from msta.data.derived import derive
from msta.data.sensors import SENSORS, STUDENT_SENSORS
from msta.data.windows import WindowDataset
from msta.data.writer import DatasetWriter

WINDOW = 16
PROVENANCE = {"terrain": "stairs_up", "terrain_level": 3, "source": "teacher", "round": 0,
              "policy": "gait", "policy_revision": "bench", "seed": 0}


def make_episodes(n: int, length: int, seed: int = 0) -> list[dict[str, np.ndarray]]:
    feats = F.build_features()
    rng = np.random.default_rng(seed)
    eps = []
    for _ in range(n):
        ep = {}
        for col in F.input_columns(feats):
            ft = feats[col]
            if ft["dtype"] == "bool":
                ep[col] = np.arange(length) == length - 1
            else:
                ep[col] = rng.standard_normal((length, ft["shape"][0])).astype(np.float32)
                if tuple(ft["shape"]) == (1,):
                    ep[col] = ep[col][:, 0]
        eps.append(ep)
    return eps


def bench_write_ours(root: Path, eps: list[dict[str, np.ndarray]]) -> float:
    t0 = time.perf_counter()
    with DatasetWriter.create(root, "local/bench") as w:
        for ep in eps:
            w.add_episode(ep, PROVENANCE)
    dt = time.perf_counter() - t0
    return sum(len(ep["action"]) for ep in eps) / dt


def bench_write_lerobot(root: Path, eps: list[dict[str, np.ndarray]]) -> float:
    # lazy: lerobot (~3 s) only for the comparison with its writer
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    # the same columns msta's writer writes: the sensors and the derived state columns
    feats = {c: ft for c, ft in F.build_features(derived=True).items()
             if c not in F.LEROBOT_DEFAULT_FEATURES}
    frames = []  # per-frame dicts prepared outside the timed region
    for ep in eps:
        ep = {**ep, **derive(ep, feats)}
        n = len(ep["action"])
        frames.append([{c: (v[t] if v.ndim == 2 else v[t:t + 1]) for c, v in ep.items()}
                       for t in range(n)])
    t0 = time.perf_counter()
    ds = LeRobotDataset.create("local/bench_stock", fps=F.DEFAULT_FPS, features=feats,
                               root=root, use_videos=False, robot_type="a1")
    for ep_frames in frames:
        for fr in ep_frames:
            ds.add_frame({**fr, "task": F.task_string(F.Provenance(**PROVENANCE))})
        ds.save_episode()
    ds.finalize()
    dt = time.perf_counter() - t0
    return sum(len(f) for f in frames) / dt


def bench_read_ours(root: Path, batch: int, seconds: float = 2.0) -> tuple[float, float]:
    t0 = time.perf_counter()
    wd = WindowDataset(root, STUDENT_SENSORS, T=WINDOW)
    load_s = time.perf_counter() - t0
    rng = np.random.default_rng(0)
    batches = [rng.integers(0, len(wd), batch) for _ in range(64)]
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        for idx in batches:
            wd.get_batch(idx)
        n += batch * len(batches)
    return n / (time.perf_counter() - t0), load_s


def bench_read_lerobot(root: Path, samples: int) -> float:
    # lazy: lerobot (~3 s) only for the comparison with its writer
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    deltas = {SENSORS[s].column: [(k - WINDOW + 1) / F.DEFAULT_FPS for k in range(WINDOW)]
              for s in STUDENT_SENSORS}
    # pyav: msta datasets hold no video, and naming it skips lerobot's torchcodec probe
    ds = LeRobotDataset("local/bench", root=root, delta_timestamps=deltas, video_backend="pyav")
    ds[0]  # warm-up
    rng = np.random.default_rng(0)
    idx = rng.integers(0, len(ds), samples)
    t0 = time.perf_counter()
    for i in idx:
        ds[int(i)]
    return samples / (time.perf_counter() - t0)


@dataclass
class BenchDataConfig:
    """Args:
        episodes: episodes written and read by msta's writer and loader.
        frames: frames per episode.
        stock_episodes: episodes written by lerobot's own writer (slow: fewer).
        stock_frames: frames per episode for lerobot's writer.
        batch_size: windows per batch read through msta's loader.
        stock_samples: samples read through lerobot's LeRobotDataset.
    """

    episodes: int = 20
    frames: int = 1000
    stock_episodes: int = 2
    stock_frames: int = 500
    batch_size: int = 256
    stock_samples: int = 100

    def __post_init__(self) -> None:
        for name, value in vars(self).items():
            if value < 1:
                raise ValueError(f"{name}={value} must be >= 1")


def main(argv: list[str] | None = None) -> None:
    args = parse_config(BenchDataConfig, argv, prog="python -m msta.eval.bench.data")
    logging.disable(logging.WARNING)
    with tempfile.TemporaryDirectory(prefix="msta_bench_") as tmp:
        tmp = Path(tmp)
        # lerobot's loader converts Parquet into an Arrow cache; keep it out of ~/.cache
        os.environ["HF_DATASETS_CACHE"] = str(tmp / "hf_datasets_cache")
        import datasets  # lazy: datasets pulls in pandas and more (~1 s); only this path needs it

        datasets.disable_progress_bars()
        F.data_schema(F.build_features())  # one-time imports (datasets) outside the timing
        eps = make_episodes(args.episodes, args.frames)
        stock_eps = [{c: v[:args.stock_frames] for c, v in ep.items()}
                     for ep in eps[:args.stock_episodes]]
        ours_w = bench_write_ours(tmp / "ours", eps)
        print(f"write  msta DatasetWriter : {ours_w:12,.0f} frames/s "
              f"({args.episodes} x {args.frames} frames, {len(F.build_features(derived=True))} columns)")
        stock_w = bench_write_lerobot(tmp / "stock", stock_eps)
        print(f"write  lerobot add_frame  : {stock_w:12,.0f} frames/s "
              f"({args.stock_episodes} x {args.stock_frames} frames)")
        ours_r, load_s = bench_read_ours(tmp / "ours", args.batch_size)
        print(f"read   msta WindowDataset : {ours_r:12,.0f} samples/s (batch {args.batch_size}, "
              f"{len(STUDENT_SENSORS)} sensors, {WINDOW} steps; load {load_s:.2f} s)")
        stock_r = bench_read_lerobot(tmp / "ours", args.stock_samples)
        print(f"read   lerobot delta_ts   : {stock_r:12,.1f} samples/s "
              f"({args.stock_samples} samples, {len(STUDENT_SENSORS)} keys, {WINDOW} steps)")
    print(f"write speed-up vs lerobot: {ours_w / stock_w:.1f}")
    print(f"read speed-up vs lerobot: {ours_r / stock_r:.1f}")


if __name__ == "__main__":
    main()
