"""Progress of an ``msta-train-teacher`` run at fixed terrains: survival vs environment steps.

    python -m eval.teacher_curve --run=outputs/teacher --image=docs/teacher_rma_curve.png

The curriculum's own survival (``curve.json``) mixes levels that move with the policy, so a
run's progress is measured here on fixed tiles instead: every snapshot the run kept
(``snapshots/iter_<n>/``, ``--ppo.snapshot_interval``), the run's starting point and the
gait controller each walk ``--episodes`` episodes of ``--episode_length_s`` per terrain type
at ``--level`` (the harness of ``eval.teacher_report``: terrain curriculum off,
randomization and observation noise on, seed 0; 95 % Wilson intervals). Results are cached in
``<run>/curve_eval.json`` (re-running evaluates only new snapshots); the image has two
panels: survival per terrain type vs environment steps (PPO's start at 0 steps, the gait
controller as dashed lines),
and the curriculum's survival per episode and mean level from ``curve.json``.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path

import torch
from tqdm import tqdm

from eval.intervals import wilson_interval
from eval.teacher_report import TeacherReportConfig, evaluate, parse_levels
from msta_data.cli import check_at_least, parse_config
from policies.teacher.config import TeacherConfig

PROG = "python -m eval.teacher_curve"
_SNAP = re.compile(r"^iter_(\d+)$")


@dataclass
class TeacherCurveConfig:
    """Args:
        run: an msta-train-teacher output directory (curve.json, snapshots/,
            train_teacher.json).
        terrains: comma-separated terrain types evaluated at ``level``.
        level: the terrain level of every evaluated tile.
        episodes: episodes per terrain type and checkpoint.
        envs_per_tile: robots per tile (each runs episodes / envs_per_tile episodes).
        episode_length_s: episode length (s); 20 is the length of docs/teacher_quality.md.
        nthread: MuJoCo rollout threads and torch threads.
        every: evaluate only the snapshots whose iteration is a multiple of this (0: all);
            a snapshot costs ~1.5 min on 2 idle cores at the defaults.
        image: the PNG to write ('' skips it).
        progress: a progress bar over checkpoints.
    """

    run: str = "outputs/teacher"
    terrains: str = "stairs_up,stairs_down,discrete"
    level: int = 4
    episodes: int = 50
    envs_per_tile: int = 25
    episode_length_s: float = 20.0
    nthread: int = 2
    every: int = 0
    image: str = "docs/teacher_rma_curve.png"
    progress: bool = True

    def __post_init__(self) -> None:
        check_at_least(self, 1, "episodes", "envs_per_tile", "nthread")
        check_at_least(self, 0, "every")
        parse_levels(str(self.level))
        if not (Path(self.run) / "curve.json").is_file():
            raise ValueError(f"--run={self.run}: no curve.json (not an msta-train-teacher "
                             "output directory, or no PPO chunk finished yet)")


def snapshots(run: Path) -> list[tuple[int, Path]]:
    """(iteration, directory) of every kept snapshot, in order."""
    found = [(int(m.group(1)), p) for p in (run / "snapshots").glob("iter_*")
             if (m := _SNAP.match(p.name)) and (p / "model.safetensors").is_file()]
    return sorted(found)


def start_teacher(run: Path) -> TeacherConfig | None:
    """The checkpoint PPO started from: ``--init_from`` or the run's own warm start."""
    cfg = json.loads((run / "train_teacher.json").read_text()) \
        if (run / "train_teacher.json").is_file() else {}
    if cfg.get("init_from"):
        return TeacherConfig(type="rma", path=cfg["init_from"])
    if (run / "warmstart" / "model.safetensors").is_file():
        return TeacherConfig(type="rma", path=str(run / "warmstart"))
    return None


def survival_of(teacher: TeacherConfig, cfg: TeacherCurveConfig) -> dict[str, float]:
    """Survival per terrain type at ``cfg.level`` for one teacher."""
    rc = TeacherReportConfig(teacher=teacher, episodes=cfg.episodes,
                             envs_per_tile=cfg.envs_per_tile, terrains=cfg.terrains,
                             levels=str(cfg.level), episode_length_s=cfg.episode_length_s,
                             nthread=cfg.nthread, report="-", image="", progress=False)
    stats = evaluate(rc)
    return {t: float(stats[(t, cfg.level)]["survival"]) for t in rc.terrain_list}


def env_steps_at(run: Path) -> dict[int, int]:
    """Environment steps at the end of each curve.json row's iteration."""
    rows = json.loads((run / "curve.json").read_text())
    return {int(r["iteration"]): int(r["env_steps"]) for r in rows}


