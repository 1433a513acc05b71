"""Deployment latency benchmark: ``make bench-deploy`` / ``python -m msta.eval.bench.deploy``.

How fast does the MSTA student answer one robot's control step on one CPU core? The
``paper`` preset (d = 128, 4 layers x 4 heads; random weights: latency does not depend on
them) at batch 1, one thread, for the full observation (7 sensors, T = 15: 735 tokens +
<S> = 736) and the paper's minimized observation (command, joint_pos, gravity, last_action
at T = 7: 210 + 1 = 211 tokens), in three runtimes:

- ``eager``: the PyTorch module under ``torch.inference_mode``;
- ``torchscript``: the ``msta-export`` TorchScript file (frozen for inference);
- ``onnxruntime``: the ``msta-export`` ONNX file on onnxruntime's CPU provider.

Each exported file passes ``msta-export``'s parity check (max |d action| <= 1e-5 against
the eager model) before it is timed; a runtime that fails it is reported and not counted.
Next to each latency: the model's FLOPs per step (counted from the shapes), the rate that
achieves, and the machine's fp32 matmul rate measured in the same run on one thread (the
roofline: latency cannot go below FLOPs / that rate without fewer FLOPs or lower precision).
Then three cheaper designs at the same preset and windows, in the same run: per-step
attention (:mod:`msta.eval.bench.deploy_step`), sensor tokens and axial attention
(:mod:`msta.eval.bench.deploy_designs`).
``full speed-up vs paper attention: <x>`` and ``minimized speed-up vs paper attention: <x>``
report the one that walks best in closed loop (``WINNER``). The last two lines are
``minimized latency (ms): <x>`` and ``full latency (ms): <x>``, the paper attention's best
parity-holding runtime's median. Goals: full <= 10 ms, minimized <= 1.5 ms.

The sensor guard (docs/faults.md, "Deployment") at the full observation, batch 1,
one core: ``guard``, :meth:`msta.policies.guard.SensorGuard.update` alone (numpy; synthetic
arrays of the fitted shapes: its cost does not depend on their values), and ``guard +
student``, one :meth:`msta.policies.onnx_runtime.OnnxStudent.step` of an export with the guard
and its removal inputs (the robot loop: readings checked, window shifted, guard, ONNX
Runtime), each as a ratio to the plain ONNX Runtime student timed above in the same run.
Bar: guard + student <= 20 ms a step.
"""

from __future__ import annotations

import itertools
import json
import statistics
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from msta.data import sensors as registry
from msta.data.cli import parse_config
from msta.eval.bench.deploy_designs import DESIGNS, bench_design
from msta.eval.bench.deploy_step import INT8, bench_step
from msta.policies import guard as guard_mod
from msta.policies.export import DeployedStudent, export_student, random_windows, resolve_sensors
from msta.policies.export_files import ExportParityError
from msta.policies.factory import make_policy
from msta.policies.guard import INPUT_SENSORS, GuardConfig, SensorGuard
from msta.policies.guard_file import save_guard
from msta.policies.input_spec import MINIMIZED_HISTORY, MINIMIZED_SENSORS
from msta.policies.msta import MSTAConfig
from msta.policies.onnx_runtime import OnnxStudent
from msta.policies.quantize import write_int8

GOALS_MS = {"full": 10.0, "minimized": 1.5}
#: the design the closing speed-up lines report: the one that walks best in closed loop
#: (docs/msta_model.md's table), a key of results.json
WINNER = "tokens"
#: the bar for guard + student at the full observation, one core, batch 1
GUARD_BAR_MS = 20.0


def synthetic_guard(seed: int = 0) -> SensorGuard:
    """A guard (default GuardConfig) with random arrays of the fitted shapes and thresholds
    nothing exceeds."""
    rng = np.random.default_rng(seed)
    cfg = GuardConfig()
    stats = {}
    for k, shape in guard_mod.array_shapes(cfg).items():
        stats[k] = (0.05 * rng.standard_normal(shape) if k.startswith(("weight", "contact_w"))
                    else np.zeros(shape) if k.startswith(("bias", "feat_mean", "contact_b",
                                                          "contact_mean"))
                    else np.full(shape, 1e300) if k == "threshold" else np.ones(shape))
    return SensorGuard(cfg, stats)


