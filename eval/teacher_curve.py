"""Progress of an ``msta-train-teacher`` run at fixed terrains: survival vs environment steps.

    python -m msta.eval.teacher_curve --run=outputs/teacher --image=outputs/teacher/curve.png

The curriculum's own survival (``curve.json``) mixes levels that move with the policy, so a
run's progress is measured here on fixed tiles instead: the snapshots the run kept
(``snapshots/iter_<n>/``, ``--ppo.snapshot_interval``; ``--every`` thins them), the run's
starting point (``init/`` or ``warmstart/``) and the gait controller each walk
``--episodes`` episodes of ``--episode_length_s`` per terrain type at ``--level`` (the
harness of ``msta.eval.teacher_report``: terrain curriculum off, randomization and observation
noise on, seed 0; 95 % Wilson intervals), each giving its survival and its mean velocity error
|v_xy - cmd_xy| (m/s): a snapshot that survives by walking slower than the command shows it
there. Results are cached in ``<run>/curve_eval.json``, one cache per setting, each entry
with the evaluated checkpoint's content revision: re-running evaluates only snapshots that
are new or whose files changed. The image has two
panels: survival per terrain type vs environment steps (PPO's start at 0 steps, the gait
controller as dashed lines), and from ``curve.json`` the curriculum's mean level and the
chance of a full episode at its fall rate. The last line names the snapshot whose worst
margin to the gait controller over the terrain types is highest (ties: the higher mean
survival, then the lower mean velocity error).
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from pathlib import Path

import torch
from tqdm import tqdm

from msta.collect.sim.env_config import load_sim_robot
from msta.collect.sim.terrain import TERRAIN_TYPES
from msta.data.checks import check_at_least
from msta.data.cli import parse_config
from msta.data.robot import LEGACY_ROBOT
from msta.eval.intervals import wilson_interval
from msta.eval.teacher_report import TeacherReportConfig, evaluate, parse_levels
from msta.policies.teacher.config import TeacherConfig, teacher_revision

PROG = "python -m msta.eval.teacher_curve"
_SNAP = re.compile(r"^iter_(\d+)$")
GAIT, START = "gait controller", "start"


@dataclass
class TeacherCurveConfig:
    """Args:
        run: an msta-train-teacher output directory (curve.json, snapshots/, init/ or
            warmstart/).
        robot: the simulated robot, the one every teacher is built for: a shipped robot's
            name (a1, go1) or a spec file's path (docs/robots.md); the run's teacher was
            trained on one robot (its ``--env.robot``), name that one.
        terrains: comma-separated terrain types evaluated at ``level``.
        level: the terrain level of every evaluated tile.
        episodes: episodes per terrain type and checkpoint (rounded up to a multiple of
            envs_per_tile, as msta.eval.teacher_report runs them).
        envs_per_tile: robots per tile (each runs episodes / envs_per_tile episodes).
        episode_length_s: episode length (s); 20 is the length of docs/teacher_quality.md.
        nthread: MuJoCo rollout threads and torch threads.
        every: evaluate one snapshot per this many iterations (the first at or after each
            multiple) and the newest one; 0: every snapshot.
        image: the PNG to write ('' skips it).
        progress: a progress bar over checkpoints.
    """

    run: str = "outputs/teacher"
    robot: str = LEGACY_ROBOT
    terrains: str = "stairs_up,stairs_down,discrete"
    level: int = 4
    episodes: int = 50
    envs_per_tile: int = 25
    episode_length_s: float = 20.0
    nthread: int = 2
    every: int = 0
    image: str = "outputs/teacher/curve.png"
    progress: bool = True

    def __post_init__(self) -> None:
        load_sim_robot(self.robot, "robot")  # a bad robot: one line, before anything runs
        check_at_least(self, 1, "episodes", "envs_per_tile", "nthread")
        check_at_least(self, 0, "every")
        parse_levels(str(self.level))
        names = [t.strip() for t in self.terrains.split(",") if t.strip()]
        if not names:
            raise ValueError("--terrains: name at least one terrain type")
        for t in names:
            if t not in TERRAIN_TYPES:
                raise ValueError(f"unknown terrain {t!r}; known terrains: {list(TERRAIN_TYPES)}")
        self.terrains = ",".join(names)
        self.envs_per_tile = min(self.envs_per_tile, self.episodes)
        if not (Path(self.run) / "curve.json").is_file():
            raise ValueError(f"--run={self.run}: no curve.json (not an msta-train-teacher "
                             "output directory, or no PPO chunk finished yet)")

    @property
    def episodes_run(self) -> int:
        """Episodes per tile that msta.eval.teacher_report actually runs."""
        return self.envs_per_tile * math.ceil(self.episodes / self.envs_per_tile)


def snapshots(run: Path) -> list[tuple[int, Path]]:
    """(iteration, directory) of every kept snapshot, in order."""
    found = [(int(m.group(1)), p) for p in (run / "snapshots").glob("iter_*")
             if (m := _SNAP.match(p.name)) and (p / "model.safetensors").is_file()]
    return sorted(found)


def thin(found: list[tuple[int, Path]], every: int) -> list[tuple[int, Path]]:
    """The first snapshot at or after each multiple of ``every``, and the newest one."""
    if not every or not found:
        return found
    kept, last_bucket = [], -1
    for it, path in found:
        if it // every > last_bucket:
            kept.append((it, path))
            last_bucket = it // every
    return kept if kept[-1] == found[-1] else [*kept, found[-1]]


def start_teacher(run: Path) -> TeacherConfig | None:
    """The checkpoint PPO started from: ``init/`` (a copy of ``--init_from``) or the run's
    own warm start."""
    for sub in ("init", "warmstart"):
        if (run / sub / "model.safetensors").is_file():
            return TeacherConfig(type="rma", path=str(run / sub))
    return None


def figures_of(teacher: TeacherConfig, cfg: TeacherCurveConfig) -> dict[str, dict[str, float]]:
    """One teacher at ``cfg.level``: ``survival`` and ``lin_err`` (mean |v_xy - cmd_xy|, m/s),
    each per terrain type."""
    rc = TeacherReportConfig(teacher=teacher, robot=cfg.robot, episodes=cfg.episodes,
                             envs_per_tile=cfg.envs_per_tile, terrains=cfg.terrains,
                             levels=str(cfg.level), episode_length_s=cfg.episode_length_s,
                             nthread=cfg.nthread, report="-", image="", progress=False)
    stats = evaluate(rc)
    return {key: {t: float(stats[(t, cfg.level)][key]) for t in rc.terrain_list}
            for key in ("survival", "lin_err")}


def env_steps_at(run: Path) -> dict[int, int]:
    """Environment steps at the end of each curve.json row's iteration."""
    rows = json.loads((run / "curve.json").read_text())
    return {int(r["iteration"]): int(r["env_steps"]) for r in rows}


