"""A dataset's episodes as the guard reads them (:func:`load_episodes`) and a guard run over
them step by step (:func:`stream`): what msta-guard's fitting (:mod:`msta.train.guard_fit`)
and its evaluation (:mod:`msta.train.guard_eval`) share.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from msta.policies.guard import (
    INPUT_SENSORS,
    P,
    SensorGuard,
)

Episodes = dict[str, np.ndarray]  # {sensor: (E, T, dim)}, plus "length" (E,)


def load_episodes(root: str | Path, episodes: list[int] | None = None) -> Episodes:
    """The guard's inputs of ``episodes`` (None: all) as ``{sensor: (E, Tmax, dim)}``
    float64, each episode padded by repeating its last frame, plus ``length`` (E,) and
    ``terrain`` (E,) (the dataset's ``provenance/terrain``; "" when not recorded)."""
    # lazy: pandas loads when a dataset is read, not for msta-guard --help
    from msta.data.windows import WindowDataset, load_episode_table

    ds = WindowDataset(root, INPUT_SENSORS, T=1, extra_columns=(), episodes=episodes,
                       verify="sizes")
    batch = ds.get_batch(np.arange(len(ds)))
    lengths = ds.lengths
    tmax = int(lengths.max())
    rows = np.minimum(np.arange(tmax)[None], lengths[:, None] - 1) + ds.starts[:, None]
    out = {s: batch[s][:, 0].astype(np.float64)[rows] for s in INPUT_SENSORS}
    table = load_episode_table(root).set_index("episode_index").loc[ds.episodes]
    col = "provenance/terrain"
    out["terrain"] = (table[col].astype(str).to_numpy() if col in table
                      else np.full(len(lengths), "", dtype=object))
    out["length"] = lengths
    return out


def stream(guard: SensorGuard, data: Episodes, injector=None) -> dict[str, np.ndarray]:
    """Run ``guard`` (num_envs = episodes) over ``data`` step by step, faults from
    ``injector`` (a ``msta.collect.faults.FaultInjector`` or None). Returns ``max_stat`` (S,)
    over valid steps, ``flags`` (E, T, P) bool latched flags, ``active`` (E, T) bool and
    ``changed`` (E, T) bool: the fault changed a reading at that step."""
    e, tmax = data["length"].shape[0], int(data["length"].max())
    guard.reset()
    if injector is not None:
        injector.reset(np.arange(e))
    max_stat = np.zeros(len(guard.names))
    flags = np.zeros((e, tmax, P), bool)
    active = np.zeros((e, tmax), bool)
    changed = np.zeros((e, tmax), bool)
    for t in range(tmax):
        obs = {s: data[s][:, t] for s in INPUT_SENSORS}
        if injector is not None:
            clean, obs = obs, injector.apply(obs)
            active[:, t] = injector.active
            changed[:, t] = np.any([(obs[s] != clean[s]).any(1) for s in injector.channels], 0)
        stat = guard.statistics(obs)
        alive = t < data["length"]
        max_stat = np.maximum(max_stat, stat[alive].max(0, initial=0.0))
        guard.flags |= guard.accused(stat)
        flags[:, t] = guard.flags
    return {"max_stat": max_stat, "flags": flags, "active": active, "changed": changed}
