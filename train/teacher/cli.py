"""``msta-train-teacher``: the paper's RMA teacher, trained by rsl_rl's PPO.

Two resumable stages under ``--output_dir``:

1. ``warmstart/``: imitation of the gait controller (DART by default) by the RMA MLP with
   privileged inputs (``train.teacher.warmstart``), so PPO starts from a walking policy,
   not from noise.
2. ``ppo/``: rsl_rl's ``OnPolicyRunner`` with rsl_rl's PPO on ``RslVecEnv`` (the paper's
   legged_gym rewards and randomization, the terrain curriculum), in chunks of
   ``--ppo.save_interval`` iterations; each chunk ends with rsl_rl's checkpoint
   (``model_<it>.pt``, optimizer included), TensorBoard events, a row of ``curve.json``
   (environment steps, falls per 1000 robot steps and the survival of a full episode at
   that rate, level, tracking) and the exported teacher.

The result, ``teacher/`` (config.json + model.safetensors), is an ``rma`` teacher:
``--teacher.type=rma --teacher.path=<output_dir>/teacher`` works wherever a teacher does.
Re-running the same command after an interruption continues where it stopped.
"""

from __future__ import annotations

import json
import os
import pickle
import re
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import torch

from collect.sim.env import EnvConfig
from msta_data.cli import check_at_least, check_number, parse_config
from msta_data.errors import DirectoryLockedError
from msta_data.locking import hold_directory
from policies.teacher.rma import RMAConfig, RMATeacher
from train.optim import select_device
from train.teacher.env import PRIVILEGED, PROPRIO, RslVecEnv
from train.teacher.model import actor_cfg, load_from_teacher, to_teacher
from train.teacher.warmstart import WarmStartConfig, warm_start

PROG = "msta-train-teacher"
_MODEL = re.compile(r"^model_(\d+)\.pt$")


#: The longest rollout per robot and PPO iteration (200 s at 50 Hz; rsl_rl recipes use 24-48
#: steps): rsl_rl allocates the whole rollout of every robot before the first step.
MAX_STEPS_PER_ENV = 10_000