def settings_key(cfg: TeacherCurveConfig) -> dict:
    """What a cache of ``curve_eval.json`` was evaluated at (the robot only when not the A1,
    so that caches written before the option existed stay valid)."""
    key = {"terrains": cfg.terrains, "level": cfg.level, "episodes": cfg.episodes_run,
           "episode_length_s": cfg.episode_length_s}
    return key if cfg.robot == LEGACY_ROBOT else {**key, "robot": cfg.robot}


def build(cfg: TeacherCurveConfig) -> dict:
    """Evaluate what is not cached yet (new, or whose files changed); return this setting's
    cache: ``settings``, ``references`` and ``snapshots`` (name -> ``revision``,
    ``survival`` and ``lin_err`` per terrain type; caches written before ``lin_err`` was
    recorded lack it). Snapshots whose directory is gone are dropped."""
    run = Path(cfg.run)
    cache_path = run / "curve_eval.json"
    caches = json.loads(cache_path.read_text())["caches"] if cache_path.is_file() else []
    key = settings_key(cfg)
    cache = next((c for c in caches if c["settings"] == key), None)
    if cache is None:
        cache = {"settings": key, "references": {}, "snapshots": {}}
        caches.append(cache)
    found = dict(snapshots(run))
    cache["snapshots"] = {k: v for k, v in cache["snapshots"].items() if int(k) in found}
    wanted: list[tuple[str, str, TeacherConfig]] = [
        ("references", GAIT, TeacherConfig(type="gait"))]
    start = start_teacher(run)
    if start is not None:
        wanted.append(("references", START, start))
    wanted += [("snapshots", str(it), TeacherConfig(type="rma", path=str(path)))
               for it, path in thin(sorted(found.items()), cfg.every)]
    todo = []
    for group, name, teacher in wanted:
        rev = teacher_revision(teacher)
        if cache[group].get(name, {}).get("revision") != rev:
            todo.append((group, name, teacher, rev))
    for group, name, teacher, rev in tqdm(todo, desc="checkpoints", disable=not cfg.progress):
        cache[group][name] = {"revision": rev, **figures_of(teacher, cfg)}
        cache_path.write_text(json.dumps({"caches": caches}, indent=1) + "\n")
    cache_path.write_text(json.dumps({"caches": caches}, indent=1) + "\n")  # drops too
    return cache


def _interval(p: float, n: int) -> tuple[float, float]:
    lo, hi = wilson_interval(p, n)
    return min(lo, p), max(hi, p)   # rounding may put p a hair outside its own interval