def build(cfg: TeacherCurveConfig) -> dict:
    """Evaluate what is not cached yet; return the cache (also written to the run)."""
    run = Path(cfg.run)
    cache_path = run / "curve_eval.json"
    key = {k: getattr(cfg, k) for k in ("terrains", "level", "episodes", "envs_per_tile",
                                         "episode_length_s")}
    cache = json.loads(cache_path.read_text()) if cache_path.is_file() else {}
    if cache.get("settings") != key:
        cache = {"settings": key, "references": {}, "snapshots": {}}
    todo: list[tuple[str, str, TeacherConfig]] = []
    start = start_teacher(run)
    for name, teacher in (("gait controller", TeacherConfig(type="gait")), ("start", start)):
        if teacher is not None and name not in cache["references"]:
            todo.append(("references", name, teacher))
    for it, path in snapshots(run):
        if str(it) not in cache["snapshots"] and not (cfg.every and it % cfg.every):
            todo.append(("snapshots", str(it), TeacherConfig(type="rma", path=str(path))))
    for group, name, teacher in tqdm(todo, desc="checkpoints", disable=not cfg.progress):
        cache[group][name] = survival_of(teacher, cfg)
        cache_path.write_text(json.dumps(cache, indent=1) + "\n")
    return cache


def render(cache: dict, run: Path, image: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    steps = env_steps_at(run)
    s = cache["settings"]
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(12, 4.2))
    its = sorted(int(i) for i in cache["snapshots"])
    n = s["episodes"]
    start = cache["references"].get("start")
    for k, t in enumerate(s["terrains"].split(",")):
        color = f"C{k}"
        xs = [steps.get(i, float("nan")) / 1e6 for i in its]
        ys = [cache["snapshots"][str(i)][t] for i in its]
        if start is not None:  # PPO's starting point sits at 0 steps
            xs, ys = [0.0] + xs, [start[t]] + ys
        lo, hi = zip(*(wilson_interval(y, n) for y in ys), strict=True) if ys else ((), ())
        ax.errorbar(xs, ys, yerr=[[y - a for y, a in zip(ys, lo, strict=True)],
                                  [b - y for y, b in zip(ys, hi, strict=True)]],
                    fmt="o-", color=color, capsize=2, label=f"{t}")
        if "gait controller" in cache["references"]:
            ax.axhline(cache["references"]["gait controller"][t], color=color, ls="--", lw=1)
    ax.set_xlim(left=-0.05 * max([steps.get(i, 0) / 1e6 for i in its] + [1.0]))
    ax.set_xlabel("environment steps (millions)")
    ax.set_ylabel(f"survival, level {s['level']}")
    ax.set_title(f"fixed tiles: {s['episodes']} episodes of {s['episode_length_s']:g} s per "
                 "point, 95 % Wilson intervals\n(0 steps: PPO's start; dashed: the gait "
                 "controller)", fontsize=9)
    ax.set_ylim(0, 1)
    ax.legend(fontsize=8)
    rows = json.loads((run / "curve.json").read_text())
    x = [r["env_steps"] / 1e6 for r in rows]
    bx.plot(x, [r["survival_per_episode"] for r in rows], color="C0", lw=1,
            label="survival per episode (curriculum)")
    bx.set_ylim(0, 1)
    bx.set_xlabel("environment steps (millions)")
    bx.set_ylabel("survival per episode")
    lx = bx.twinx()
    lx.plot(x, [r["mean_level_at_end"] for r in rows], color="C3", lw=1,
            label="mean level at episode end")
    lx.set_ylabel("level")
    bx.set_title("the curriculum (curve.json, one row per chunk)", fontsize=9)
    bx.legend(loc="lower left", fontsize=8)
    lx.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    image.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(image, dpi=110)
    plt.close(fig)


def table(cache: dict, run: Path) -> str:
    """A Markdown table of the cache: one row per checkpoint, survival with its 95 % Wilson
    interval over the episodes."""
    steps = env_steps_at(run)
    terrains = cache["settings"]["terrains"].split(",")
    n = cache["settings"]["episodes"]

    def cell(p: float) -> str:
        lo, hi = wilson_interval(p, n)
        return f"{p:.2f} ({lo:.2f}-{hi:.2f})"

    lines = ["| checkpoint | env steps | " + " | ".join(terrains) + " |",
             "|---|---|" + "---|" * len(terrains)]
    for name, res in cache["references"].items():
        lines.append(f"| {name} | - | " + " | ".join(cell(res[t]) for t in terrains) + " |")
    for it in sorted(int(i) for i in cache["snapshots"]):
        res = cache["snapshots"][str(it)]
        lines.append(f"| iteration {it} | {steps.get(it, 0):,} | "
                     + " | ".join(cell(res[t]) for t in terrains) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    cfg = parse_config(TeacherCurveConfig, argv, prog=PROG)
    torch.set_num_threads(cfg.nthread)  # the teachers' networks too: no oversubscribed cores
    try:
        cache = build(cfg)
        if cfg.image:
            render(cache, Path(cfg.run), Path(cfg.image))
    except (OSError, ValueError) as e:
        raise SystemExit(f"{PROG}: error: {e}") from None
    print(table(cache, Path(cfg.run)))
    if cfg.image:
        print(f"image: {cfg.image}")


if __name__ == "__main__":
    main()
