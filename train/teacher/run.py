"""msta-train-teacher's run (its command line: :mod:`msta.train.teacher.cli`): the warm start
or ``--init_from``, then rsl_rl's PPO in chunks, each exported as an ``rma`` teacher."""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path

import torch
from rsl_rl.runners import OnPolicyRunner

from msta.data.locking import hold_directory
from msta.data.threads import resolve_threads
from msta.policies.factory import select_device
from msta.policies.teacher.rma import RMAConfig, RMATeacher
from msta.train.ppo import ChunkLoop, latest_checkpoint
from msta.train.rsl_env import RslVecEnv
from msta.train.teacher.config import PROG, TrainTeacherConfig
from msta.train.teacher.model import load_from_teacher, teacher_runner_cfg, to_teacher
from msta.train.teacher.warmstart import warm_start


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


def train_teacher(cfg: TrainTeacherConfig, log=print) -> Path:
    """Run (or resume) both stages; return the exported teacher's directory. output_dir is
    locked for the run: another process on it fails at once, naming this one's pid."""
    with hold_directory(cfg.output_dir, f"another {PROG} run") as out:
        return _train_teacher_locked(cfg, out, log)


def _train_teacher_locked(cfg: TrainTeacherConfig, out: Path, log) -> Path:
    """:func:`train_teacher` once output_dir is locked."""
    torch.set_num_threads(resolve_threads(cfg.num_threads))
    torch.manual_seed(cfg.seed)
    rma = RMAConfig.for_robot(cfg.env.robot_description)  # its default pose
    resuming = cfg.ppo.iterations > 0 and latest_checkpoint(out / "ppo") is not None
    init_from = str(Path(cfg.init_from).resolve()) if cfg.init_from else ""
    record_path = out / "train_teacher.json"
    if resuming and record_path.is_file():
        _check_same_start(json.loads(record_path.read_text()).get("init_from", ""),
                          init_from, out)
    start_net = None if resuming else _start_net(cfg, out, rma, init_from, log)
    record_path.write_text(json.dumps({**asdict(cfg), "init_from": init_from}, indent=2,
                                      default=str) + "\n")
    teacher_dir = out / "teacher"
    if not cfg.ppo.iterations:
        (start_net or RMATeacher(rma)).save_pretrained(teacher_dir)
        return teacher_dir
    warm = bool(init_from or cfg.warmstart.iterations)  # PPO starts from a walking policy
    _run_ppo(cfg, out, rma, start_net, warm, log)
    return teacher_dir


def _check_same_start(recorded: str, init_from: str, out: Path) -> None:
    """A resumed PPO run keeps its start: the recorded ``--init_from`` (or none)."""
    if recorded != init_from:
        raise ValueError(
            f"{out} holds a PPO run that started from "
            f"{recorded or 'its own warm start'}; resume it with "
            f"{'--init_from=' + recorded if recorded else 'no --init_from'} "
            "(or train into a fresh --output_dir)")


def _start_net(cfg: TrainTeacherConfig, out: Path, rma: RMAConfig, init_from: str,
               log) -> RMATeacher | None:
    """PPO's starting actor: ``--init_from`` (copied to ``out/init``), else the warm start
    (when it has iterations), else none (rsl_rl's random initialization)."""
    if init_from:
        start_net = load_init(init_from, rma)
        start_net.save_pretrained(out / "init")  # the run keeps its own starting point
        log(f"== PPO starts from the rma teacher {init_from} (no warm start run; a copy in "
            f"{out / 'init'}) ==")
        return start_net
    if cfg.warmstart.iterations:
        log(f"== warm start: {cfg.warmstart.iterations} imitation iterations from the gait "
            f"controller, {cfg.env.num_envs} robots x {cfg.warmstart.steps} steps each ==")
        return warm_start(cfg.env, rma, cfg.warmstart, out / "warmstart", cfg.seed, log)
    return None


def _run_ppo(cfg: TrainTeacherConfig, out: Path, rma: RMAConfig,
             start_net: RMATeacher | None, warm: bool, log) -> None:
    """Stage 2: rsl_rl's PPO in chunks (:class:`msta.train.ppo.ChunkLoop`), started from
    ``start_net`` or resumed; the critic warm-up only when PPO starts from a walking
    policy (``warm``), not from rsl_rl's random actor."""
    device = str(select_device(cfg.device))
    env = RslVecEnv(cfg.env, rma, device=device)
    runner = OnPolicyRunner(env, teacher_runner_cfg(cfg.ppo, rma), log_dir=str(out / "ppo"),
                            device=device)
    runner.add_git_repo_to_log(__file__)
    actor = runner.alg.get_policy()

    def save(dirs: Sequence[Path], iteration: int) -> None:
        exported = to_teacher(actor, rma)  # once: a fresh RMATeacher draws its init weights
        for d in dirs:
            exported.save_pretrained(d)

    loop = ChunkLoop(runner, env, cfg.ppo, out, out / "teacher", save,
                     critic_warmup=cfg.ppo.critic_warmup if warm else 0, keep_levels=True,
                     detail=lambda row: f"level {row['mean_level_at_end']:.2f}", log=log)
    done = loop.resume(device)
    if not done:
        if start_net is not None:
            load_from_teacher(actor, start_net)
        log(f"== PPO: {cfg.ppo.iterations} iterations x {cfg.env.num_envs} robots x "
            f"{cfg.ppo.num_steps_per_env} steps, device {device} ==")
    loop.run(done)
