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

Episodes carry the per-sensor columns only; the writer adds ``observation.state`` and
``observation.environment_state`` for stock LeRobot policies (:mod:`msta.data.derived`).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from msta.collect.ray_pool import RayOptions, check_ray_options, shared_pool
from msta.collect.rollout import Step, as_policy, rollout
from msta.collect.sim.env import EnvConfig, QuadrupedEnv, StepResult
from msta.collect.sim.env_config import check_sizes
from msta.collect.sim.terrain import TerrainConfig
from msta.data import cli, layout
from msta.data.errors import DatasetError, DirectoryLockedError
from msta.data.features import NON_SENSOR_FEATURES, load_info
from msta.data.layout import LOCK_NAME
from msta.data.robot import NUM_JOINTS
from msta.data.sensors import DEFAULT_RECORDED, EXTENSION_SENSORS, SENSORS
from msta.data.writer import DatasetWriter
from msta.policies.teacher.config import TeacherConfig, build_teacher, teacher_revision


class EpisodeRecorder:
    """Per-environment buffers of the running episodes, emitted when an episode ends.

    Args:
        num_envs: environments recorded.
        max_steps: longest episode (the env's time limit in control steps).
        sensors: registry sensors to record.
    """

    def __init__(self, num_envs: int, max_steps: int, sensors: tuple[str, ...]) -> None:
        dims = {SENSORS[s].column: SENSORS[s].dim for s in sensors}
        dims.update({k: int(np.prod(v["shape"])) for k, v in NON_SENSOR_FEATURES.items()})
        self.sensors = sensors
        self.buf = {k: np.zeros((num_envs, max_steps, d),
                                dtype=bool if k == "next.done" else np.float32)
                    for k, d in dims.items()}
        self.ptr = np.zeros(num_envs, dtype=np.int64)
        self.level = np.zeros(num_envs, dtype=np.int64)
        self.type_idx = np.zeros(num_envs, dtype=np.int64)

    def start(self, ids: np.ndarray, type_idx: np.ndarray, level: np.ndarray) -> None:
        self.ptr[ids] = 0
        self.type_idx[ids] = type_idx[ids]
        self.level[ids] = level[ids]

    def add(self, obs: dict[str, np.ndarray], label: np.ndarray, executed: np.ndarray,
            res: StepResult) -> None:
        rows = np.arange(len(self.ptr))
        p = np.minimum(self.ptr, self.buf["action"].shape[1] - 1)
        for s in self.sensors:
            self.buf[SENSORS[s].column][rows, p] = obs[s]
        self.buf["action"][rows, p] = label
        self.buf["executed_action"][rows, p] = executed
        self.buf["next.reward"][rows, p, 0] = res.reward
        self.buf["next.lin_vel_tracking"][rows, p, 0] = res.metrics["lin_vel_tracking"]
        self.buf["next.ang_vel_tracking"][rows, p, 0] = res.metrics["ang_vel_tracking"]
        self.buf["next.done"][rows, p, 0] = res.done
        self.ptr += 1

    def take(self, i: int) -> dict[str, np.ndarray]:
        """Copy out env ``i``'s finished episode."""
        n = int(self.ptr[i])
        return {k: v[i, :n].copy() for k, v in self.buf.items()}


