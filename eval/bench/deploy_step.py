"""``make bench-deploy``'s second part: MSTA with per-step attention (``--policy.attention=step``,
:mod:`msta.policies.msta.step_attention`) at the same preset, observations and windows as the
paper's full attention timed before it, one thread, batch 1.

Two ways to answer a control step: the whole window each call (the runtimes of the first
part: eager, TorchScript and ONNX Runtime files from ``msta-export``, parity-checked), and
:class:`~msta.policies.msta.step_stream.StepStream`, which encodes only the newest step
and reuses the cached keys and values of the older ones (its two parts in eager PyTorch, as
frozen TorchScript and on ONNX Runtime; each stream's actions are checked against the
whole window's before it is timed). The speed-up is the paper
attention's best runtime over the step design's best way, both measured in this run.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from pathlib import Path

import torch

from msta.policies.export import random_windows, resolve_sensors
from msta.policies.factory import make_policy
from msta.policies.msta import MSTAConfig
from msta.policies.msta.step_stream import RUNTIMES, StepStream

#: the int8 runtime (ONNX Runtime's dynamic quantization): timed beside the fp32 ones, never
#: the speed-up's fp32 best
INT8 = "onnxruntime-int8"

#: |stream - window| action difference the stream must stay within before it is timed
STREAM_TOLERANCE = 1e-4

Timer = Callable[[Callable[[], object], float], tuple[float, float, int]]
Runtimes = Callable[..., tuple[dict[str, Callable[[], object]], dict]]


def stream_call(policy, names: Sequence[str], T: int, runtime: str
                ) -> tuple[Callable[[], object], float]:
    """A callable answering one control step through a :class:`StepStream` on ``runtime``
    whose cache holds T steps (a robot in mid-episode), and the
    largest action difference to the whole-window forward (over the T steps of 4 random
    windows, each window's actions from its first step on)."""
    windows = random_windows(policy, names, T, 4, seed=1)
    stream = StepStream(policy, T, names, runtime=runtime)
    diff = 0.0
    for i in range(4):
        stream.reset()
        for t in range(T):
            action = stream.step({n: torch.from_numpy(windows[n][i:i + 1, t]) for n in names})
            with torch.inference_mode():
                full = policy({n: torch.from_numpy(windows[n][i:i + 1, :t + 1]) for n in names})
            diff = max(diff, float((action - full).abs().max()))
    last = {n: torch.from_numpy(windows[n][:1, -1]) for n in names}
    return (lambda: stream.step(last)), diff


def bench_step(cfg: MSTAConfig, observations: Mapping[str, tuple[Sequence[str], int]],
               stats: Mapping, out: Path, seconds: float, time_call: Timer,
               runtimes: Runtimes, paper_ms: Mapping[str, float]) -> dict:
    """Time the step design per observation (whole-window runtimes and the stream), print a
    row each and the speed-up lines; returns the figures for results.json."""
    step_cfg = replace(cfg, attention="step")
    policy = make_policy(step_cfg, stats).eval()
    print(f"\nper-step attention (--policy.attention=step, readout_layers = "
          f"{step_cfg.readout_layers}), same preset and windows:")
    results = {"readout_layers": step_cfg.readout_layers, "observations": {}}
    for obs, (names, T) in observations.items():
        names = resolve_sensors(policy, list(names))
        fns, parity = runtimes(policy, names, T, out / obs)
        fns = {rt: fn for rt, fn in fns.items() if rt == "eager" or "error" not in parity}
        diff = int8_diff = 0.0
        for runtime in RUNTIMES:
            stream, d = stream_call(policy, names, T, runtime)
            if runtime == INT8:  # int8 moves actions by design: timed, its difference reported
                int8_diff = d
                fns[f"stream {runtime}"] = stream
                continue
            diff = max(diff, d)
            if d <= STREAM_TOLERANCE:
                fns[f"stream {runtime}"] = stream
        rows = {}
        for rt, fn in fns.items():
            med, p90, n = time_call(fn, seconds)
            rows[rt] = {"median_ms": med, "p90_ms": p90, "calls": n}
            print(f"  {obs:<11} {rt:<22} {med:>8.2f} ms median {p90:>8.2f} ms p90 {n:>6} calls")
        fp32 = [rt for rt in rows if not rt.endswith(INT8)]
        best = min(fp32, key=lambda rt: rows[rt]["median_ms"])
        int8 = min((rt for rt in rows if rt.endswith(INT8)), key=lambda rt: rows[rt]["median_ms"])
        results["observations"][obs] = {
            "runtimes": rows, "best": best, "parity": parity, "stream_max_abs_diff": diff,
            "speedup": paper_ms[obs] / rows[best]["median_ms"],
            "int8": {"runtime": int8, "median_ms": rows[int8]["median_ms"],
                     "speedup": paper_ms[obs] / rows[int8]["median_ms"],
                     "max_abs_diff": max(int8_diff, parity.get("int8_max_abs_diff", 0.0))}}
        if diff > STREAM_TOLERANCE:
            print(f"  {obs}: a stream's action differs from the window's by {diff:.1e} "
                  f"(> {STREAM_TOLERANCE:g}): not timed")
    for obs in ("full", "minimized"):
        r = results["observations"][obs]
        print(f"{obs}: step attention best {r['best']} "
              f"{r['runtimes'][r['best']]['median_ms']:.2f} ms against the paper attention's "
              f"{paper_ms[obs]:.2f} ms (stream vs window {r['stream_max_abs_diff']:.1e})")
    return results