def bench_guard(policy, T: int, out: Path, seconds: float, student_ms: float) -> dict:
    """Guard alone and guard + student (OnnxStudent.step) per step at the full observation;
    printed with their ratios to ``student_ms`` (the plain ONNX Runtime student)."""
    guard = synthetic_guard()
    save_guard(guard, out / "guard")
    names = resolve_sensors(policy, "all")
    absent = [n for n in names if n in guard.sensors]
    spec = export_student(policy, out / "export", names, T, absent=absent,
                          guard_dir=out / "guard",
                          windows={"random": random_windows(policy, names, T, 16)})
    stream = random_windows(policy, INPUT_SENSORS, 64, 1, seed=1)  # (1, 64, dim) each
    obs = [{s: stream[s][:, t] for s in INPUT_SENSORS} for t in range(64)]
    robot = OnnxStudent(out / "export", num_threads=1)
    robot.reset()
    i = itertools.count()
    g_med, g_p90, g_n = time_call(lambda: guard.update(obs[next(i) % 64]), seconds)
    both = time_call(lambda: robot.step({s: v[0] for s, v in obs[next(i) % 64].items()}),
                     seconds)
    rows = {"guard": {"median_ms": g_med, "p90_ms": g_p90, "calls": g_n},
            "guard + student": dict(zip(("median_ms", "p90_ms", "calls"), both, strict=True))}
    for name, r in rows.items():
        r["ratio_to_student"] = r["median_ms"] / student_ms
        print(f"{'full':<11} {'':>6} {'':>6} {name:<16} {r['median_ms']:>7.3f} ms "
              f"(p90 {r['p90_ms']:.3f}, {r['calls']} calls) = {r['ratio_to_student']:.3f} x "
              f"the student alone ({student_ms:.2f} ms)")
    ms = rows["guard + student"]["median_ms"]
    return {"runtimes": rows, "student_ms": student_ms, "bar_ms": GUARD_BAR_MS,
            "met": ms <= GUARD_BAR_MS, "parity_max_abs_diff": spec["parity_max_abs_diff"],
            "absent_inputs": absent}


def synthetic_stats(names) -> dict:
    """Unit statistics for every non-binary input and the action (latency ignores them)."""
    stats = {registry.get(n).column: {"mean": [0.0] * registry.get(n).dim,
                                      "std": [1.0] * registry.get(n).dim}
             for n in names if not registry.get(n).binary}
    stats["action"] = {"mean": [0.0] * 12, "std": [1.0] * 12}
    return stats


def model_flops(cfg: MSTAConfig, tokens: int) -> float:
    """FLOPs (2 x multiply-adds) of one forward pass over ``tokens`` tokens (readout tokens
    included); the last block computes only the R readout tokens' outputs (keys and values
    of all tokens)."""
    d, L, R, hidden = cfg.dim, tokens, cfg.state_tokens, round(cfg.mlp_ratio * cfg.dim)

    def layer(queries: int) -> int:
        kv = 2 * L * d * 2 * d  # keys and values of every token
        q_out_mlp = 2 * queries * d * (2 * d + 2 * hidden)  # query, output projection, MLP
        return kv + q_out_mlp + 2 * 2 * queries * L * d  # + scores and weighted sum

    h = cfg.head_hidden_dim
    head = 2 * R * d * h + 2 * h * 12 if h else 2 * R * d * 12
    return float((cfg.num_layers - 1) * layer(L) + layer(R) + head)


def matmul_gflops(seconds: float = 1.0) -> float:
    """fp32 ``torch.mm`` rate on the current thread count (a 512 x 512 x 512 product)."""
    a, b = torch.randn(512, 512), torch.randn(512, 512)
    for _ in range(3):
        a @ b
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        a @ b
        n += 1
    return 2 * 512 ** 3 * n / (time.perf_counter() - t0) / 1e9


def time_call(fn: Callable[[], object], seconds: float) -> tuple[float, float, int]:
    """Median and 90th-percentile milliseconds of ``fn()`` over ``seconds`` (after warm-up)."""
    for _ in range(10):
        fn()
    times, t_end = [], time.perf_counter() + seconds
    while time.perf_counter() < t_end or len(times) < 20:
        t0 = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t0) * 1e3)
    times.sort()
    return statistics.median(times), times[int(0.9 * (len(times) - 1))], len(times)


