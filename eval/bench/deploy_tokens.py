"""``make bench-deploy``'s third part: MSTA with sensor tokens (``--policy.tokens=sensor``,
:mod:`msta.policies.msta.sensor_tokens`: one token per sensor and step, removal still per
reading) at the same preset, observations and windows as the paper's scalar tokens timed
before it, one thread, batch 1, in the same runtimes (the ``msta-export`` files, each
parity-checked against the eager model before it is timed). The speed-up is the paper
attention's best fp32 runtime over this design's best fp32 runtime, both measured in this
run; the int8 graph is timed beside them and never counted as the fp32 best.
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

__all__ = ["bench_tokens"]


def bench_tokens(cfg: MSTAConfig, observations: Mapping[str, tuple[Sequence[str], int]],
                 stats: Mapping, out: Path, seconds: float, time_call: Timer,
                 runtimes: Runtimes, paper_ms: Mapping[str, float],
                 flops: Callable[[MSTAConfig, int], float]) -> dict:
    """Time the sensor-token design per observation, print a row per runtime and a line per
    observation; returns the figures for results.json."""
    tok_cfg = replace(cfg, tokens="sensor")
    policy = make_policy(tok_cfg, stats).eval()
    print("\nsensor tokens (--policy.tokens=sensor: one token per sensor and step, removal per "
          "reading), same preset and windows:")
    results = {"observations": {}}
    for obs, (names, T) in observations.items():
        names = resolve_sensors(policy, list(names))
        tokens = T * len(names) + tok_cfg.state_tokens
        encoders = sum(2 * T * (2 * registry.get(n).dim * 2 * cfg.dim + 2 * cfg.dim * cfg.dim)
                       for n in names)
        gflop = (flops(tok_cfg, tokens) + encoders) / 1e9
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
    for obs in ("full", "minimized"):
        r = results["observations"][obs]
        print(f"{obs}: sensor tokens best {r['best']} {r['runtimes'][r['best']]['median_ms']:.2f} "
              f"ms against the paper attention's {paper_ms[obs]:.2f} ms "
              f"(export parity {r['parity'].get('parity_max_abs_diff', float('nan')):.1e})")
    return results
