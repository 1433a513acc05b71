"""rsl_rl PPO as msta runs it: the settings (:class:`PPOConfig`) and the one chunk loop
(:class:`ChunkLoop`) that msta-train-teacher (:mod:`msta.train.teacher.cli`) and
msta-finetune-ppo (:mod:`msta.train.finetune_ppo`) both run.

A run lives in ``out/``: rsl_rl's ``OnPolicyRunner`` learns in chunks that end at multiples
of ``save_interval`` (also after a resume from mid-chunk, and after a critic warm-up that
ends mid-chunk). Each chunk ends with rsl_rl's checkpoint ``ppo/model_<it>.pt`` (optimizer
included; the two newest are kept), a row of ``curve.json`` (written atomically), the
command's product (the exported teacher, the fine-tuned student) and, at every multiple of
``snapshot_interval``, a copy of it in ``snapshots/iter_<n>/``. Re-running resumes from the
newest checkpoint.
"""

from __future__ import annotations

import json
import pickle
import re
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from msta.train.ppo_config import PPOConfig
from msta.train.rsl_env import RslVecEnv
from msta.train.state import atomic_json

_MODEL = re.compile(r"^model_(\d+)\.pt$")


def latest_checkpoint(ppo_dir: Path) -> tuple[Path, int] | None:
    """The rsl_rl checkpoint with the highest iteration in ``ppo_dir``, if any."""
    found = [(int(m.group(1)), p) for p in ppo_dir.glob("model_*.pt")
             if (m := _MODEL.match(p.name))]
    if not found:
        return None
    it, path = max(found)
    return path, it


def load_runner(runner, path: Path, device: str) -> None:
    """Resume rsl_rl's ``runner`` from its checkpoint ``path``. rsl_rl reads it with
    ``torch.load(weights_only=False)``, which runs whatever code a pickle carries, so the
    file is read first with ``weights_only=True`` (tensors and plain types only) and
    refused in one line when that fails: a tampered checkpoint never runs code."""
    try:
        torch.load(path, weights_only=True, map_location="cpu")
    except (pickle.UnpicklingError, RuntimeError, EOFError, ValueError) as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else ""
        raise ValueError(f"{path}: not a plain rsl_rl checkpoint ({type(e).__name__}: "
                         f"{first}); delete it to resume from the one before") from None
    runner.load(str(path), map_location=device)


def prune_checkpoints(ppo_dir: Path, keep: int) -> None:
    """Delete all but the ``keep`` newest rsl_rl checkpoints (each holds the optimizer)."""
    found = sorted((int(m.group(1)), p) for p in ppo_dir.glob("model_*.pt")
                   if (m := _MODEL.match(p.name)))
    for _, p in found[:-keep]:
        p.unlink()


def snapshot_dir(out: Path, iteration: int) -> Path:
    """Where the run in ``out`` keeps the exported policy of ``iteration``."""
    return out / "snapshots" / f"iter_{iteration}"


def save_levels(env: RslVecEnv, ppo_dir: Path) -> None:
    """The curriculum's state (every robot's terrain level), so a resumed run keeps it."""
    (ppo_dir / "levels.json").write_text(json.dumps(env.sim.level.tolist()) + "\n")


def load_levels(env: RslVecEnv, ppo_dir: Path) -> None:
    """Restore :func:`save_levels`' levels (when saved for as many robots)."""
    path = ppo_dir / "levels.json"
    if path.is_file():
        levels = json.loads(path.read_text())
        if len(levels) == env.num_envs:
            env.sim.set_tiles(env.sim.type_idx, levels)
            env.raw_obs = env.sim.reset()