def runtimes(policy, names, T, out: Path) -> tuple[dict[str, Callable[[], object]], dict]:
    """Callables answering one batch-1 window per runtime, and the export's parity figures."""
    names = resolve_sensors(policy, list(names))  # the order the exported graph takes
    windows = random_windows(policy, names, T, 32, seed=0)
    one = [np.ascontiguousarray(windows[n][:1]) for n in names]
    module = DeployedStudent(policy, names).eval()
    eager_in = tuple(torch.from_numpy(x) for x in one)

    def eager() -> object:
        with torch.inference_mode():
            return module(*eager_in)

    fns: dict[str, Callable[[], object]] = {"eager": eager}
    try:
        spec = export_student(policy, out, list(names), T, windows={"random": windows})
    except ExportParityError as e:  # report it and time the eager model only
        return fns, {"error": str(e)}
    ts = torch.jit.optimize_for_inference(
        torch.jit.freeze(torch.jit.load(str(out / "student.pt")).eval()))

    def torchscript() -> object:
        with torch.inference_mode():
            return ts(*eager_in)

    import onnxruntime as ort  # lazy: onnxruntime loads only where an ONNX graph runs

    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    options.inter_op_num_threads = 1
    session = ort.InferenceSession(str(out / "student.onnx"), options,
                                   providers=["CPUExecutionProvider"])
    int8 = ort.InferenceSession(str(write_int8(out / "student.onnx", out / "student_int8.onnx")),
                                options, providers=["CPUExecutionProvider"])
    feed = dict(zip(names, one, strict=True))
    fns |= {"torchscript": torchscript,
            "onnxruntime": lambda: session.run(["action"], feed),
            INT8: lambda: int8.run(["action"], feed)}
    with torch.inference_mode():  # the frozen, optimized file too must answer as eager does
        d_ts = float((ts(*eager_in) - eager()).abs().max())
        all_in = [torch.from_numpy(windows[n]) for n in names]
        d_int8 = float(np.abs(int8.run(["action"], {n: windows[n] for n in names})[0]
                              - module(*all_in).numpy()).max())
    return fns, {"parity_max_abs_diff": max(spec["parity_max_abs_diff"], d_ts),
                 "int8_max_abs_diff": d_int8}


@dataclass
class BenchDeployConfig:
    """Args:
        seconds: timing window per runtime and observation (s), after 10 warm-up calls.
        preset: MSTA preset to time (``paper``: the issue's figures; ``cpu``, ``tiny``).
        history: the full observation's window T (0: the preset's; the demo's student is
            the ``cpu`` preset at 4).
        output_dir: results.json goes here (the exported files go to a temporary folder).
    """

    seconds: float = 3.0
    preset: str = "paper"
    history: int = 0
    output_dir: str = "outputs/bench_deploy"

    def __post_init__(self) -> None:
        if not self.seconds > 0:
            raise ValueError(f"seconds must be > 0, got {self.seconds}")
        if self.preset not in MSTAConfig.PRESETS:
            raise ValueError(f"preset must be one of {sorted(MSTAConfig.PRESETS)}, "
                             f"got {self.preset!r}")
        if self.history < 0:
            raise ValueError(f"history must be >= 0, got {self.history}")


def summary(results: dict, best: dict[str, str], rate: float) -> None:
    """Each observation's best fp32 runtime against its goal and floor, and the guard's line."""
    print()
    for obs in ("minimized", "full"):
        r = results["observations"][obs]
        ms, goal = r["runtimes"][best[obs]]["median_ms"], GOALS_MS[obs]
        floor = r["flops"] / (rate * 1e9) * 1e3
        print(f"{obs}: best {best[obs]} {ms:.2f} ms (goal <= {goal:g} ms: "
              f"{'met' if ms <= goal else 'not met'}); parity {r['parity']}; the matmul-rate "
              f"floor for its {r['flops'] / 1e9:.3f} GFLOP is {floor:.2f} ms")
    g = results["guard"]
    print(f"guard + student (full, 1 core, batch 1): "
          f"{g['runtimes']['guard + student']['median_ms']:.2f} ms a step (bar <= "
          f"{GUARD_BAR_MS:g} ms: {'met' if g['met'] else 'not met'}); the guard alone "
          f"{g['runtimes']['guard']['median_ms'] * 1e3:.0f} us; export parity with random "
          f"removal masks {g['parity_max_abs_diff']:.1e}")


