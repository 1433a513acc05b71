"""``make bench-deploy``'s last parts: cheaper MSTA designs at the same preset, observations
and windows as the paper's scalar tokens timed before them, one thread, batch 1, in the same
runtimes (the ``msta-export`` files, each parity-checked against the eager model before it
is timed):

- sensor tokens (``--policy.tokens=sensor``, :mod:`msta.policies.msta.sensor_tokens`: one
  token per sensor and step, removal still per reading);
- axial attention (``--policy.attention=axial``, :mod:`msta.policies.msta.axial_attention`:
  the paper's tokens, blocks alternating between a step's tokens and a channel's).

Each speed-up is the paper attention's best fp32 runtime over the design's best fp32 runtime,
both measured in this run; the int8 graph is timed beside them and never counted as the fp32
best.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from pathlib import Path

from msta.data import sensors as registry
from msta.eval.bench.deploy_step import INT8, Runtimes, Timer
from msta.policies.export import resolve_sensors
from msta.policies.factory import make_policy
from msta.policies.msta import MSTAConfig

__all__ = ["DESIGNS", "bench_design"]

#: results key -> (the config's overrides, the line's description)
DESIGNS = {
    "tokens": ({"tokens": "sensor"}, "sensor tokens (--policy.tokens=sensor: one token per "
               "sensor and step, removal per reading)"),
    "axial": ({"attention": "axial"}, "axial attention (--policy.attention=axial: blocks "
              "alternate between a step's tokens and a channel's)"),
}


def design_flops(cfg: MSTAConfig, names: Sequence[str], T: int,
                 flops: Callable[[MSTAConfig, int], float]) -> tuple[int, float]:
    """(tokens, FLOPs) of one forward pass of ``cfg``'s design over ``names`` at window T:
    ``flops`` (the paper attention's count) with sensor tokens' encoders added, or with
    axial attention's grouped scores in place of the full ones."""
    d, R = cfg.dim, cfg.state_tokens
    if cfg.tokens == "sensor":
        tokens = T * len(names) + R
        encoders = sum(2 * T * (2 * registry.get(n).dim * 2 * d + 2 * d * d) for n in names)
        return tokens, flops(cfg, tokens) + encoders
    n = sum(registry.get(k).dim for k in names)
    tokens = T * n + R
    total = flops(cfg, tokens)
    if cfg.attention == "axial":  # token blocks: groups instead of the whole window
        full = 4 * tokens * tokens * d
        blocks = range(cfg.num_layers - 1)
        grouped = sum(4 * d * ((T * n * n) if i % 2 == 0 else (n * T * T)) + 4 * R * tokens * d
                      for i in blocks)
        total += grouped - len(blocks) * full
    return tokens, total


def bench_design(key: str, cfg: MSTAConfig, observations: Mapping[str, tuple[Sequence[str], int]],
                 stats: Mapping, out: Path, seconds: float, time_call: Timer,
                 runtimes: Runtimes, paper_ms: Mapping[str, float],
                 flops: Callable[[MSTAConfig, int], float]) -> dict:
    """Time design ``key`` of :data:`DESIGNS` per observation, print a row per runtime and a
    line per observation; returns the figures for results.json."""
    overrides, description = DESIGNS[key]
    design_cfg = replace(cfg, **overrides)
    policy = make_policy(design_cfg, stats).eval()
    print(f"\n{description}, same preset and windows:")
    results = {"observations": {}}
    for obs, (names, T) in observations.items():
        names = resolve_sensors(policy, list(names))
        tokens, count = design_flops(design_cfg, names, T, flops)
        gflop = count / 1e9
        fns, parity = runtimes(policy, names, T, out / obs)
        rows = {}
        for rt, fn in fns.items():
            med, p90, n = time_call(fn, seconds)
            rows[rt] = {"median_ms": med, "p90_ms": p90, "calls": n}
            print(f"  {obs:<11} {tokens:>4} tokens {gflop:>6.3f} GFLOP {rt:<16} {med:>8.2f} ms "
                  f"median {p90:>8.2f} ms p90 {n:>6} calls")
        ok = [rt for rt in rows if rt == "eager" or ("error" not in parity and rt != INT8)]
        best = min(ok, key=lambda rt: rows[rt]["median_ms"])
        results["observations"][obs] = {
            "tokens": tokens, "gflop": gflop, "runtimes": rows, "best": best, "parity": parity,
            "speedup": paper_ms[obs] / rows[best]["median_ms"],
            "int8": ({"median_ms": rows[INT8]["median_ms"],
                      "speedup": paper_ms[obs] / rows[INT8]["median_ms"],
                      "max_abs_diff": parity["int8_max_abs_diff"]} if INT8 in rows else None)}
    name = description.split(" (")[0]
    for obs in ("full", "minimized"):
        r = results["observations"][obs]
        print(f"{obs}: {name} best {r['best']} {r['runtimes'][r['best']]['median_ms']:.2f} "
              f"ms against the paper attention's {paper_ms[obs]:.2f} ms "
              f"(export parity {r['parity'].get('parity_max_abs_diff', float('nan')):.1e})")
    return results