class LabelledActor:
    """``actor`` drives; ``label`` (default: the actor) acts on the same observation right
    after it, once per step, and its action is the recorded ``action`` label
    (``label_action``; the actor's own action is ``actor_action``). With ``beta`` > 0 every
    environment executes the label's action instead with probability ``beta`` per step
    (DAgger mixing, msta-correct). With ``noise`` > 0, Gaussian noise is added to every
    executed action while the label stays clean (DART: the robot visits states off the
    driver's own path, each labelled with the action that returns to it).

    Args:
        actor: the policy that drives (act/reset or a callable).
        label: the labelling policy (a teacher), or None.
        beta: probability that an environment executes the label's action in a step.
        seed: seeds the per-step coin flips and the noise.
        noise: std of the noise on executed actions (action units).
    """

    def __init__(self, actor: Any, label: Any = None, beta: float = 0.0, seed: int = 0,
                 noise: float = 0.0) -> None:
        if noise < 0:
            raise ValueError(f"noise={noise} must be >= 0")
        self._act, self._reset = as_policy(actor)
        self._lab_act, self._lab_reset = (as_policy(label) if label is not None
                                          else (None, lambda ids: None))
        self.beta, self.noise, self.rng = beta, noise, np.random.default_rng(seed)
        self.label_action = np.zeros((0, NUM_JOINTS), dtype=np.float32)
        self.actor_action = self.label_action  # the actor's own answer, before any mixing
        self.label_share = [0, 0]  # label-executed env steps, all env steps

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        return self._perturb(self._mix(obs))

    def _mix(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        executed = self.actor_action = np.asarray(self._act(obs), dtype=np.float32)  # (N, 12)
        if self._lab_act is None:
            self.label_action = executed
            return executed
        self.label_action = np.asarray(self._lab_act(obs), dtype=np.float32)
        if self.beta <= 0:  # the usual case: the actor drives, no coin flips needed
            self.label_share[1] += len(executed)
            return executed
        use = self.rng.random(len(executed)) < self.beta          # (N,)
        self.label_share[0] += int(use.sum())
        self.label_share[1] += len(use)
        return np.where(use[:, None], self.label_action, executed)

    def _perturb(self, executed: np.ndarray) -> np.ndarray:
        if self.noise <= 0:
            return executed
        return executed + self.rng.normal(0.0, self.noise, executed.shape).astype(np.float32)

    def reset(self, ids: np.ndarray) -> None:
        self._reset(ids)
        self._lab_reset(ids)


def record_rollouts(env: QuadrupedEnv, actor: Any, episodes: int,
                    write: Callable[[dict[str, np.ndarray], int, int], None],
                    sensors: tuple[str, ...] | None = None, label: Any = None,
                    progress: bool = True, horizon: int | None = None) -> int:
    """Run ``actor`` until ``episodes`` episodes have finished, handing each to ``write``
    (:func:`msta.collect.rollout.rollout` with a recording hook); or, with ``horizon``, for
    exactly ``horizon`` control steps, keeping every frame.

    Args:
        env: the simulator (reset here).
        actor: the policy that drives (act/reset or a callable), or a
            :class:`LabelledActor` (which then also labels; ``label`` must be None).
        episodes: how many finished episodes to emit (ignored with ``horizon``).
        write: called as ``write(frames, type_idx, level)`` per finished episode.
        sensors: registry sensors to record (default: all but the extension sensors).
        label: the policy whose action is stored as the ``action`` label (default: actor).
        horizon: run this many control steps instead; every episode that ends is emitted,
            and at the end so is every episode still running, cut there (its last
            ``next.done`` false, as after a time limit). The emitted states then follow the
            policy's own state distribution: the first ``episodes`` to finish are the short
            ones (falls), and the steps of the unfinished ones would be simulated for
            nothing.
    Returns:
        environment steps taken.
    """
    sensors = tuple(sensors or DEFAULT_RECORDED)
    if horizon is not None and horizon <= 0:
        raise ValueError(f"horizon={horizon} must be > 0")
    env.reset()
    if episodes <= 0:
        return 0
    policy = actor if isinstance(actor, LabelledActor) and label is None \
        else LabelledActor(actor, label)
    rec = EpisodeRecorder(env.num_envs, env.max_steps, sensors)
    rec.start(np.arange(env.num_envs), env.type_idx, env.level)
    done_count = 0
    bar = _Progress(horizon, episodes, progress, env.num_envs)

    def on_step(step: Step) -> bool:
        nonlocal done_count
        rec.add(step.obs, policy.label_action, step.action, step.res)
        ended = np.flatnonzero(step.res.done)
        for i in ended:
            if horizon or done_count < episodes:
                write(rec.take(i), int(rec.type_idx[i]), int(rec.level[i]))
                done_count += 1
        if len(ended):
            rec.start(ended, env.type_idx, env.level)
        bar.update(step.t, len(ended))
        if horizon:
            return step.t + 1 >= horizon
        return done_count >= episodes

    steps = rollout(env, policy, on_step) * env.num_envs
    if horizon:  # the episodes still running, cut at the horizon
        for i in np.flatnonzero(rec.ptr > 0):
            write(rec.take(i), int(rec.type_idx[i]), int(rec.level[i]))
    bar.bar.close()
    return steps


class _Progress:
    """:func:`record_rollouts`' progress bar: control steps (with ``horizon``) or finished
    episodes, with the simulated frames per second."""

    def __init__(self, horizon: int | None, episodes: int, enabled: bool, num_envs: int) -> None:
        self.bar = (tqdm(total=horizon, disable=not enabled, unit="step", desc="control steps")
                    if horizon else
                    tqdm(total=episodes, disable=not enabled, unit="ep", desc="episodes"))
        self.horizon, self.num_envs, self.t0 = horizon, num_envs, time.time()

    def update(self, t: int, ended: int) -> None:
        """After control step ``t`` (0-based), in which ``ended`` episodes ended."""
        if self.horizon:
            self.bar.update(1)
        elif ended:
            self.bar.update(min(ended, self.bar.total - self.bar.n))
        rate = (t + 1) * self.num_envs / max(time.time() - self.t0, 1e-9)
        self.bar.set_postfix(frames_per_s=f"{rate:,.0f}")


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
            student input the paper's students do not read); a new dataset only (a resumed
            one keeps its own sensors).
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
    progress: bool = True

    @property
    def extra(self) -> tuple[str, ...]:
        """``extra_sensors`` as registry names."""
        return tuple(s.strip() for s in self.extra_sensors.split(",") if s.strip())

    def __post_init__(self) -> None:
        for name in self.extra:
            if name not in SENSORS or not SENSORS[name].extension:
                raise ValueError(f"extra_sensors: {name!r} is not an extension sensor (the others "
                                 f"are always recorded); extension sensors: "
                                 f"{', '.join(EXTENSION_SENSORS)}")
        cli.check_number("action_noise", self.action_noise, 0)
        check_ray_options(self.workers, self.ray_address)
        cli.check_at_least(self, 1, "episodes", "flush_every_frames")
        check_sizes(self.num_envs, self.episode_length_s)
        terrain = self.env.terrain
        default = TerrainConfig.__dataclass_fields__["max_init_level"].default
        if terrain.max_init_level >= terrain.num_levels and terrain.max_init_level != default:
            raise ValueError(f"env.terrain.max_init_level={terrain.max_init_level}: the terrain "
                             f"has levels 0..{terrain.num_levels - 1}")