def speed_lines(results: dict, best: dict[str, str]) -> None:
    """The int8 lines, each design's speed-ups, then the last four lines the issue asks for
    (the winning design's speed-ups, the paper attention's latencies)."""
    for obs in ("full", "minimized"):
        step, tok = (results[k]["observations"][obs] for k in ("step", "tokens"))
        print(f"{obs}: int8 (ONNX Runtime dynamic quantization) paper attention "
              f"{results['observations'][obs]['runtimes'][INT8]['median_ms']:.2f} ms, step "
              f"attention {step['int8']['median_ms']:.2f} ms ({step['int8']['runtime']}), sensor "
              f"tokens {tok['int8']['median_ms']:.2f} ms; speed-ups vs the fp32 paper attention "
              f"{step['int8']['speedup']:.2f} / {tok['int8']['speedup']:.2f}; |int8 - fp32| action "
              f"{max(step['int8']['max_abs_diff'], tok['int8']['max_abs_diff']):.1e} (accepted on "
              "closed loop only: python -m msta.eval.bench.deploy_loop)")
    for design, key in (("step attention", "step"), ("sensor tokens", "tokens"),
                        ("axial attention", "axial")):
        r = results[key]["observations"]
        print(f"{design} speed-up vs paper attention: full {r['full']['speedup']:.2f}, "
              f"minimized {r['minimized']['speedup']:.2f}")
    for obs in ("full", "minimized"):  # the winner in closed loop: sensor tokens
        print(f"{obs} speed-up vs paper attention: "
              f"{results[WINNER]['observations'][obs]['speedup']:.2f}")
    print(f"minimized latency (ms): {results['observations']['minimized']['runtimes'][best['minimized']]['median_ms']:.2f}")
    print(f"full latency (ms): {results['observations']['full']['runtimes'][best['full']]['median_ms']:.2f}")


def main(argv: list[str] | None = None) -> None:
    a = parse_config(BenchDeployConfig, argv, prog="python -m msta.eval.bench.deploy")
    torch.set_num_threads(1)
    torch.manual_seed(0)
    cfg = MSTAConfig.from_preset(a.preset, tokens="scalar",  # the paper's tokens first
                                 **({"history": a.history} if a.history else {}))
    policy = make_policy(cfg, synthetic_stats(cfg.input_sensors)).eval()
    rate = matmul_gflops()
    print(f"MSTA {a.preset} preset (d = {cfg.dim}, {cfg.num_layers} layers x {cfg.num_heads} "
          f"heads, T = {cfg.history}), batch 1, 1 thread; fp32 matmul rate on this core: {rate:.1f} GFLOP/s")
    observations = {"full": (tuple(cfg.input_sensors), cfg.history),
                    "minimized": (MINIMIZED_SENSORS, MINIMIZED_HISTORY)}
    header = (f"{'observation':<11} {'tokens':>6} {'GFLOP':>6} {'runtime':<16} {'median ms':>9} "
              f"{'p90 ms':>7} {'calls':>6} {'GFLOP/s':>8} {'of matmul':>9}")
    print(header + "\n" + "-" * len(header))
    results, best = {"matmul_gflops": rate, "observations": {}}, {}
    with tempfile.TemporaryDirectory() as tmp:
        for obs, (names, T) in observations.items():
            tokens = T * sum(registry.get(n).dim for n in names) + cfg.state_tokens
            flops = model_flops(cfg, tokens)
            fns, parity = runtimes(policy, names, T, Path(tmp) / obs)
            rows = {}
            for rt, fn in fns.items():
                med, p90, n = time_call(fn, a.seconds)
                achieved = flops / (med / 1e3) / 1e9
                rows[rt] = {"median_ms": med, "p90_ms": p90, "calls": n, "gflops": achieved}
                print(f"{obs:<11} {tokens:>6} {flops / 1e9:>6.3f} {rt:<16} {med:>9.2f} "
                      f"{p90:>7.2f} {n:>6} {achieved:>8.1f} {achieved / rate:>8.0%}")
            ok = {rt: r for rt, r in rows.items()
                  if rt == "eager" or ("error" not in parity and rt != INT8)}
            best[obs] = min(ok, key=lambda rt: ok[rt]["median_ms"])
            results["observations"][obs] = {"tokens": tokens, "flops": flops, "parity": parity,
                                            "runtimes": rows, "best": best[obs]}
        results["guard"] = bench_guard(policy, cfg.history, Path(tmp) / "guard", a.seconds,
                                       results["observations"]["full"]["runtimes"]
                                       ["onnxruntime"]["median_ms"])
        paper_ms = {obs: results["observations"][obs]["runtimes"][best[obs]]["median_ms"]
                    for obs in observations}
        stats = synthetic_stats(cfg.input_sensors)
        results["step"] = bench_step(cfg, observations, stats, Path(tmp) / "step", a.seconds,
                                     time_call, runtimes, paper_ms)
        for key in DESIGNS:
            results[key] = bench_design(key, cfg, observations, stats, Path(tmp) / key,
                                        a.seconds, time_call, runtimes, paper_ms, model_flops)
        results["winner"] = WINNER
    out = Path(a.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps(results, indent=1) + "\n")
    summary(results, best, rate)
    print(f"wrote {out / 'results.json'}")
    speed_lines(results, best)


if __name__ == "__main__":
    main()
