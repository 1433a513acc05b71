"""Does a deployment graph walk as its checkpoint does? ``python -m msta.eval.bench.deploy_loop
--policy_path=DIR``.

One MSTA checkpoint evaluated three ways on the same msta-eval trials (the quick suite's
test masks 0 / 25 / 50 % over the five terrains, the teacher as reference): the PyTorch
policy, its network as one ONNX Runtime graph in fp32, and the same graph with int8
weights (:class:`msta.policies.msta.onnx_policy.OnnxMSTA`; each graph removes the tokens
the policy removes, from the same random draw). It prints linear-velocity tracking and
survival (teacher-normalized, 95 % intervals) per way and mask, then each graph's
difference to the PyTorch policy, and the line ``int8 vs fp32 closed loop: max |d tracking|
<x> (tolerance <t>): accepted|refused; max |d survival| <y>``: int8 is accepted when its
tracking stays within the tolerance of the fp32 graph's at every test mask. Survival is
reported beside it, not gated: a trial either falls or not, and float rounding alone (the
fp32 graph against PyTorch) flips a trial now and then in closed loop. msta-eval's
metrics.json and report.md are in ``output_dir``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from msta.data.cli import parse_config
from msta.eval.eval_config import EvalConfig
from msta.policies.teacher.config import TeacherConfig

#: the ways a checkpoint is run, in the order of the rows
WAYS = ("pytorch", "onnxruntime", "onnxruntime-int8")


@dataclass
class DeployLoopConfig:
    """Args:
        policy_path: an MSTA checkpoint directory (msta-train / msta-correct output).
        output_dir: msta-eval's output directory.
        trials: trials per test mask (spread over 5 terrains x the levels).
        levels: terrain levels, comma-separated.
        episode_length_s: trial length (s).
        num_threads: torch and ONNX Runtime threads.
        tolerance: the largest |int8 - fp32| difference of tracking at any test mask for
            int8 to be accepted.
        teacher: the reference teacher (the demo's by default).
    """

    policy_path: str = ""
    output_dir: str = "outputs/deploy_loop"
    trials: int = 100
    levels: str = "0,1,2"
    episode_length_s: float = 5.0
    num_threads: int = 2
    tolerance: float = 0.02
    teacher: TeacherConfig = field(default_factory=TeacherConfig)

    def __post_init__(self) -> None:
        if not self.policy_path:
            raise ValueError("policy_path: name an MSTA checkpoint directory")
        if not Path(self.policy_path).is_dir():
            raise ValueError(f"policy_path={self.policy_path!r} is not a directory")


def figures(metrics: dict) -> dict[str, dict[float, dict]]:
    """way -> test mask -> {lin, lin_ci, survival, trials} from msta-eval's metrics."""
    out: dict[str, dict[float, dict]] = {}
    for run in metrics["runs"]:
        if run["policy"] == "teacher" or run.get("status") != "ok":
            continue
        n, r = run["normalized"]["per_terrain"]["average"], run["raw"]["per_terrain"]["average"]
        out.setdefault(run["policy"], {})[float(run["spec"]["mask_ratio"])] = {
            "lin": n["lin_tracking"], "lin_ci": n["ci"]["lin_tracking"],
            "survival": r["survival"], "trials": r["trials"]}
    return out


def report(got: dict[str, dict[float, dict]], tolerance: float) -> list[str]:
    """The table's lines, the differences and the verdict line."""
    lines = [f"{'way':<18} {'mask':>5} {'tracking vs teacher':>22} {'survival':>9} {'trials':>7}"]
    for way in WAYS:
        for mask, f in sorted(got.get(way, {}).items()):
            lo, hi = f["lin_ci"] or (float("nan"), float("nan"))
            lines.append(f"{way:<18} {mask:>5.2f} {f['lin']:>8.3f} [{lo:.3f}, {hi:.3f}] "
                         f"{f['survival']:>9.3f} {f['trials']:>7}")

    def worst(a: str, b: str) -> tuple[float, float]:
        masks = sorted(set(got.get(a, {})) & set(got.get(b, {})))
        if not masks:
            return float("nan"), float("nan")
        return (max(abs(got[a][m]["lin"] - got[b][m]["lin"]) for m in masks),
                max(abs(got[a][m]["survival"] - got[b][m]["survival"]) for m in masks))

    for way in WAYS[1:]:
        d_lin, d_surv = worst(way, "pytorch")
        lines.append(f"{way} vs pytorch: max |d tracking| {d_lin:.3f}, max |d survival| {d_surv:.3f}")
    d_lin, d_surv = worst("onnxruntime-int8", "onnxruntime")
    lines.append(f"int8 vs fp32 closed loop: max |d tracking| {d_lin:.3f} (tolerance "
                 f"{tolerance:g}): {'accepted' if d_lin <= tolerance else 'refused'}; "
                 f"max |d survival| {d_surv:.3f}")
    return lines


def main(argv: list[str] | None = None) -> None:
    """Evaluate one checkpoint as PyTorch, ONNX Runtime fp32 and int8 (``--help``)."""
    cfg = parse_config(DeployLoopConfig, argv, prog="python -m msta.eval.bench.deploy_loop")
    from msta.eval.evaluation import evaluate, load_entries  # lazy: torch after parsing
    from msta.eval.evaluator import PolicyEntry  # lazy: torch after parsing
    from msta.policies.msta.onnx_policy import OnnxMSTA  # lazy: torch after parsing

    ecfg = EvalConfig(policies=f"teacher,{cfg.policy_path}", suite="quick",
                      scenarios="token_removal", output_dir=cfg.output_dir, trials=cfg.trials,
                      levels=cfg.levels, episode_length_s=cfg.episode_length_s,
                      num_threads=cfg.num_threads, progress=True, teacher=cfg.teacher,
                      device="cpu")
    teacher, student = load_entries(ecfg)
    student.name = WAYS[0]
    entries = [teacher, student]
    for way in WAYS[1:]:
        graph = OnnxMSTA(student.obj, int8=way.endswith("int8"), num_threads=cfg.num_threads)
        entries.append(PolicyEntry(way, student.source, "student", student.path,
                                   f"{student.revision}-{way}", graph, student.train_masks))
    for line in report(figures(evaluate(ecfg, entries)), cfg.tolerance):
        print(line)


if __name__ == "__main__":
    main()