@dataclass
class ChunkLoop:
    """One rsl_rl PPO run in chunks (the module's docstring says what each chunk leaves).

    Args:
        runner: rsl_rl's ``OnPolicyRunner``; its actor has ``set_actor_frozen(frozen)``
            (freeze all of it for the critic warm-up, or restore what it trains).
        env: the ``RslVecEnv`` the runner steps.
        ppo: the run's settings (iterations, save_interval, snapshot_interval).
        out: the run's directory (``ppo/``, ``curve.json``, ``snapshots/``).
        product: the directory of the command's product (``out/teacher``, ``out/student``).
        save: ``save(dirs, iteration)`` writes the actor as the product into each of
            ``dirs``; called once per chunk (an export that draws from torch's random
            generator, as ``to_teacher`` does, draws once).
        critic_warmup: first iterations that train only the critic (0: none).
        keep_levels: save the curriculum's levels with every chunk and restore them on a
            resume (msta-train-teacher); msta-finetune-ppo's windows of past steps do not
            follow a reset of the simulator, so its resumed robots start over at their
            initial levels.
        label: the resume line's name of the run.
        detail: the progress line's tail for a curve row.
        row_extra: extra fields of a curve row, read after each chunk.
        log: where the progress lines go.
    """

    runner: Any
    env: RslVecEnv
    ppo: PPOConfig
    out: Path
    product: Path
    save: Callable[[Sequence[Path], int], None]
    critic_warmup: int
    keep_levels: bool = False
    label: str = "PPO"
    detail: Callable[[dict], str] = lambda row: ""
    row_extra: Callable[[], dict] = field(default=dict)
    log: Callable[[str], None] = print

    @property
    def ppo_dir(self) -> Path:
        return self.out / "ppo"

    def resume(self, device: str) -> int:
        """Load the newest checkpoint, if any (and the levels, and a snapshot the run was
        killed before writing); return the iterations done."""
        found = latest_checkpoint(self.ppo_dir)
        if found is None:
            return 0
        load_runner(self.runner, found[0], device)
        done = found[1] + 1
        self.runner.current_learning_iteration = done
        if self.keep_levels:
            load_levels(self.env, self.ppo_dir)
        self.log(f"== {self.label}: resuming from {found[0].name} ({done}/"
                 f"{self.ppo.iterations} iterations) ==")
        every = self.ppo.snapshot_interval
        lost = snapshot_dir(self.out, done)
        if every and done % every == 0 and not lost.is_dir():
            # killed between the checkpoint and its snapshot: the checkpoint has the weights
            self.save([lost], done)
            self.log(f"snapshot {lost.name} written from {found[0].name} (the run stopped "
                     "before it)")
        return done

    def next_chunk(self, done: int) -> tuple[int, bool]:
        """(iterations, critic only) of the chunk after ``done``: it ends at the next
        multiple of save_interval, at the total, or at the end of the critic warm-up."""
        every = self.ppo.save_interval
        chunk = min(every - done % every, self.ppo.iterations - done)
        frozen = done < self.critic_warmup
        if frozen:
            chunk = min(chunk, self.critic_warmup - done)
        return chunk, frozen

    def run(self, done: int) -> None:
        """Learn from iteration ``done`` to ``ppo.iterations``, chunk by chunk."""
        actor = self.runner.alg.get_policy()
        curve_path = self.out / "curve.json"
        curve = json.loads(curve_path.read_text()) if curve_path.is_file() and done else []
        steps_so_far = curve[-1]["env_steps"] if curve else 0
        first = True  # spread the time-outs (rsl_rl's init_at_random_ep_len), also on a resume
        while done < self.ppo.iterations:
            chunk, frozen = self.next_chunk(done)
            actor.set_actor_frozen(frozen)
            t0 = time.time()
            self.env.take_stats()
            self.runner.learn(chunk, init_at_random_ep_len=first)
            first = False
            done += chunk
            self.runner.current_learning_iteration = done
            st = self.env.take_stats()
            steps_so_far += st["env_steps"]
            row = self.env.curve_row(st, iteration=done, env_steps=steps_so_far,
                                     seconds=round(time.time() - t0, 1), critic_only=frozen,
                                     **self.row_extra())
            curve.append(row)
            atomic_json(curve_path, curve)
            self._end_chunk(done, chunk)
            self.log(f"PPO {done}/{self.ppo.iterations}: {steps_so_far:,} env steps, full "
                     f"episode at the fall rate {row['full_episode_at_fall_rate']:.3f} per "
                     f"{self.env.cfg['episode_length_s']:g} s episode ({st['falls']} falls), "
                     + self.detail(row) + (" (critic only)" if frozen else ""))
        actor.set_actor_frozen(False)
        if not (self.product / "model.safetensors").is_file():
            self.save([self.product], done)

    def _end_chunk(self, done: int, chunk: int) -> None:
        """The product (and a snapshot when the chunk crossed a multiple of
        snapshot_interval), the levels, and the checkpoints pruned to the two newest."""
        every = self.ppo.snapshot_interval
        crossed = every and done // every > (done - chunk) // every
        self.save([self.product, snapshot_dir(self.out, done)] if crossed else [self.product],
                  done)
        if self.keep_levels:
            save_levels(self.env, self.ppo_dir)
        prune_checkpoints(self.ppo_dir, keep=2)
