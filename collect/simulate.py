"""``msta-sim``: roll a policy in the batched simulator, print a per-terrain table, save pictures.

    msta-sim --policy=zero --seconds=5 --env.num_envs=64 --out=outputs/sim
    msta-sim --policy=gait --env.terrain.types='[flat,stairs_up]'
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import policies.teacher  # noqa: F401  (registers the built-in teachers)
from collect.rollout import ZeroPolicy, run
from collect.sim.env import EnvConfig, QuadrupedEnv
from msta_data.cli import parse_config
from policies.teacher.base import make_teacher


@dataclass
class SimRunConfig:
    """Args:
        env: simulator configuration.
        policy: "zero" (hold the default pose) or a registered teacher name (e.g. "gait").
        seconds: simulated time per environment.
        out: folder for the image strip (and video with ``video=True``).
        image: save an image strip of environment 0.
        video: also save an MP4 of environment 0.
        progress: show a progress bar.
    """

    env: EnvConfig = field(default_factory=lambda: EnvConfig(num_envs=64))
    policy: str = "zero"
    seconds: float = 5.0
    out: str = "outputs/sim"
    image: bool = True
    video: bool = False
    progress: bool = True


def make_policy(name: str):
    """'zero' or a registered teacher."""
    if name == "zero":
        return ZeroPolicy()
    return make_teacher(name)


def simulate(cfg: SimRunConfig) -> str:
    """Run, print and return the Markdown summary table."""
    env = QuadrupedEnv(cfg.env)
    env.reset()
    policy = make_policy(cfg.policy)
    steps = max(1, int(round(cfg.seconds / env.dt)))
    summary = run(env, policy, steps, progress=cfg.progress)
    table = summary.table()
    print(f"\npolicy={cfg.policy}  envs={env.num_envs}  {cfg.seconds:.1f} s each "
          f"({steps * env.num_envs:,} env steps); episode ends by reason "
          f"{dict(zip(('running', 'fall', 'timeout', 'nan'), env.resets_by_reason.tolist()))}")
    print(table)
    if cfg.image or cfg.video:
        os.environ.setdefault("MUJOCO_GL", "egl")
        from collect.sim.render import record, save_strip, save_video

        env.reset()
        act = policy.act if hasattr(policy, "act") else policy
        if hasattr(policy, "reset"):
            policy.reset(np.arange(env.num_envs))
        frames = record(env, act, steps=min(steps, 150), every=5)
        out = Path(cfg.out)
        if cfg.image:
            print(f"image strip: {save_strip(frames, out / f'{cfg.policy}_strip.png')}")
        if cfg.video:
            print(f"video: {save_video(frames, out / f'{cfg.policy}.mp4')}")
    return table


def main(argv: list[str] | None = None) -> None:
    """Console entry point (``msta-sim``)."""
    simulate(parse_config(SimRunConfig, argv, "msta-sim"))


if __name__ == "__main__":
    main()
