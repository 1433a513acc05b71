"""``make demo`` / ``msta-demo``: the msta pipeline on built-in defaults, sized for a laptop CPU.

Steps (each prints what it did and where the files are):
  1. simulator + teacher: the default teacher walks every terrain type; summary table and
     an image strip.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

from collect.sim.cli import SimRunConfig, simulate
from collect.sim.env import EnvConfig
from collect.sim.terrain import TerrainConfig


def default_teacher() -> str:
    """The gait controller when it is available, else the hold-the-pose baseline."""
    import policies.teacher  # noqa: F401
    from policies.teacher.base import TEACHERS

    return "gait" if "gait" in TEACHERS else "zero"


def step_teacher(out: Path, seconds: float, envs_per_type: int) -> None:
    terrain = TerrainConfig(curriculum=False, max_init_level=2)
    cfg = SimRunConfig(
        env=EnvConfig(num_envs=envs_per_type * len(terrain.types), seed=0, terrain=terrain),
        policy=default_teacher(), seconds=seconds, out=str(out / "teacher"))
    print(f"\n== 1. teacher '{cfg.policy}' on every terrain type (levels 0-9, "
          f"{envs_per_type} robots per type, {seconds:.0f} s) ==")
    simulate(cfg)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description="Run the msta demo pipeline on built-in defaults.")
    p.add_argument("--out", type=Path, default=Path("outputs/demo"), help="output folder")
    p.add_argument("--seconds", type=float, default=10.0, help="teacher walk per robot (s)")
    p.add_argument("--envs_per_type", type=int, default=16)
    args = p.parse_args(argv)
    os.environ.setdefault("MUJOCO_GL", "egl")
    t0 = time.time()
    step_teacher(args.out, args.seconds, args.envs_per_type)
    print(f"\ndemo finished in {time.time() - t0:.0f} s; outputs in {args.out}/")


if __name__ == "__main__":
    main()
