"""Recording on Ray workers (``--workers``): blocks of episode slots with their own seeds.

Slot k of a run is one environment whose every random draw (spawn, domain-randomization
variant, commands, latency, pushes, observation noise) comes from its own stream keyed by
(run seed, k) (``QuadrupedEnv.reset(streams=...)``), on a tile (terrain type, level) drawn
from a generator keyed the same way (:func:`slot_tiles`; the level stays for the run, no
curriculum). A block of slots is simulated together in one batched simulator by one worker
(:func:`record_block`); its policies are seeded by (run seed, block index)
(:func:`msta.collect.ray_pool.block_seed`). The blocks are fixed by the run's episode count and
``--num_envs`` (:func:`msta.collect.ray_pool.plan_blocks`), so the episodes, and the order the
committer writes them in (block by block, slot by slot), are the same for any worker count.

Two ways to fill a slot: its first episode (msta-collect; msta-correct without
``keep_unfinished``), or every episode in a fixed number of control steps, the one still
running then cut there (msta-correct's ``keep_unfinished``).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from msta.collect.ray_pool import (
    RayPool,
    block_seed,
    cached,
    exit_if_asked,
    plan_blocks,
    shared_pool,
)
from msta.collect.recorder import EpisodeBar, EpisodeRecorder, LabelledActor
from msta.collect.rollout import Step, rollout
from msta.collect.sim.env import QuadrupedEnv
from msta.collect.sim.env_config import EnvConfig
from msta.data.robot import RobotDescription
from msta.policies.teacher.config import build_teacher

#: Salt of the per-slot tile generators (apart from the simulator's stream salts).
TILE_SALT = 0x711E
#: (frames, terrain type index, level) of one recorded episode.
Episode = tuple[dict[str, np.ndarray], int, int]
#: (block index, slots in the block) -> the actor that drives and labels that block.
ActorFactory = Callable[[int, int], Any]


def slot_tiles(cfg: EnvConfig, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(type_idx, level) of every slot in ``keys``: the type drawn by ``cfg.type_weights``
    (uniform when empty), the level uniform in [0, max_init_level] with the curriculum on
    (as the single-process recording starts), else over every level; each from the
    generator ``default_rng([cfg.seed, TILE_SALT, key])``."""
    t = cfg.terrain
    w = np.asarray(cfg.type_weights or np.ones(len(t.types)), dtype=np.float64)
    top = min(t.max_init_level, t.num_levels - 1) if t.curriculum else t.num_levels - 1
    types, levels = [], []
    for k in np.asarray(keys, dtype=np.int64):
        rng = np.random.default_rng([cfg.seed, TILE_SALT, int(k)])
        types.append(rng.choice(len(t.types), p=w / w.sum()))
        levels.append(rng.integers(0, top + 1))
    return np.asarray(types, dtype=np.int64), np.asarray(levels, dtype=np.int64)


def record_block(env: QuadrupedEnv, actor: Any, block: int, keys: np.ndarray,
                 sensors: tuple[str, ...], horizon: int | None = None
                 ) -> tuple[list[Episode], int]:
    """Simulate one block: environment i is slot ``keys[i]`` (its stream and tile).

    Args:
        env: a simulator of ``len(keys)`` environments, curriculum off, seeded by the run.
        actor: drives and labels (a :class:`~msta.collect.recorder.LabelledActor`, or any policy,
            which then labels itself).
        block: the block's index (the test hook's key).
        keys: (n,) slot indices.
        sensors: registry sensors to record.
        horizon: None: each slot's first episode; else every episode that ends within
            ``horizon`` control steps, and the one still running then, cut there.
    Returns:
        the episodes, slot by slot (each slot's in the order they ran), and the env steps
        simulated.
    """
    n = len(keys)
    env.reset(*slot_tiles(env.cfg, keys), streams=keys)
    policy = actor if isinstance(actor, LabelledActor) else LabelledActor(actor)
    rec = EpisodeRecorder(n, env.max_steps, sensors)
    rec.start(np.arange(n), env.type_idx, env.level)
    out: list[list[Episode]] = [[] for _ in range(n)]
    alive = np.ones(n, dtype=bool)

    def on_step(step: Step) -> bool:
        if step.t == 1:
            exit_if_asked(block)
        rec.add(step.obs, policy.label_action, step.action, step.res)
        ended = np.flatnonzero(step.res.done)
        for i in ended[alive[ended]]:
            out[i].append((rec.take(i), int(rec.type_idx[i]), int(rec.level[i])))
        rec.start(ended, env.type_idx, env.level)
        if horizon is None:
            alive[ended] = False
            return not alive.any()
        return step.t + 1 >= horizon

    steps = rollout(env, policy, on_step, max_steps=horizon or env.max_steps) * n
    if horizon is not None:  # the episodes still running, cut at the horizon
        for i in np.flatnonzero(rec.ptr > 0):
            out[i].append((rec.take(i), int(rec.type_idx[i]), int(rec.level[i])))
    return [e for slot in out for e in slot], steps