@dataclass
class PPOConfig:
    """rsl_rl PPO settings (legged_gym's defaults unless noted).

    Args:
        iterations: PPO iterations in all (each: num_steps_per_env steps of every robot,
            then the update); a resumed run stops at this total.
        num_steps_per_env: rollout steps per robot per iteration.
        learning_rate: Adam learning rate at the start (then adapted to desired_kl).
            legged_gym's 1e-3 suits a policy starting from noise; on the warm-started one
            the first update moved the mean far past the KL target (the schedule cut the
            rate to 1e-5 at once) and the share of episodes ending in a fall rose from 0.39
            to 0.81 within 10 iterations.
        desired_kl: target KL of the adaptive learning-rate schedule.
        entropy_coef: entropy bonus.
        init_std: initial action noise std (action units); small after a warm start, so
            exploration does not undo the walking policy.
        critic_warmup: first iterations that train only the critic (the actor frozen), so
            a random value function does not drive the first policy updates.
        num_learning_epochs: passes over each rollout.
        num_mini_batches: mini-batches per pass.
        clip_param: PPO ratio clip.
        gamma: discount.
        lam: GAE lambda.
        save_interval: iterations per chunk (a checkpoint, a curve row, an export each).
        snapshot_interval: every this many iterations the exported teacher is also kept as
            ``snapshots/iter_<n>/`` (an ``rma`` checkpoint, ~1 MB), so the run's progress can
            be evaluated afterwards and its best checkpoint chosen; 0 keeps none. Taken at
            the end of the chunk that reaches or passes each multiple, and named by that
            chunk's last iteration.
    """

    iterations: int = 300
    num_steps_per_env: int = 48
    learning_rate: float = 1e-4
    desired_kl: float = 0.01
    entropy_coef: float = 0.01
    init_std: float = 0.2
    critic_warmup: int = 10
    num_learning_epochs: int = 5
    num_mini_batches: int = 4
    clip_param: float = 0.2
    gamma: float = 0.99
    lam: float = 0.95
    save_interval: int = 10
    snapshot_interval: int = 100

    def __post_init__(self) -> None:
        check_at_least(self, 0, "iterations", "critic_warmup", "snapshot_interval")
        check_at_least(self, 1, "num_learning_epochs", "num_mini_batches", "save_interval")
        check_at_least(self, 1, "num_steps_per_env", maximum=MAX_STEPS_PER_ENV,
                       why="rsl_rl stores each iteration's whole rollout")
        for name in ("learning_rate", "desired_kl", "init_std", "clip_param"):
            check_number(f"ppo.{name}", getattr(self, name), 0, above=True)
        check_number("ppo.entropy_coef", self.entropy_coef, 0)
        check_number("ppo.gamma", self.gamma, 0, 1)
        check_number("ppo.lam", self.lam, 0, 1)

    def runner_cfg(self, rma: RMAConfig) -> dict:
        """rsl_rl ``OnPolicyRunner`` train_cfg."""
        both = [PRIVILEGED, PROPRIO]
        return {
            "num_steps_per_env": self.num_steps_per_env, "save_interval": self.save_interval,
            "obs_groups": {"actor": both, "critic": both},
            "actor": actor_cfg(rma, self.init_std),
            "critic": {"class_name": "MLPModel", "hidden_dims": [512, 256, 128],
                       "activation": "elu", "obs_normalization": True},
            "algorithm": {"class_name": "PPO", "learning_rate": self.learning_rate,
                          "desired_kl": self.desired_kl, "entropy_coef": self.entropy_coef,
                          "num_learning_epochs": self.num_learning_epochs,
                          "num_mini_batches": self.num_mini_batches,
                          "clip_param": self.clip_param, "gamma": self.gamma, "lam": self.lam,
                          "schedule": "adaptive", "max_grad_norm": 1.0,
                          "value_loss_coef": 1.0, "use_clipped_value_loss": True},
        }


def _default_env() -> EnvConfig:
    return EnvConfig(num_envs=256, episode_length_s=20.0, nthread=0)


@dataclass
class TrainTeacherConfig:
    """Args:
        output_dir: where warmstart/, ppo/ (rsl_rl checkpoints, TensorBoard), curve.json and
            teacher/ (the exported rma checkpoint) go; re-running resumes.
        seed: seeds torch, the warm start and the simulator (env.seed follows it).
        device: torch device for PPO: auto (CUDA when present), cpu, cuda.
        num_threads: torch threads (0: one per core).
        init_from: an existing ``rma`` teacher checkpoint (a directory with config.json and
            model.safetensors, e.g. policies/teacher/checkpoints/rma_dart, the shipped warm
            start) that PPO starts from instead of running the warm start; empty: run the
            warm start (warmstart.iterations) as configured.
        warmstart: the warm start: imitation of the gait controller (DART by default).
        ppo: rsl_rl PPO settings.
        env: the simulator (robots, terrains and curriculum, rewards, randomization);
            env.nthread 0 uses every core for physics.
    """

    output_dir: str = "outputs/teacher"
    seed: int = 0
    device: str = "auto"
    num_threads: int = 0
    init_from: str = ""
    warmstart: WarmStartConfig = field(default_factory=WarmStartConfig)
    ppo: PPOConfig = field(default_factory=PPOConfig)
    env: EnvConfig = field(default_factory=_default_env)

    def __post_init__(self) -> None:
        check_at_least(self, 0, "num_threads")
        self.env.seed = self.seed


def load_init(path: str, rma: RMAConfig) -> RMATeacher:
    """The ``rma`` teacher at ``path`` (``--init_from``); a one-line error when it is not
    one or its layers differ from the actor PPO trains (``rma``)."""
    try:
        net = RMATeacher.from_pretrained(path)
    except (OSError, ValueError) as e:
        raise ValueError(f"--init_from={path}: {e}") from None
    if net.config.to_dict() != rma.to_dict():
        raise ValueError(f"--init_from={path}: its network ({net.config.to_dict()}) is not "
                         f"the one PPO trains ({rma.to_dict()})")
    return net


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


