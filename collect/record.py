"""``msta-collect``: roll a teacher in the batched simulator and record a LeRobot v3.0 dataset.

    msta-collect --teacher.type=gait --episodes=2000 --num_envs=256 \\
        --repo_id=local/a1_teacher --root=outputs/datasets/a1_teacher
    msta-collect ... --resume=true      # continue a killed run up to --episodes

Every finished episode (fall or time limit) is written with its provenance; episodes still
running when the requested count is reached are dropped. The writer flushes complete
Parquet files atomically, so a killed collector loses at most the episodes in flight.

Nothing is created before the configuration, the teacher and the simulator are checked; an
existing dataset is verified (every committed file against the sha256 recorded at commit)
before it is extended, and a damaged one is refused with one line naming the file. A
dataset left empty by a run that recorded nothing is reused by the next run.

The dataset records the simulated robot (``--env.robot``'s name, ``meta/msta.json``'s
``robot``); ``--resume`` on a dataset of another robot is refused in one line.

Episodes carry the per-sensor columns only; the writer adds ``observation.state`` and
``observation.environment_state`` for stock LeRobot policies (:mod:`msta.data.derived`).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from msta.collect.ray_pool import RayOptions, check_ray_options, shared_pool
from msta.collect.ray_record import collect_on_workers
from msta.collect.recorder import LabelledActor, record_rollouts, recorded_sensors
from msta.collect.sim.env import QuadrupedEnv
from msta.collect.sim.env_config import EnvConfig, check_sizes
from msta.collect.sim.terrain import TerrainConfig
from msta.data import checks, cli, layout
from msta.data.errors import DatasetError, DirectoryLockedError
from msta.data.features import load_info
from msta.data.layout import LOCK_NAME
from msta.data.lerobot_edits import UNKNOWN
from msta.data.msta_json import (
    ROBOT,
    add_recording,
    check_robot,
    differences,
    meta_robot,
    recorded_settings,
)
from msta.policies.teacher.config import TeacherConfig, build_teacher, teacher_revision

if TYPE_CHECKING:
    from msta.data.writer import DatasetWriter


@dataclass
class CollectConfig(RayOptions):
    """Args:
        teacher: which teacher acts and labels (default: the shipped PPO teacher, rma_ppo;
            ``--teacher.type=gait``: the gait controller).
        episodes: total finished episodes wanted in the dataset (with ``resume``, counting
            the ones already there).
        num_envs: environments simulated together.
        repo_id: dataset id recorded in the metadata (``user/name``).
        root: dataset directory.
        resume: append to an existing dataset at ``root`` until it holds ``episodes``.
        seed: seeds the simulator (a resumed run shifts it by the episodes already present;
            with ``workers``: episode k's own streams are keyed by (seed, k)).
        episode_length_s: episode time limit (s).
        env: simulator options (terrain mix and levels, randomization, noise, ...).
        flush_every_frames: frames buffered before they are written (a killed run loses at
            most these plus the episodes in flight).
        action_noise: std of Gaussian noise added to every action the teacher executes (its
            clean action stays the ``action`` label; ``executed_action`` holds what ran):
            DART, states off the teacher's path labelled with the way back, recorded at the
            teacher's speed instead of a student's. 0 = the teacher's own path.
        extra_sensors: extension sensors to record too, a comma list (``height_map``: a
            student input the paper's students do not read), each one the robot offers; a
            new dataset only (a resumed one keeps its own sensors). Without it a dataset
            records the default sensors the robot offers (on the A1 all of them).
        allow_mixed_settings: let ``resume`` append episodes recorded with other settings
            than the dataset's (teacher, its revision, episode length, terrains, levels,
            action noise); without it a difference is refused, each one named. The settings
            of each session are kept in ``meta/msta.json`` (``recordings``).
        progress: show a progress bar.
    """

    teacher: TeacherConfig = field(default_factory=TeacherConfig)
    episodes: int = 200
    num_envs: int = 64
    repo_id: str = "local/a1_teacher"
    root: str = "outputs/datasets/a1_teacher"
    resume: bool = False
    seed: int = 0
    episode_length_s: float = 20.0
    env: EnvConfig = field(default_factory=EnvConfig)
    flush_every_frames: int = 50_000
    action_noise: float = 0.0
    extra_sensors: str = ""
    allow_mixed_settings: bool = False
    progress: bool = True

    @property
    def extra(self) -> tuple[str, ...]:
        """``extra_sensors`` as registry names."""
        return tuple(s.strip() for s in self.extra_sensors.split(",") if s.strip())

    def __post_init__(self) -> None:
        recorded_sensors(self.env.robot_description, self.extra)  # one line if not offered
        self.teacher = self.teacher.on_robot(self.env.robot, "msta-collect", "--env.robot")
        checks.check_number("action_noise", self.action_noise, 0)
        check_ray_options(self.workers, self.ray_address)
        checks.check_at_least(self, 1, "episodes", "flush_every_frames")
        check_sizes(self.num_envs, self.episode_length_s)
        terrain = self.env.terrain
        default = TerrainConfig.__dataclass_fields__["max_init_level"].default
        if terrain.max_init_level >= terrain.num_levels and terrain.max_init_level != default:
            raise ValueError(f"env.terrain.max_init_level={terrain.max_init_level}: the terrain "
                             f"has levels 0..{terrain.num_levels - 1}")


def _existing_dataset(cfg: CollectConfig, root: Path) -> DatasetWriter | None:
    """The verified writer of the dataset at ``root`` to extend, or None for a new one."""
    # lazy: pandas and pyarrow load after the command line is parsed (--help at once)
    from msta.data.writer import DatasetWriter

    if layout.is_dataset_root(root):
        have = int(load_info(root)["total_episodes"])
        if cfg.resume or have == 0:  # an empty dataset is what a failed first run leaves
            return DatasetWriter.open(root, flush_every_frames=cfg.flush_every_frames)
        raise FileExistsError(f"{root} already holds a dataset ({have} episodes); pass "
                              "--resume=true to extend it or choose another --root")
    if root.exists() and not root.is_dir():
        raise NotADirectoryError(f"--root={root} is not a folder; choose a folder for the "
                                 "dataset")
    if root.exists() and any(p for p in root.iterdir() if p.name != LOCK_NAME):
        raise FileExistsError(f"{root} is not empty and holds no dataset (no meta/info.json); "
                              "choose another --root")
    return None


def recording_settings(cfg: CollectConfig, revision: str) -> dict[str, Any]:
    """What a session records with, as ``meta/msta.json`` keeps it (msta.data.msta_json)."""
    terrain = cfg.env.terrain
    return {"teacher": cfg.teacher.type, "teacher_revision": revision,
            "episode_length_s": float(cfg.episode_length_s), "terrains": list(terrain.types),
            "terrain_levels": int(terrain.num_levels), "curriculum": bool(terrain.curriculum),
            "max_init_level": int(terrain.max_init_level),
            "action_noise": float(cfg.action_noise)}


def check_same_settings(cfg: CollectConfig, writer: DatasetWriter,
                        settings: dict[str, Any]) -> None:
    """``--resume`` with other settings than the dataset's: one line naming each difference,
    unless ``allow_mixed_settings``. A dataset that records no settings is compared on its
    episodes' teacher."""
    have = writer.num_episodes
    recorded = recorded_settings(writer.msta_meta, have)
    if recorded is None:
        from msta.data.windows import load_episode_table  # lazy: pandas, an old dataset only

        policies = set(load_episode_table(writer.root)["provenance/policy"]) - {UNKNOWN}
        recorded = {"teacher": policies.pop()} if len(policies) == 1 else {}
        settings = {k: v for k, v in settings.items() if k in recorded}
    diffs = differences(recorded, settings)
    if diffs and not cfg.allow_mixed_settings:
        raise ValueError(
            f"{writer.root} was recorded with other settings ({'; '.join(diffs)}): its "
            f"{have} episodes would be mixed with new ones; give the dataset's settings, "
            "choose another --root, or pass --allow_mixed_settings=true (each session's "
            "settings are kept in meta/msta.json)")


def check_same_robot(writer: DatasetWriter, robot: str) -> None:
    """``--resume`` on a dataset of another robot than ``robot`` (the name of the one
    ``--env.robot`` simulates): one line naming both (:func:`msta.data.msta_json.check_robot`).
    A dataset that holds no episode yet takes the robot of the run that fills it."""
    if writer.num_episodes:
        check_robot(meta_robot(writer.msta_meta), robot, str(writer.root), "--env.robot")
    elif meta_robot(writer.msta_meta) != robot:
        writer.msta_meta[ROBOT] = writer.info["robot_type"] = robot
        writer.meta_changed()


def collect(cfg: CollectConfig) -> Path:
    """Record (or extend) the dataset; returns its root (checks: module docstring)."""
    root = Path(cfg.root)
    writer = _existing_dataset(cfg, root)
    have = writer.num_episodes if writer is not None else 0
    try:
        todo = cfg.episodes - have
        if todo <= 0:
            print(f"{root}: already holds {have} episodes (>= {cfg.episodes}); nothing to do")
            if writer is not None:
                writer.close()  # its lock too: the caller may append or push in this process
            return root
        seed = cfg.seed if cfg.workers else cfg.seed + have  # workers: seeds per episode
        env_cfg = cfg.env
        env_cfg.num_envs, env_cfg.seed, env_cfg.episode_length_s = (
            cfg.num_envs, seed, cfg.episode_length_s)
        revision = teacher_revision(cfg.teacher, robot := cfg.env.teacher_robot)
        settings = recording_settings(cfg, revision)
        if writer is not None:
            check_same_robot(writer, robot.name)
        if writer is not None and have:
            check_same_settings(cfg, writer, settings)
        teacher = build_teacher(cfg.teacher, robot)  # teacher and simulator before any file
        env = QuadrupedEnv(env_cfg)
        if cfg.workers:  # the workers too: a cluster that does not answer creates no file
            shared_pool(cfg.workers, cfg.ray_address)
        if writer is None:
            from msta.data.writer import DatasetWriter  # lazy: pandas and pyarrow (--help)

            writer = DatasetWriter.create(root, cfg.repo_id, robot=env.robot.name,
                                          sensors=recorded_sensors(env.robot, cfg.extra),
                                          flush_every_frames=cfg.flush_every_frames)
    except BaseException:
        if writer is not None:
            writer.close()
        raise
    if add_recording(writer.msta_meta, have, settings):
        writer.meta_changed()
    with writer:
        types = env.cfg.terrain.types

        def write(frames: dict[str, np.ndarray], type_idx: int, level: int) -> None:
            writer.add_episode(frames, {
                "terrain": types[type_idx], "terrain_level": level, "source": "teacher",
                "round": 0, "policy": cfg.teacher.type, "policy_revision": revision,
                "seed": seed})

        t0 = time.time()
        sensors = tuple(writer.msta_meta["sensors"])
        if cfg.workers:  # Ray workers simulate, this process commits (docs/scale.md)

            steps = collect_on_workers(cfg, write, have, sensors)
        else:
            driver = LabelledActor(teacher, noise=cfg.action_noise, seed=seed)
            steps = record_rollouts(env, driver, todo, write, progress=cfg.progress,
                                    sensors=sensors)
        print(f"recorded {todo} episodes ({steps:,} env steps simulated, "
              f"{steps / (time.time() - t0):,.0f}/s) -> {root} ({writer.num_episodes} episodes, "
              f"{writer.num_frames:,} frames)")
    return root


def parse_config(argv: Sequence[str] | None = None, prog: str = "msta-collect") -> CollectConfig:
    """:func:`msta.data.cli.parse_config`: an unknown option or an invalid value exits 2 with
    one line naming the field and the reason."""
    return cli.parse_config(CollectConfig, argv, prog, aliases={
        "env.num_envs": "num_envs", "env.seed": "seed", "env.episode_length_s": "episode_length_s"})


def main(argv: Sequence[str] | None = None) -> None:
    """Entry point of ``msta-collect``: errors end in one line naming the file or field."""
    cfg = parse_config(argv)
    try:
        collect(cfg)
    except (DatasetError, DirectoryLockedError, FileExistsError, FileNotFoundError,
            NotADirectoryError, PermissionError, ValueError) as e:
        raise SystemExit(f"msta-collect: error: {e}") from None


if __name__ == "__main__":
    main()