@dataclass
class RecordJob:
    """A pool job (:class:`msta.collect.ray_pool.Job`): record blocks of slots.

    Args:
        env: the run's simulator settings (its ``seed`` keys every slot; ``num_envs`` is
            each block's size; the curriculum is turned off, tiles are pinned per slot).
        make_actor: (block index, slots) -> the block's driving and labelling actor.
        sensors: registry sensors to record.
        horizon: :func:`record_block`'s.
    """

    env: EnvConfig
    make_actor: ActorFactory
    sensors: tuple[str, ...]
    horizon: int | None = None

    def sim_config(self, n: int) -> EnvConfig:
        """The block simulator: ``n`` environments, one MuJoCo thread (a worker is one
        CPU), tiles pinned."""
        return replace(self.env, num_envs=n, nthread=1,
                       terrain=replace(self.env.terrain, curriculum=False))

    def setup(self) -> None:
        return None  # the simulators are cached per worker process, by settings

    def run(self, state: None, block: tuple[int, np.ndarray]) -> tuple[list[Episode], int, float]:
        """(episodes, env steps, seconds) of block ``(index, slot keys)``."""
        b, keys = block
        t0 = time.perf_counter()
        sim = self.sim_config(len(keys))
        env = cached(repr(sim), lambda: QuadrupedEnv(sim))
        eps, steps = record_block(env, self.make_actor(b, len(keys)), b, keys, self.sensors,
                                  self.horizon)
        return eps, steps, time.perf_counter() - t0


def record_on_workers(pool: RayPool, job: RecordJob, slots: int, first: int,
                      write: Callable[[Episode], None]) -> int:
    """Record slots ``first..slots-1`` of a run of ``slots`` (blocks of ``job.env.num_envs``)
    on ``pool`` and hand each episode to ``write`` in slot order, in this process. Slots
    below ``first`` (committed by an earlier run) are not written again: a block that holds
    some of them is simulated whole and its first ones dropped, so a resumed run writes
    what an uninterrupted one would have. Returns the env steps simulated."""
    blocks = [(b, keys) for b, keys in enumerate(plan_blocks(slots, job.env.num_envs))
              if keys[-1] >= first]
    steps = 0

    def commit(i: int, result: tuple[list[Episode], int, float]) -> None:
        nonlocal steps
        eps, n, _ = result
        skip = max(first - int(blocks[i][1][0]), 0)  # one slot, one episode in such runs
        for ep in eps[skip:]:
            write(ep)
        steps += n

    pool.map(job, blocks, commit)
    return steps


def teacher_factory(teacher_cfg: Any, noise: float, seed: int,
                    robot: RobotDescription | None = None) -> ActorFactory:
    """msta-collect's block actor: a fresh teacher (stateful ones are sized per batch)
    for ``robot`` (``EnvConfig.teacher_robot``) that drives and labels, with ``noise`` on
    what it executes (DART), seeded per block."""
    def make(block: int, n: int) -> LabelledActor:

        return LabelledActor(build_teacher(teacher_cfg, robot), noise=noise,
                             seed=block_seed(seed, block))
    return make


def collect_on_workers(cfg: Any, write: Callable[[dict[str, np.ndarray], int, int], None],
                       have: int, sensors: tuple[str, ...]) -> int:
    """msta-collect's ``--workers`` path: episodes ``have..cfg.episodes-1`` of the run, slot
    k = episode k, seeded by ``cfg.seed``; returns the env steps simulated."""
    env = replace(cfg.env, num_envs=cfg.num_envs, seed=cfg.seed,
                  episode_length_s=cfg.episode_length_s)
    job = RecordJob(env, teacher_factory(cfg.teacher, cfg.action_noise, cfg.seed,
                                         env.teacher_robot), sensors)
    pool = shared_pool(cfg.workers, cfg.ray_address)
    bar = EpisodeBar(None, cfg.episodes - have, cfg.progress, cfg.num_envs)
    frames = [0]

    def commit(ep: Episode) -> None:  # the bar as in one process: episodes, frames per s
        write(*ep)
        frames[0] += len(ep[0]["action"])
        bar.update(frames[0] // cfg.num_envs - 1, 1)

    try:
        return record_on_workers(pool, job, cfg.episodes, have, commit)
    finally:
        bar.bar.close()