def snapshot_dir(out: Path, iteration: int) -> Path:
    """Where the run in ``out`` keeps the exported teacher of ``iteration``."""
    return out / "snapshots" / f"iter_{iteration}"


def _save_levels(env: RslVecEnv, ppo_dir: Path) -> None:
    """The curriculum's state (every robot's terrain level), so a resumed run keeps it."""
    (ppo_dir / "levels.json").write_text(json.dumps(env.sim.level.tolist()) + "\n")


def _load_levels(env: RslVecEnv, ppo_dir: Path) -> None:
    path = ppo_dir / "levels.json"
    if path.is_file():
        levels = json.loads(path.read_text())
        if len(levels) == env.num_envs:
            env.sim.set_tiles(env.sim.type_idx, levels)
            env.raw_obs = env.sim.reset()


def prune_checkpoints(ppo_dir: Path, keep: int) -> None:
    """Delete all but the ``keep`` newest rsl_rl checkpoints (each holds the optimizer)."""
    found = sorted((int(m.group(1)), p) for p in ppo_dir.glob("model_*.pt")
                   if (m := _MODEL.match(p.name)))
    for _, p in found[:-keep]:
        p.unlink()


def train_teacher(cfg: TrainTeacherConfig, log=print) -> Path:
    """Run (or resume) both stages; return the exported teacher's directory. output_dir is
    locked for the run: another process on it fails at once, naming this one's pid."""
    with hold_directory(cfg.output_dir, f"another {PROG} run") as out:
        return _train_teacher_locked(cfg, out, log)


