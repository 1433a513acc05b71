"""Offline measurement of the sensor guard: faults from ``msta.collect.faults.FaultInjector``
injected into recorded held-out episodes, the guard streamed over them step by step
(``msta-guard evaluate``; docs/faults.md, "The guard").

Detection of a fault in one episode: the first step at or after the onset at which any of
the fault's channels is flagged; "within 10" means flagged at one of the first 10 faulty
steps (delay <= 9). A flag on the fault's channels before the onset counts as an early
(false) flag and not as a detection. Collateral: another channel (not the fault's and not
its encoder partner) flagged by onset + 10. False alarms: flagged channel-steps per 10,000
physical channel-steps on the fault-free held-out episodes (flags latch, so one false
trigger counts every step to the episode's end). "Within 10 of showing": flagged by the
10th step from the first one at which the fault changed a reading (a stuck contact shows
only when the foot changes state; spikes at rate 0.1 miss a channel's first 10 faulty
steps 35 % of the time), over the faults that showed 10 steps before their episode ended.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from msta.collect.faults import BINARY_FAULTS, FaultInjector, FaultSpec, std_from_stats
from msta.data.sensors import PHYSICAL_SENSORS, get
from msta.data.stats import load_stats
from msta.policies.guard import NJ, OFFSET, P, SensorGuard, encoder_partner
from msta.train.guard_data import load_episodes, stream

WITHIN = 10
#: (type, severity) with a detection minimum (docs/faults.md), then the subtle ones (reported).
MAIN_FAULTS = (("stuck", 0.0), ("bias", 3.0), ("noise", 3.0), ("spikes", 5.0))
SUBTLE_FAULTS = (("bias", 1.0), ("drift", 0.5), ("dropout", 0.2))


def targets() -> dict[str, list[str]]:
    """Target kind -> the targets measured (every joint, every channel, every sensor)."""
    one = [f"{s}:{i}" for s in PHYSICAL_SENSORS for i in range(get(s).dim)]
    return {"encoder": [f"encoder:{j}" for j in range(NJ)], "channel": one,
            "sensor": list(PHYSICAL_SENSORS)}


def _channels(spec: FaultSpec) -> np.ndarray:
    return np.array([OFFSET[s] + int(i) for s, idx in spec.channels.items() for i in idx])


def run_fault(guard_factory, data: dict, spec: FaultSpec, std: dict, seed: int) -> dict:
    """One fault spec over every episode of ``data``: per episode onset, delay (-1: never
    flagged after onset), early flag and collateral flag."""
    n = len(data["length"])
    guard = guard_factory(n)
    inj = FaultInjector(spec, n, std, dt=guard.dt, seed=seed)
    out = stream(guard, data, inj)
    flags, onset = out["flags"], inj.onset.copy()
    chans = _channels(spec)
    hit = flags[:, :, chans].any(2)  # (E, T)
    tmax = flags.shape[1]
    steps = np.arange(tmax)[None]
    after = hit & (steps >= onset[:, None]) & (steps < data["length"][:, None])
    delay = np.where(after.any(1), after.argmax(1) - onset, -1)
    early = (hit & (steps < onset[:, None])).any(1)
    other = np.ones(P, bool)
    other[chans] = False
    other[encoder_partner(chans)] = False
    by = np.minimum(onset + WITHIN - 1, tmax - 1)
    collateral = flags[np.arange(n), by][:, other].any(1)
    valid = onset + WITHIN <= data["length"]
    shown = out["changed"] & (steps >= onset[:, None])
    first = np.where(shown.any(1), shown.argmax(1), tmax)
    by_shown = np.where(delay >= 0, onset + delay - first, tmax) < WITHIN
    valid_shown = first + WITHIN <= data["length"]
    return {"delay": delay[valid], "early": early[valid], "collateral": collateral[valid],
            "shown_ok": (by_shown & ~early)[valid_shown]}


def summarize(runs: list[dict]) -> dict:
    delay = np.concatenate([r["delay"] for r in runs])
    early = np.concatenate([r["early"] for r in runs])
    coll = np.concatenate([r["collateral"] for r in runs])
    ok = (delay >= 0) & (delay < WITHIN) & ~early
    found = delay[delay >= 0]

    def share(x: np.ndarray) -> float | None:
        return float(x.mean()) if len(x) else None

    shown = np.concatenate([r["shown_ok"] for r in runs])
    return {"faults": len(delay), "within_10": share(ok), "detected": share(delay >= 0),
            "within_10_shown": share(shown), "shown": len(shown),
            "median_delay": float(np.median(found)) if len(found) else None,
            "early": share(early), "collateral": share(coll)}


def false_alarms(guard_factory, data: dict) -> dict:
    """Flagged channel-steps per 10,000 on fault-free episodes: overall and per terrain."""
    n = len(data["length"])
    flags = stream(guard_factory(n), data)["flags"]
    valid = np.arange(flags.shape[1])[None] < data["length"][:, None]
    per_ep = (flags & valid[:, :, None]).sum((1, 2))
    steps = data["length"] * P
    out = {"all": _rate(per_ep, steps), "episodes_with_a_flag": int((per_ep > 0).sum()),
           "episodes": int(n)}
    for t in sorted(set(data["terrain"])):
        m = data["terrain"] == t
        out[f"terrain:{t}"] = _rate(per_ep[m], steps[m])
    return out


def _rate(flagged: np.ndarray, steps: np.ndarray) -> dict:
    return {"per_10k": float(1e4 * flagged.sum() / max(1, steps.sum())),
            "channel_steps": int(steps.sum())}


def evaluate_guard(guard: SensorGuard, root: str | Path, episodes: list[int], seed: int = 0,
                   min_length: int = 300, faults=MAIN_FAULTS + SUBTLE_FAULTS) -> dict:
    """Detection per (fault, target kind) and false alarms of ``guard`` on ``episodes``.

    Args:
        guard: a fitted guard (its arrays and config are copied per run).
        root: the dataset.
        episodes: held-out episode indices (not used to fit the guard).
        seed: seeds every injector (spec i gets seed + i).
        min_length: faults go into episodes at least this long (onset in 1-3 s).
        faults: (type, severity) pairs measured on every target kind.
    """
    def factory(n: int) -> SensorGuard:
        return SensorGuard(guard.cfg, guard.stats, guard.sensors, n, guard.dt)

    data = load_episodes(root, episodes)
    std = std_from_stats(load_stats(root), PHYSICAL_SENSORS)
    long = data["length"] >= min_length
    if not long.any():
        raise ValueError(f"no held-out episode is {min_length} steps long")
    faulty = {k: (v[long] if isinstance(v, np.ndarray) else v) for k, v in data.items()}
    report = {"false_alarms": false_alarms(factory, data), "detection": {}}
    i = 0
    for kind, severity in faults:
        for tkind, names in targets().items():
            runs = []
            for target in names:
                sensor = target.split(":")[0]
                if sensor != "encoder" and get(sensor).binary and kind not in BINARY_FAULTS:
                    continue
                spec = FaultSpec(kind, severity, target)
                runs.append(run_fault(factory, faulty, spec, std, seed + i))
                i += 1
            report["detection"][f"{kind}:{severity:g}:{tkind}"] = summarize(runs)
    return report




def format_table(report: dict) -> str:
    """Markdown tables: detection per condition, false alarms per terrain."""
    lines = ["| fault | target | faults | within 10 steps | within 10 of showing | detected | "
             "median delay | early | collateral |", "|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    for key, r in report["detection"].items():
        kind, sev, tkind = key.split(":")
        cells = [_cell(r[k], ".3f") for k in ("within_10", "within_10_shown", "detected")]
        cells += [_cell(r["median_delay"], "g")]
        cells += [_cell(r[k], ".3f") for k in ("early", "collateral")]
        lines.append(f"| {kind} {sev} | {tkind} | {r['faults']} | " + " | ".join(cells) + " |")
    fa = report["false_alarms"]
    lines += ["", "| fault-free | flagged channel-steps per 10,000 | channel-steps |",
              "|---|---:|---:|"]
    for key, r in fa.items():
        if isinstance(r, dict):
            lines.append(f"| {key} | {r['per_10k']:.2f} | {r['channel_steps']} |")
    lines.append(f"\n{fa['episodes_with_a_flag']} of {fa['episodes']} fault-free episodes "
                 "had a flag.")
    return "\n".join(lines)


def _cell(value: float | None, fmt: str) -> str:
    return "-" if value is None else format(value, fmt)
