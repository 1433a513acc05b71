"""Quality report of a teacher: survival and command tracking per terrain type and level.

    python -m eval.teacher_report --episodes 100 --out docs/teacher_quality.md

Every terrain type runs on its own grid (``columns`` columns of that type x the levels),
and every (type, level) tile gets ``--envs-per-tile`` environments pinned to it (terrain
curriculum off); each environment runs the same number of 20 s episodes, so
falls do not bias the count. Commands come from the simulator's defaults (the paper's
ranges: vx, vy in [-1, 1] m/s, yaw rate from a sampled heading capped to [-1, 1] rad/s);
domain randomization and observation noise are on unless disabled. The image strip shows
the teacher climbing stairs (MuJoCo offscreen, ``MUJOCO_GL=egl``).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

import policies.teacher.gait  # noqa: F401  (registers "gait")
from collect.rollout import Step, rollout
from collect.sim.commands import CommandConfig
from collect.sim.env import REASONS, EnvConfig, NoiseConfig, QuadrupedEnv
from collect.sim.randomization import RandomizationConfig
from collect.sim.terrain import TERRAIN_TYPES, TerrainConfig
from eval.metrics import TrialResults, summarize
from policies.teacher.base import TEACHERS, make_teacher

MINIMUM_FLAT_LEVELS = 5          # flat and smooth slope levels 0-4: >= 95 % survival
MINIMUM_LOW_LEVELS = 3           # every type, levels 0-2: >= 80 % survival


def tile_row(summary: dict[str, Any]) -> dict[str, Any]:
    """A report row from :func:`eval.metrics.summarize` over a tile's episodes: ``episodes``,
    ``survival`` (share ending by the time limit) with its 95 % interval ``survival_ci``,
    ``lin_reward`` / ``ang_reward`` (tracking reward per step lived: the episodes' summed
    returns over their summed steps), ``lin_err`` / ``ang_err`` (mean |v_xy - cmd_xy| and
    |w_z - cmd_wz| over all steps, :func:`collect.rollout.step_quantities`)."""
    length = summary["length"] or float("nan")
    return {"episodes": summary["trials"], "survival": summary["survival"],
            "survival_ci": summary["ci"]["survival"],
            "lin_reward": summary["lin_tracking"] / length,
            "ang_reward": summary["ang_tracking"] / length,
            "lin_err": summary["vel_err"], "ang_err": summary["yaw_err"]}


#: Report rows per (terrain type, level): :func:`tile_row`.
Stats = dict[tuple[str, int], dict[str, Any]]


@dataclass
class ReportConfig:
    teacher: str = "gait"
    episodes: int = 100
    envs_per_tile: int = 10
    types: tuple[str, ...] = TERRAIN_TYPES
    levels: tuple[int, ...] = tuple(range(10))
    episode_length_s: float = 20.0
    randomization: bool = True
    noise: bool = True
    seed: int = 0
    nthread: int = 2
    columns: int = 3
    extra: dict = field(default_factory=dict)


def evaluate(cfg: ReportConfig, progress: bool = True) -> Stats:
    """Roll the teacher on every (type, level) tile; see the module docstring.

    Each terrain type runs on its own grid (``columns_per_type`` columns of that type
    only), so a robot walking away along x stays on its type; walking along y moves it
    between neighbouring levels of the same type.

    Args:
        cfg: what to run.
        progress: show a tqdm bar over control steps.
    Returns:
        report rows (:func:`tile_row`) per (type name, level).
    """
    stats: Stats = {}
    for t in cfg.types:
        stats.update(_evaluate_type(cfg, t, progress))
    return stats


def _evaluate_type(cfg: ReportConfig, terrain: str, progress: bool) -> Stats:
    """One terrain type: every environment runs ``ceil(episodes / envs_per_tile)`` episodes
    through :func:`collect.rollout.rollout`; each finished episode is one trial of
    :class:`eval.metrics.TrialResults`, summarized per tile by :func:`eval.metrics.summarize`."""
    k = cfg.envs_per_tile
    n = len(cfg.levels) * k
    env_cfg = EnvConfig(num_envs=n, seed=cfg.seed, episode_length_s=cfg.episode_length_s,
                        nthread=cfg.nthread,
                        terrain=TerrainConfig(types=(terrain,), columns_per_type=cfg.columns,
                                              curriculum=False),
                        randomization=RandomizationConfig(enabled=cfg.randomization),
                        noise=NoiseConfig(enabled=cfg.noise))
    env = QuadrupedEnv(env_cfg)
    env.reset(type_idx=np.zeros(n, dtype=np.int64), level=np.repeat(np.asarray(cfg.levels), k))
    teacher = make_teacher(cfg.teacher)
    per_env = math.ceil(cfg.episodes / k)
    done_eps = np.zeros(n, dtype=np.int64)
    episodes = TrialResults.zeros(n * per_env, env.max_steps)  # env e's j-th: e * per_env + j
    fell = np.isin(np.arange(len(REASONS)), [REASONS.index("fall"), REASONS.index("nan")])
    total = per_env * env.max_steps
    bar = _bar(total, progress, terrain)

    def on_step(step: Step) -> bool:
        active = done_eps < per_env
        slot = np.arange(n) * per_env + np.minimum(done_eps, per_env - 1)
        episodes.add(slot, step, active.astype(np.float64))
        ended = np.flatnonzero(step.res.done & active)
        episodes.fell[slot[ended]] = fell[step.res.reason[ended]]
        done_eps[ended] += 1
        if bar is not None and (step.t + 1) % 25 == 0:
            bar.n = min(total, int(np.minimum(done_eps * env.max_steps + env.episode_step,
                                              per_env * env.max_steps).mean()))
            bar.refresh()
        return not (done_eps < per_env).any()

    rollout(env, teacher, on_step)
    if bar is not None:
        bar.close()
    tile_of_episode = np.repeat(np.arange(len(cfg.levels)), k * per_env)
    return {(terrain, lv): tile_row(summarize(episodes, [np.flatnonzero(tile_of_episode == i)]))
            for i, lv in enumerate(cfg.levels)}


def _bar(total: int, progress: bool, terrain: str):
    if not progress:
        return None
    return tqdm(total=total, unit="step/env", desc=f"teacher report {terrain}", smoothing=0.1)


def highest_level(stats: Stats, terrain: str, levels: tuple[int, ...],
                  threshold: float = 0.8) -> int:
    """Highest level L such that every level <= L has survival >= threshold (-1 if none)."""
    best = -1
    for lv in sorted(levels):
        if stats[(terrain, lv)]["survival"] < threshold:
            break
        best = lv
    return best


def render_markdown(stats: Stats, cfg: ReportConfig, command: str,
                    seconds: float, image: str | None) -> str:
    """The report as Markdown (tables per terrain, summary, minimums)."""
    lines = [f"# Teacher quality: `{cfg.teacher}`", "",
             f"Regenerate: `{command}`", "",
             f"{cfg.episodes} episodes of {cfg.episode_length_s:g} s per terrain type and level "
             f"({cfg.envs_per_tile} environments per tile), each terrain type on its own grid "
             f"({cfg.columns} columns of that type x 10 levels, so a robot walking along x "
             f"stays on its type; walking along y moves it to neighbouring levels of the same "
             f"type), terrain curriculum off, "
             f"randomization {'on' if cfg.randomization else 'off'}, observation noise "
             f"{'on' if cfg.noise else 'off'}, commands from the paper's ranges "
             f"(vx, vy in [-1, 1] m/s, yaw rate from a heading, capped to [-1, 1] rad/s), "
             f"seed {cfg.seed}. Wall time {seconds / 60:.1f} min.", "",
             "Columns: survival = episodes reaching the time limit; lin/ang track = mean per-step "
             "tracking reward exp(-err^2/0.25) (1 = perfect; the simulator's reward adds the "
             "scale x dt factor: x 0.02 and x 0.01); |v err| = mean |v_xy - cmd_xy| (m/s); "
             "|w err| = mean |w_z - cmd_wz| (rad/s), over all steps of all episodes.", ""]
    lines += ["## Summary", "", "| terrain | highest level with >= 80 % survival | "
              "survival L0-4 | mean abs(v err) L0-4 |", "|---|---|---|---|"]
    for t in cfg.types:
        low = [stats[(t, lv)] for lv in cfg.levels if lv < 5]
        surv = np.mean([r["survival"] for r in low]) if low else float("nan")
        err = np.mean([r["lin_err"] for r in low]) if low else float("nan")
        lines.append(f"| {t} | {highest_level(stats, t, cfg.levels)} | {surv:.1%} | {err:.3f} |")
    lines += ["", "## Minimums (issue 3)", ""] + _minimums(stats, cfg) + [""]
    for t in cfg.types:
        lines += [f"## {t}", "", "| level | episodes | survival | lin track | ang track | "
                  "abs(v err) m/s | abs(w err) rad/s |", "|---|---|---|---|---|---|---|"]
        for lv in cfg.levels:
            r = stats[(t, lv)]
            lines.append(f"| {lv} | {r['episodes']} | {r['survival']:.1%} | "
                         f"{r['lin_reward'] / (env_scale('lin')):.3f} | "
                         f"{r['ang_reward'] / env_scale('ang'):.3f} | {r['lin_err']:.3f} | "
                         f"{r['ang_err']:.3f} |")
        lines.append("")
    if image:
        lines += ["## Stairs up", "", f"![teacher on stairs up]({Path(image).name})", ""]
    return "\n".join(lines)


def env_scale(which: str) -> float:
    """scale x dt of the default tracking rewards (to map them to [0, 1])."""
    cfg = EnvConfig(num_envs=1)
    s = cfg.rewards.scales
    return (s.tracking_lin_vel if which == "lin" else s.tracking_ang_vel) * cfg.dt


def _minimums(stats: Stats, cfg: ReportConfig) -> list[str]:
    out = []
    for t in ("flat", "smooth_slope"):
        for lv in range(MINIMUM_FLAT_LEVELS):
            if (t, lv) in stats:
                r = stats[(t, lv)]
                ok = r["survival"] >= 0.95 and r["lin_err"] <= 0.25
                out.append(f"- {t} L{lv}: survival {r['survival']:.1%} (>= 95 %), |v err| "
                           f"{r['lin_err']:.3f} (<= 0.25): {'met' if ok else 'NOT met'}")
    for t in cfg.types:
        for lv in range(MINIMUM_LOW_LEVELS):
            if (t, lv) in stats:
                r = stats[(t, lv)]
                ok = r["survival"] >= 0.8
                out.append(f"- {t} L{lv}: survival {r['survival']:.1%} (>= 80 %): "
                           f"{'met' if ok else 'NOT met'}")
    return out


# ----------------------------------------------------------------------------- image
def render_stairs(path: Path, teacher_name: str = "gait", level: int = 4, seconds: float = 6.0,
                  frames: int = 6, seed: int = 0) -> Path:
    """Image strip of the teacher walking out of the stairs-up pit (forward command).

    Args:
        path: PNG to write.
        teacher_name: registered teacher.
        level: stairs-up level (step height 0.05 + 0.18 level / 10 m).
        seconds: simulated time covered by the strip.
        frames: pictures in the strip.
        seed: simulator seed.
    """
    os.environ.setdefault("MUJOCO_GL", "egl")
    import mujoco
    from PIL import Image

    cfg = EnvConfig(num_envs=1, seed=seed, terrain=TerrainConfig(curriculum=False),
                    commands=CommandConfig(use_heading=False, resample_s=1e6),
                    randomization=RandomizationConfig(enabled=False),
                    noise=NoiseConfig(enabled=False), spawn_offset=0.0)
    env = QuadrupedEnv(cfg)
    obs = env.reset(type_idx=np.array([cfg.terrain.types.index("stairs_up")]),
                    level=np.array([level]))
    teacher = make_teacher(teacher_name)
    command = np.array([[0.6, 0.0, 0.0]])
    renderer = mujoco.Renderer(env.model, 360, 480)
    data = mujoco.MjData(env.model)
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_TRACKING
    cam.trackbodyid = 1
    cam.distance, cam.elevation = 1.4, -15.0
    steps = int(round(seconds / env.dt))
    every = max(1, steps // frames)
    images = []
    try:
        for t in range(steps):
            env.commands.command[:] = command
            obs["command"][:] = command
            if t % every == every - 1 and len(images) < frames:
                mujoco.mj_setState(env.model, data, env.state[0],
                                   mujoco.mjtState.mjSTATE_FULLPHYSICS)
                mujoco.mj_forward(env.model, data)
                cam.azimuth = float(np.degrees(env.meas["yaw"][0])) + 90.0
                renderer.update_scene(data, camera=cam)
                images.append(renderer.render().copy())
            res = env.step(teacher.act(obs))
            obs = res.obs
            teacher.reset(np.flatnonzero(res.done))
    finally:
        renderer.close()
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.concatenate(images, axis=1)).save(path)
    return path


# ----------------------------------------------------------------------------- CLI
def _parse(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m eval.teacher_report", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--teacher", default="gait", help=f"registered teacher {sorted(TEACHERS)}")
    p.add_argument("--episodes", type=int, default=100, help="episodes per (terrain, level)")
    p.add_argument("--envs-per-tile", type=int, default=10)
    p.add_argument("--types", default=",".join(TERRAIN_TYPES), help="comma-separated types")
    p.add_argument("--levels", default="0-9", help="e.g. 0-9 or 0,1,2")
    p.add_argument("--seconds", type=float, default=20.0, help="episode length (s)")
    p.add_argument("--no-randomization", action="store_true")
    p.add_argument("--no-noise", action="store_true")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="docs/teacher_quality.md")
    p.add_argument("--image", default="docs/teacher_stairs_up.png",
                   help="image strip path ('' to skip)")
    p.add_argument("--no-progress", action="store_true")
    return p.parse_args(argv)


def _levels(text: str) -> tuple[int, ...]:
    if "-" in text:
        lo, hi = (int(v) for v in text.split("-"))
        return tuple(range(lo, hi + 1))
    return tuple(int(v) for v in text.split(","))


def main(argv: list[str] | None = None) -> None:
    """Run the report and write the Markdown (and the stairs image)."""
    a = _parse(argv)
    types = tuple(t for t in a.types.split(",") if t)
    for t in types:
        if t not in TERRAIN_TYPES:
            raise SystemExit(f"unknown terrain type {t!r}; known: {TERRAIN_TYPES}")
    cfg = ReportConfig(teacher=a.teacher, episodes=a.episodes,
                       envs_per_tile=min(a.envs_per_tile, a.episodes), types=types,
                       levels=_levels(a.levels), episode_length_s=a.seconds,
                       randomization=not a.no_randomization, noise=not a.no_noise, seed=a.seed)
    t0 = time.time()
    stats = evaluate(cfg, progress=not a.no_progress)
    image = None
    if a.image:
        image = str(render_stairs(Path(a.image), a.teacher, seed=a.seed))
    command = "python -m eval.teacher_report " + " ".join(sys.argv[1:] if argv is None else argv)
    md = render_markdown(stats, cfg, command.strip(), time.time() - t0, image)
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(md)
    print(md.split("## Minimums")[0])
    print(f"wrote {out}" + (f" and {image}" if image else ""))


if __name__ == "__main__":
    main()