def _train_teacher_locked(cfg: TrainTeacherConfig, out: Path, log) -> Path:
    """:func:`train_teacher` once output_dir is locked."""
    from rsl_rl.runners import OnPolicyRunner

    torch.set_num_threads(cfg.num_threads or os.cpu_count() or 1)
    torch.manual_seed(cfg.seed)
    rma = RMAConfig()
    resuming = cfg.ppo.iterations > 0 and latest_checkpoint(out / "ppo") is not None
    init_from = str(Path(cfg.init_from).resolve()) if cfg.init_from else ""
    record_path = out / "train_teacher.json"
    if resuming and record_path.is_file():
        recorded = json.loads(record_path.read_text()).get("init_from", "")
        if recorded != init_from:
            raise ValueError(
                f"{out} holds a PPO run that started from "
                f"{recorded or 'its own warm start'}; resume it with "
                f"{'--init_from=' + recorded if recorded else 'no --init_from'} "
                "(or train into a fresh --output_dir)")
    start_net = None
    if init_from and not resuming:
        start_net = load_init(init_from, rma)
        start_net.save_pretrained(out / "init")  # the run keeps its own starting point
        log(f"== PPO starts from the rma teacher {init_from} (no warm start run; a copy in "
            f"{out / 'init'}) ==")
    elif cfg.warmstart.iterations and not resuming:
        log(f"== warm start: {cfg.warmstart.iterations} imitation iterations from the gait "
            f"controller, {cfg.env.num_envs} robots x {cfg.warmstart.steps} steps each ==")
        start_net = warm_start(cfg.env, rma, cfg.warmstart, out / "warmstart", cfg.seed, log)
    record_path.write_text(json.dumps({**asdict(cfg), "init_from": init_from}, indent=2,
                                      default=str) + "\n")
    teacher_dir = out / "teacher"
    if not cfg.ppo.iterations:
        (start_net or RMATeacher(rma)).save_pretrained(teacher_dir)
        return teacher_dir
    device = str(select_device(cfg.device))
    env = RslVecEnv(cfg.env, rma, device=device)
    ppo_dir = out / "ppo"
    runner = OnPolicyRunner(env, cfg.ppo.runner_cfg(rma), log_dir=str(ppo_dir), device=device)
    runner.add_git_repo_to_log(__file__)
    found = latest_checkpoint(ppo_dir)
    done = 0
    if found is not None:
        load_runner(runner, found[0], device)
        done = found[1] + 1
        runner.current_learning_iteration = done
        _load_levels(env, ppo_dir)
        log(f"== PPO: resuming from {found[0].name} ({done}/{cfg.ppo.iterations} iterations) ==")
        every = cfg.ppo.snapshot_interval
        lost = snapshot_dir(out, done)
        if every and done % every == 0 and not lost.is_dir():
            # killed between the checkpoint and its snapshot: the checkpoint has the weights
            to_teacher(runner.alg.get_policy(), rma).save_pretrained(lost)
            log(f"snapshot {lost.name} written from {found[0].name} (the run stopped before it)")
    else:
        if start_net is not None:
            load_from_teacher(runner.alg.get_policy(), start_net)
        log(f"== PPO: {cfg.ppo.iterations} iterations x {cfg.env.num_envs} robots x "
            f"{cfg.ppo.num_steps_per_env} steps, device {device} ==")
    curve_path = out / "curve.json"
    curve = json.loads(curve_path.read_text()) if curve_path.is_file() and done else []
    steps_so_far = curve[-1]["env_steps"] if curve else 0
    actor = runner.alg.get_policy()
    first = True  # spread the time-outs (rsl_rl's init_at_random_ep_len), also on a resume
    warm = bool(init_from or cfg.warmstart.iterations)  # PPO started from a walking policy
    while done < cfg.ppo.iterations:
        # chunks end at multiples of save_interval, also after a resume from mid-chunk
        chunk = min(cfg.ppo.save_interval - done % cfg.ppo.save_interval,
                    cfg.ppo.iterations - done)
        frozen = done < cfg.ppo.critic_warmup and warm
        if frozen:
            chunk = min(chunk, cfg.ppo.critic_warmup - done)
        for p in actor.parameters():
            p.requires_grad_(not frozen)
        t0 = time.time()
        env.take_stats()
        runner.learn(chunk, init_at_random_ep_len=first)
        first = False
        done += chunk
        runner.current_learning_iteration = done
        st = env.take_stats()
        steps_so_far += st["env_steps"]
        row = env.curve_row(st, iteration=done, env_steps=steps_so_far,
                            seconds=round(time.time() - t0, 1), critic_only=frozen)
        curve.append(row)
        curve_path.write_text(json.dumps(curve, indent=1) + "\n")
        exported = to_teacher(actor, rma)
        exported.save_pretrained(teacher_dir)
        every = cfg.ppo.snapshot_interval
        if every and done // every > (done - chunk) // every:  # crossed a multiple
            exported.save_pretrained(snapshot_dir(out, done))
        _save_levels(env, ppo_dir)
        prune_checkpoints(ppo_dir, keep=2)
        log(f"PPO {done}/{cfg.ppo.iterations}: {steps_so_far:,} env steps, survival "
            f"{row['survival_per_episode']:.3f} per {cfg.env.episode_length_s:g} s episode "
            f"({st['falls']} falls), level "
            f"{row['mean_level_at_end']:.2f}" + (" (critic only)" if frozen else ""))
    for p in actor.parameters():
        p.requires_grad_(True)
    if not teacher_dir.is_dir():
        to_teacher(actor, rma).save_pretrained(teacher_dir)
    return teacher_dir


def main(argv: Sequence[str] | None = None) -> None:
    cfg = parse_config(TrainTeacherConfig, argv, prog=PROG, aliases={"env.seed": "seed"})
    try:
        path = train_teacher(cfg)
    except (OSError, ValueError, DirectoryLockedError) as e:
        raise SystemExit(f"{PROG}: error: {e}") from None
    print(f"teacher: {path} (use --teacher.type=rma --teacher.path={path})")


if __name__ == "__main__":
    main()
