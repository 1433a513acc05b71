"""Quality report of a teacher: survival and command tracking per terrain type and level.

    python -m msta.eval.teacher_report --episodes=100 --envs_per_tile=20 \\
        --report=docs/teacher_quality.md --image=docs/teacher_stairs_up.png
    python -m msta.eval.teacher_report --teacher.type=rma --teacher.path=CKPT --terrains=flat \\
        --levels=0-4 --report=outputs/rma_quality.md --image=''

Every terrain type runs on its own grid (``--columns`` columns of that type x the levels),
and every (type, level) tile gets ``--envs_per_tile`` environments pinned to it (terrain
curriculum off); each environment runs the same number of ``--episode_length_s`` episodes,
so falls do not bias the count. Commands come from the simulator's defaults (the paper's
ranges: vx, vy in [-1, 1] m/s, yaw rate from a sampled heading capped to [-1, 1] rad/s);
domain randomization and observation noise are on unless disabled (``--randomization=false``,
``--noise=false``). The image strip shows
the teacher climbing stairs (MuJoCo offscreen, ``MUJOCO_GL=egl``).
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from msta.collect.rollout import Step, fell, film, rollout
from msta.collect.sim.commands import CommandConfig
from msta.collect.sim.env import QuadrupedEnv
from msta.collect.sim.env_config import EnvConfig, NoiseConfig, load_sim_robot
from msta.collect.sim.randomization import RandomizationConfig
from msta.collect.sim.render import save_strip, tracking_camera
from msta.collect.sim.terrain import TERRAIN_TYPES, TerrainConfig
from msta.data.checks import check_at_least
from msta.data.cli import parse_config
from msta.data.robot import LEGACY_ROBOT
from msta.eval.metrics import TrialResults, summarize
from msta.policies.teacher.config import TeacherConfig, build_teacher

PROG = "python -m msta.eval.teacher_report"

MINIMUM_FLAT_LEVELS = 5          # flat and smooth slope levels 0-4: >= 95 % survival
MINIMUM_LOW_LEVELS = 3           # every type, levels 0-2: >= 80 % survival


def tile_row(summary: dict[str, Any]) -> dict[str, Any]:
    """A report row from :func:`msta.eval.metrics.summarize` over a tile's episodes: ``episodes``,
    ``survival`` (share ending by the time limit) with its 95 % interval ``survival_ci``,
    ``lin_reward`` / ``ang_reward`` (tracking reward per step lived: the episodes' summed
    returns over their summed steps), ``lin_err`` / ``ang_err`` (mean |v_xy - cmd_xy| and
    |w_z - cmd_wz| over all steps, :func:`msta.collect.rollout.step_quantities`)."""
    length = summary["length"] or float("nan")
    return {"episodes": summary["trials"], "survival": summary["survival"],
            "survival_ci": summary["ci"]["survival"],
            "lin_reward": summary["lin_tracking"] / length,
            "ang_reward": summary["ang_tracking"] / length,
            "lin_err": summary["vel_err"], "ang_err": summary["yaw_err"]}


#: Report rows per (terrain type, level): :func:`tile_row`.
Stats = dict[tuple[str, int], dict[str, Any]]


@dataclass
class TeacherReportConfig:
    """What the report runs and where it writes it (``python -m msta.eval.teacher_report``).

    Args:
        teacher: the teacher to report on (``--teacher.type``, ``--teacher.path``).
        robot: the simulated robot, the one the teacher is built for: a shipped robot's name
            (a1, go1) or a spec file's path (docs/robots.md).
        episodes: episodes per (terrain type, level) tile.
        envs_per_tile: environments pinned to each tile (at most ``episodes``); each runs
            ceil(episodes / envs_per_tile) episodes.
        terrains: comma-separated terrain types (empty: all six).
        levels: terrain levels, a range ``0-9`` or a list ``0,1,2``.
        episode_length_s: episode length (s).
        randomization: domain randomization (dynamics, pushes, latency) on.
        noise: observation noise on.
        seed: simulator seed (terrain, spawns, commands, noise), also of the image strip.
        nthread: MuJoCo rollout threads.
        columns: columns of each terrain type in its grid.
        report: the Markdown file to write.
        image: the stairs-up image strip to write ('' skips it).
        progress: show a progress bar per terrain type.
    """

    teacher: TeacherConfig = field(default_factory=TeacherConfig)
    robot: str = LEGACY_ROBOT
    episodes: int = 100
    envs_per_tile: int = 10
    terrains: str = ""
    levels: str = "0-9"
    episode_length_s: float = 20.0
    randomization: bool = True
    noise: bool = True
    seed: int = 0
    nthread: int = 2
    columns: int = 3
    report: str = "docs/teacher_quality.md"
    image: str = "docs/teacher_stairs_up.png"
    progress: bool = True

    def __post_init__(self) -> None:
        load_sim_robot(self.robot, "robot")  # a bad robot: one line, before anything runs
        self.teacher = self.teacher.on_robot(self.robot, "teacher_report")
        check_at_least(self, 1, "episodes", "envs_per_tile", "nthread", "columns")
        if not self.episode_length_s > 0:
            raise ValueError(f"episode_length_s={self.episode_length_s} must be > 0")
        if not self.report:
            raise ValueError("report is the Markdown file to write; it cannot be empty")
        self.envs_per_tile = min(self.envs_per_tile, self.episodes)
        # what evaluate() runs: the parsed terrains and levels
        self.terrain_list = tuple(t for t in self.terrains.split(",") if t) or TERRAIN_TYPES
        for t in self.terrain_list:
            if t not in TERRAIN_TYPES:
                raise ValueError(f"unknown terrain {t!r}; known terrains: {list(TERRAIN_TYPES)}")
        self.level_list = parse_levels(self.levels)


def parse_levels(text: str) -> tuple[int, ...]:
    """``"0-9"`` (a range, both ends included) or ``"0,1,2"`` -> level numbers."""
    words = [w.strip() for w in text.split("-" if "-" in text else ",") if w.strip()]
    if not all(w.isdigit() for w in words) or ("-" in text and len(words) != 2):
        raise ValueError(f"levels {text!r}: write a range (0-9) or a list (0,1,2)")
    numbers = [int(w) for w in words]
    levels = tuple(range(numbers[0], numbers[1] + 1)) if "-" in text else tuple(numbers)
    n = TerrainConfig().num_levels
    if not levels or not all(0 <= lv < n for lv in levels):
        raise ValueError(f"levels {text!r}: give levels in [0, {n - 1}]")
    return levels


def evaluate(cfg: TeacherReportConfig) -> Stats:
    """Roll the teacher on every (type, level) tile; see the module docstring.

    Each terrain type runs on its own grid (``columns_per_type`` columns of that type
    only), so a robot walking away along x stays on its type; walking along y moves it
    between neighbouring levels of the same type.

    Args:
        cfg: what to run (``cfg.progress``: a tqdm bar over control steps).
    Returns:
        report rows (:func:`tile_row`) per (type name, level).
    """
    stats: Stats = {}
    for t in cfg.terrain_list:
        stats.update(_evaluate_type(cfg, t))
    return stats


def _evaluate_type(cfg: TeacherReportConfig, terrain: str) -> Stats:
    """One terrain type: every environment runs ``ceil(episodes / envs_per_tile)`` episodes
    through :func:`msta.collect.rollout.rollout`; each finished episode is one trial of
    :class:`msta.eval.metrics.TrialResults`, summarized per tile by :func:`msta.eval.metrics.summarize`."""
    k = cfg.envs_per_tile
    n = len(cfg.level_list) * k
    env_cfg = EnvConfig(robot=cfg.robot, num_envs=n, seed=cfg.seed,
                        episode_length_s=cfg.episode_length_s, nthread=cfg.nthread,
                        terrain=TerrainConfig(types=(terrain,), columns_per_type=cfg.columns,
                                              curriculum=False),
                        randomization=RandomizationConfig(enabled=cfg.randomization),
                        noise=NoiseConfig(enabled=cfg.noise))
    env = QuadrupedEnv(env_cfg)
    env.reset(type_idx=np.zeros(n, dtype=np.int64), level=np.repeat(np.asarray(cfg.level_list), k))
    teacher = build_teacher(cfg.teacher, env.cfg.teacher_robot)
    per_env = math.ceil(cfg.episodes / k)
    done_eps = np.zeros(n, dtype=np.int64)
    episodes = TrialResults.zeros(n * per_env, env.max_steps)  # env e's j-th: e * per_env + j
    total = per_env * env.max_steps
    bar = _bar(total, cfg.progress, terrain)

    def on_step(step: Step) -> bool:
        active = done_eps < per_env
        slot = np.arange(n) * per_env + np.minimum(done_eps, per_env - 1)
        episodes.add(slot, step, active.astype(np.float64))
        ended = np.flatnonzero(step.res.done & active)
        episodes.fell[slot[ended]] = fell(step.res)[ended]
        done_eps[ended] += 1
        if bar is not None and (step.t + 1) % 25 == 0:
            bar.n = min(total, int(np.minimum(done_eps * env.max_steps + env.episode_step,
                                              per_env * env.max_steps).mean()))
            bar.refresh()
        return not (done_eps < per_env).any()

    rollout(env, teacher, on_step)
    if bar is not None:
        bar.close()
    tile_of_episode = np.repeat(np.arange(len(cfg.level_list)), k * per_env)
    return {(terrain, lv): tile_row(summarize(episodes, [np.flatnonzero(tile_of_episode == i)]))
            for i, lv in enumerate(cfg.level_list)}


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


def render_markdown(stats: Stats, cfg: TeacherReportConfig, command: str,
                    seconds: float, image: str | None) -> str:
    """The report as Markdown (tables per terrain, summary, minimums)."""
    on = "" if cfg.robot == LEGACY_ROBOT else f" on `{cfg.robot}`"
    lines = [f"# Teacher quality: `{cfg.teacher.type}`{on}", "",
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
    easy = [lv for lv in cfg.level_list if lv < 5]  # the levels the summary averages
    span = f"L{min(easy)}-{max(easy)}" if easy else "L0-4"
    lines += ["## Summary", "", "| terrain | highest level with >= 80 % survival | "
              f"survival {span} | mean abs(v err) {span} |", "|---|---|---|---|"]
    for t in cfg.terrain_list:
        low = [stats[(t, lv)] for lv in easy]
        surv = np.mean([r["survival"] for r in low]) if low else float("nan")
        err = np.mean([r["lin_err"] for r in low]) if low else float("nan")
        lines.append(f"| {t} | {highest_level(stats, t, cfg.level_list)} | {surv:.1%} | {err:.3f} |")
    lines += ["", "## Minimums", ""] + _minimums(stats, cfg) + [""]
    for t in cfg.terrain_list:
        lines += [f"## {t}", "", "| level | episodes | survival | lin track | ang track | "
                  "abs(v err) m/s | abs(w err) rad/s |", "|---|---|---|---|---|---|---|"]
        for lv in cfg.level_list:
            r = stats[(t, lv)]
            lines.append(f"| {lv} | {r['episodes']} | {r['survival']:.1%} | "
                         f"{r['lin_reward'] / (env_scale('lin', cfg.robot)):.3f} | "
                         f"{r['ang_reward'] / env_scale('ang', cfg.robot):.3f} | "
                         f"{r['lin_err']:.3f} | "
                         f"{r['ang_err']:.3f} |")
        lines.append("")
    if image:
        lines += ["## Stairs up", "", f"![teacher on stairs up]({Path(image).name})", ""]
    return "\n".join(lines)


def env_scale(which: str, robot: str = LEGACY_ROBOT) -> float:
    """scale x dt of the default tracking rewards (to map them to [0, 1]).

    Args:
        which: ``"lin"`` or ``"ang"``.
        robot: the simulated robot (its control period is the dt).
    """
    cfg = EnvConfig(num_envs=1, robot=robot)
    s = cfg.rewards.scales
    return (s.tracking_lin_vel if which == "lin" else s.tracking_ang_vel) * cfg.dt


def _minimums(stats: Stats, cfg: TeacherReportConfig) -> list[str]:
    out = []
    for t in ("flat", "smooth_slope"):
        for lv in range(MINIMUM_FLAT_LEVELS):
            if (t, lv) in stats:
                r = stats[(t, lv)]
                ok = r["survival"] >= 0.95 and r["lin_err"] <= 0.25
                out.append(f"- {t} L{lv}: survival {r['survival']:.1%} (>= 95 %), |v err| "
                           f"{r['lin_err']:.3f} (<= 0.25): {'met' if ok else 'NOT met'}")
    for t in cfg.terrain_list:
        for lv in range(MINIMUM_LOW_LEVELS):
            if (t, lv) in stats:
                r = stats[(t, lv)]
                ok = r["survival"] >= 0.8
                out.append(f"- {t} L{lv}: survival {r['survival']:.1%} (>= 80 %): "
                           f"{'met' if ok else 'NOT met'}")
    return out


# ----------------------------------------------------------------------------- image
def render_stairs(path: Path, teacher: TeacherConfig | None = None, level: int = 4,
                  seconds: float = 6.0, frames: int = 6, seed: int = 0,
                  robot: str = LEGACY_ROBOT) -> Path:
    """Image strip of the teacher walking out of the stairs-up pit (forward command).

    Args:
        path: PNG to write.
        teacher: the teacher (default: gait).
        level: stairs-up level (step height 0.05 + 0.18 level / 10 m).
        seconds: simulated time covered by the strip.
        frames: pictures in the strip.
        seed: simulator seed.
        robot: the simulated robot, the one the teacher is built for.
    """
    cfg = EnvConfig(robot=robot, num_envs=1, seed=seed, terrain=TerrainConfig(curriculum=False),
                    commands=CommandConfig(use_heading=False, resample_s=1e6),
                    randomization=RandomizationConfig(enabled=False),
                    noise=NoiseConfig(enabled=False), spawn_offset=0.0)
    env = QuadrupedEnv(cfg)
    env.reset(type_idx=np.array([cfg.terrain.types.index("stairs_up")]), level=np.array([level]))
    command = np.array([[0.6, 0.0, 0.0]])

    def hold_command(obs: dict[str, np.ndarray]) -> None:  # every step: straight ahead
        env.commands.command[:] = command
        obs["command"][:] = command

    def camera(env: QuadrupedEnv):  # beside the robot, looking across its heading
        return tracking_camera(1.4, float(np.degrees(env.meas["yaw"][0])) + 90.0, -15.0)

    steps = int(round(seconds / env.dt))
    every = max(1, steps // frames)
    hold_command(env.last_obs)
    images = film(env, build_teacher(teacher or TeacherConfig(), env.cfg.teacher_robot),
                  min(steps, every * frames),
                  every=every, first=every - 1, camera=camera,
                  on_step=lambda step: hold_command(step.res.obs))
    return save_strip(images, path, columns=len(images))


# ----------------------------------------------------------------------------- CLI
#: Options the Regenerate line always shows (the others only where they differ from the
#: defaults; ``progress`` never: it changes no figure).
ALWAYS_SHOWN = ("teacher", "episodes", "envs_per_tile")


def command_line(cfg: TeacherReportConfig) -> str:
    """The command that regenerates ``cfg``'s report (the report's "Regenerate:" line)."""
    default = TeacherReportConfig()
    parts = [PROG]
    for f in fields(cfg):
        value, base = getattr(cfg, f.name), getattr(default, f.name)
        if f.name == "progress" or (value == base and f.name not in ALWAYS_SHOWN):
            continue
        if f.name == "teacher":
            parts += [f"--teacher.{k}={_word(v)}" for k, v in asdict(value).items()
                      if k == "type" or v != getattr(TeacherConfig(type=value.type), k)]
        else:
            parts.append(f"--{f.name}={_word(value)}")
    return " ".join(parts)


def _word(value: object) -> str:
    if isinstance(value, bool):
        return str(value).lower()
    return "''" if value == "" else str(value)


def main(argv: list[str] | None = None) -> None:
    """Run the report and write the Markdown (and the stairs image)."""
    cfg = parse_config(TeacherReportConfig, argv, PROG)
    t0 = time.time()
    stats = evaluate(cfg)
    image = None
    if cfg.image:
        image = str(render_stairs(Path(cfg.image), cfg.teacher, seed=cfg.seed,
                                  robot=cfg.robot))
    md = render_markdown(stats, cfg, command_line(cfg), time.time() - t0, image)
    out = Path(cfg.report)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(md)
    print(md.split("## Minimums")[0])
    print(f"wrote {out}" + (f" and {image}" if image else ""))


if __name__ == "__main__":
    main()