def render(cache: dict, run: Path, image: Path) -> None:
    import matplotlib  # lazy: matplotlib (~0.5 s) loads only when a picture is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # lazy: matplotlib (~0.5 s) loads only when a picture is drawn

    steps = env_steps_at(run)
    s = cache["settings"]
    n = s["episodes"]
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(12, 4.2))
    its = sorted(int(i) for i in cache["snapshots"])
    refs = cache["references"]
    for k, t in enumerate(s["terrains"].split(",")):
        color = f"C{k}"
        xs = [steps.get(i, float("nan")) / 1e6 for i in its]
        ys = [cache["snapshots"][str(i)]["survival"][t] for i in its]
        if START in refs:  # PPO's starting point sits at 0 steps
            xs, ys = [0.0, *xs], [refs[START]["survival"][t], *ys]
        bounds = [_interval(y, n) for y in ys]
        ax.errorbar(xs, ys, yerr=[[y - lo for y, (lo, _) in zip(ys, bounds, strict=True)],
                                  [hi - y for y, (_, hi) in zip(ys, bounds, strict=True)]],
                    fmt="o-", color=color, capsize=2, label=t)
        if GAIT in refs:
            ax.axhline(refs[GAIT]["survival"][t], color=color, ls="--", lw=1)
    ax.set_xlim(left=-0.05 * max([steps.get(i, 0) / 1e6 for i in its] + [1.0]))
    ax.set_xlabel("environment steps (millions)")
    ax.set_ylabel(f"survival, level {s['level']}")
    ax.set_title(f"fixed tiles: {n} episodes of {s['episode_length_s']:g} s per point, 95 % "
                 "Wilson intervals\n(0 steps: PPO's start; dashed: the gait controller)",
                 fontsize=9)
    ax.set_ylim(0, 1)
    ax.legend(fontsize=8)
    rows = json.loads((run / "curve.json").read_text())
    x = [r["env_steps"] / 1e6 for r in rows]
    # curve.json rows written before the figure was renamed call it survival_per_episode
    bx.plot(x, [r.get("full_episode_at_fall_rate", r.get("survival_per_episode")) for r in rows],
            color="C0", lw=1, label="full episode at the fall rate (curriculum)")
    bx.set_ylim(0, 1)
    bx.set_xlabel("environment steps (millions)")
    bx.set_ylabel("full episode at the fall rate")
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


def best_snapshot(cache: dict) -> tuple[str, float] | None:
    """The snapshot whose worst margin to the gait controller over the terrain types is
    highest, with that margin; ties go to the higher mean survival, then to the lower mean
    velocity error (where recorded), then to the newer snapshot."""
    gait = cache["references"].get(GAIT)
    if gait is None or not cache["snapshots"]:
        return None
    snaps = cache["snapshots"]
    margins = {k: min(v["survival"][t] - gait["survival"][t] for t in gait["survival"])
               for k, v in snaps.items()}

    def mean(values: dict) -> float:
        return round(sum(values.values()) / len(values), 6)  # 6 digits: sums tie as reals

    def rank(k: str) -> tuple:
        err = mean(snaps[k]["lin_err"]) if "lin_err" in snaps[k] else math.inf
        return round(margins[k], 6), mean(snaps[k]["survival"]), -err, int(k)

    best = max(margins, key=rank)
    return best, margins[best]


def table(cache: dict, run: Path) -> str:
    """A Markdown table of the cache: one row per checkpoint, survival with its 95 % Wilson
    interval over the episodes, then the mean velocity error (m/s) where recorded."""
    steps = env_steps_at(run)
    terrains = cache["settings"]["terrains"].split(",")
    n = cache["settings"]["episodes"]

    def cell(res: dict, t: str) -> str:
        p = res["survival"][t]
        lo, hi = _interval(p, n)
        err = f", {res['lin_err'][t]:.2f} m/s" if "lin_err" in res else ""
        return f"{p:.2f} ({lo:.2f}-{hi:.2f}){err}"

    def cells(res: dict) -> str:
        return " | ".join(cell(res, t) for t in terrains)

    lines = ["| checkpoint | env steps | " + " | ".join(f"{t}: survival, abs(v err)"
                                                     for t in terrains) + " |",
             "|---|---|" + "---|" * len(terrains)]
    for name, res in cache["references"].items():
        lines.append(f"| {name} | - | {cells(res)} |")
    for it in sorted(int(i) for i in cache["snapshots"]):
        st = f"{steps[it]:,}" if it in steps else "-"
        lines.append(f"| iteration {it} | {st} | {cells(cache['snapshots'][str(it)])} |")
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
    best = best_snapshot(cache)
    if best is not None:
        errs = cache["snapshots"][best[0]].get("lin_err")
        err = f", mean abs(v err) {sum(errs.values()) / len(errs):.2f} m/s" if errs else ""
        print(f"best snapshot: iter_{best[0]} (worst margin to the gait controller "
              f"{best[1]:+.2f} at level {cfg.level}{err}; {cfg.episodes_run} episodes per "
              "point)")


if __name__ == "__main__":
    main()