def _existing_dataset(cfg: CollectConfig, root: Path) -> DatasetWriter | None:
    """The verified writer of the dataset at ``root`` to extend, or None for a new one."""
    if layout.is_dataset_root(root):
        have = int(load_info(root)["total_episodes"])
        if cfg.resume or have == 0:  # an empty dataset is what a failed first run leaves
            return DatasetWriter.open(root, flush_every_frames=cfg.flush_every_frames)
        raise FileExistsError(f"{root} already holds a dataset ({have} episodes); pass "
                              "--resume=true to extend it or choose another --root")
    if root.exists() and any(p for p in root.iterdir() if p.name != LOCK_NAME):
        raise FileExistsError(f"{root} is not empty and holds no dataset (no meta/info.json); "
                              "choose another --root")
    return None


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
        teacher = build_teacher(cfg.teacher)  # teacher and simulator before any file
        revision = teacher_revision(cfg.teacher)
        env = QuadrupedEnv(env_cfg)
        if cfg.workers:  # the workers too: a cluster that does not answer creates no file
            shared_pool(cfg.workers, cfg.ray_address)
        if writer is None:
            writer = DatasetWriter.create(root, cfg.repo_id,
                                          sensors=(*DEFAULT_RECORDED, *cfg.extra),
                                          flush_every_frames=cfg.flush_every_frames)
    except BaseException:
        if writer is not None:
            writer.close()
        raise
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
            from msta.collect.distributed import collect_on_workers

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
            ValueError) as e:
        raise SystemExit(f"msta-collect: error: {e}") from None


if __name__ == "__main__":
    main()
