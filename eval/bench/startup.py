"""How fast the commands answer: ``make bench-startup`` / ``python -m msta.eval.bench.startup``.

Each ``msta-*`` console script runs ``--help`` in a fresh process (the time a user waits for
the option list), against the reference measured in the same run: a fresh Python that only
imports torch, what every training command paid before its arguments were parsed. Then
msta-train on a small synthetic dataset is timed to its first line of output (the command
has parsed, checked and opened its dataset). Each figure is the best of ``--rounds`` (round
robin, so a busy moment hits every command alike).

The last lines are ``slowest --help: <s> s (<command>)``, ``slowest --help vs import torch:
<ratio>`` and ``msta-train first line: <s> s``.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import time
import tomllib
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path

from msta.data.checks import check_at_least
from msta.data.cli import parse_config
from msta.eval.bench.outputs import own_output
from msta.eval.bench.scale_train import make_dataset

PROG = "python -m msta.eval.bench.startup"
#: The reference: what a command paid before parsing when it imported torch first.
REFERENCE = (sys.executable, "-c", "import torch")


@dataclass
class StartupConfig:
    """Args:
        rounds: fresh processes per command (its best is kept).
        output_dir: where the synthetic dataset for the first-line run goes.
    """

    rounds: int = 3
    output_dir: str = "outputs/bench/startup"

    def __post_init__(self) -> None:
        check_at_least(self, 1, "rounds")


def commands() -> dict[str, list[str]]:
    """Every ``msta-*`` console script as a command line running its entry point in this
    Python (``name -> argv``): the tree's pyproject.toml, else the installed distribution's."""
    pyproject = Path(__file__).resolve().parents[2] / "pyproject.toml"
    if pyproject.is_file():
        scripts = tomllib.loads(pyproject.read_text())["project"]["scripts"]
    else:
        scripts = {e.name: e.value for e in metadata.entry_points(group="console_scripts")
                   if e.name.startswith("msta-") and e.module.startswith("msta.")}
    code = "import sys, {m}; sys.argv[0] = {n!r}; {m}.{f}()"
    return {name: [sys.executable, "-c", code.format(m=v.split(":")[0], f=v.split(":")[1],
                                                    n=name)]
            for name, v in sorted(scripts.items())}


def wall(argv: list[str]) -> float:
    """Seconds one successful run of ``argv`` takes (output discarded; a failure raises)."""
    t = time.perf_counter()
    subprocess.run(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, check=True)
    return time.perf_counter() - t


def first_line(argv: list[str]) -> float:
    """Seconds until ``argv`` prints its first non-empty line (stdout or stderr); the run is
    stopped there."""
    t = time.perf_counter()
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        assert proc.stdout is not None
        for line in proc.stdout:
            if line.strip():
                return time.perf_counter() - t
        raise RuntimeError(f"{argv[-1]} printed nothing")
    finally:
        proc.kill()
        proc.wait()


def measure(cfg: StartupConfig) -> dict[str, float]:
    """Best seconds per command (``--help``), for the reference and for msta-train's first
    line."""
    out = own_output(cfg.output_dir, PROG, frozenset({"dataset", "run"}))
    out.mkdir(parents=True, exist_ok=True)
    dataset = out / "dataset"
    if not dataset.exists():
        make_dataset(dataset, episodes=8, frames=100)
    shutil.rmtree(out / "run", ignore_errors=True)
    train = [*commands()["msta-train"], f"--dataset={dataset}", "--policy.preset=tiny",
             "--steps=50", f"--output_dir={out / 'run'}"]
    runs = {name: [*argv, "--help"] for name, argv in commands().items()}
    best: dict[str, float] = {}
    for _ in range(cfg.rounds):
        for name, argv in [("reference", list(REFERENCE)), *runs.items()]:
            best[name] = min(best.get(name, float("inf")), wall(argv))
        best["msta-train first line"] = min(best.get("msta-train first line", float("inf")),
                                            first_line(train))
        shutil.rmtree(out / "run", ignore_errors=True)
    return best


def main(argv: list[str] | None = None) -> None:
    cfg = parse_config(StartupConfig, argv, PROG)
    best = measure(cfg)
    reference = best.pop("reference")
    line = best.pop("msta-train first line")
    for name, s in best.items():
        print(f"{name:<20} --help {s:5.2f} s")
    slowest = max(best, key=best.__getitem__)
    print(f"reference (python -c 'import torch'): {reference:.2f} s")
    print(f"slowest --help: {best[slowest]:.2f} s ({slowest})")
    print(f"slowest --help vs import torch: {best[slowest] / reference:.2f}")
    print(f"msta-train first line: {line:.2f} s")


if __name__ == "__main__":
    main()
