"""msta-finetune-ppo's run (described in :mod:`msta.train.finetune_ppo`, which holds its
command line): the student as rsl_rl's actor (:class:`MSTAActor`) in a vectorized env that
feeds it its windows (:class:`StudentVecEnv`), PPO in chunks, each saved as a student."""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
import torch
from rsl_rl.modules.distribution import GaussianDistribution
from rsl_rl.runners import OnPolicyRunner
from tensordict import TensorDict
from torch import nn

from msta.collect.sim.env_config import EnvConfig
from msta.data import sensors as registry
from msta.data.locate import locate_checkpoint
from msta.data.locking import hold_directory
from msta.data.stats import load_stats
from msta.data.threads import resolve_threads
from msta.policies.actor import StudentActor
from msta.policies.base import StudentPolicy
from msta.policies.factory import load_config, load_policy, select_device
from msta.policies.msta import MSTAPolicy
from msta.policies.teacher.rma import RMAConfig
from msta.train.finetune_config import sensor_names, trainable_modules
from msta.train.finetune_ppo_config import PROG, FinetunePPOConfig, StudentPPOConfig
from msta.train.finetune_run import freeze, module_of
from msta.train.ppo import ChunkLoop
from msta.train.rsl_env import PRIVILEGED, PROPRIO, RslVecEnv
from msta.train.state import atomic_json

RECORD = "finetune.json"


RECORD_FORMAT = "msta-finetune-ppo/1"


#: rsl_rl observation group of the student's window (N, T, channels + 1: the pad flag last)
STUDENT = "student"


#: rsl_rl observation group of the dummy tokens' draws (N, D * 4 uniforms; --dummy_tokens)
DUMMY = "dummy"


class StudentVecEnv(RslVecEnv):
    """:class:`~msta.train.rsl_env.RslVecEnv` plus the group ``student``: every robot's last
    T steps of the student's sensors in the registry's raw units, concatenated over the
    sensors in the student's order, with a last column that is 1 on steps before the
    episode start (filled with the episode's first frame, the datasets' window rule,
    :class:`msta.policies.actor.StudentActor`'s buffer).

    With ``dummy_tokens`` = D > 0 there is also the group ``dummy``: D x 4 uniform numbers
    in [0, 1) per robot, fresh every step (seeded by ``env_cfg.seed``), that fix the draws of
    the D random dummy tokens appended to the student's tokens (the paper's stress test,
    :mod:`msta.policies.msta.modeling_msta`): stored with the rollout, they give PPO's update the
    same tokens the rollout saw.

    Args:
        env_cfg: the simulator.
        policy: the student (its ``required_sensors`` and ``config.history``).
        device: torch device of the returned tensors.
        dummy_tokens: random dummy tokens per step (0: no ``dummy`` group).
    """

    def __init__(self, env_cfg: EnvConfig, policy: StudentPolicy,
                 device: str | torch.device = "cpu", dummy_tokens: int = 0) -> None:
        super().__init__(env_cfg, RMAConfig.for_robot(env_cfg.robot_description), device)
        self.windows = StudentActor(policy, self.num_envs)
        self.dummy_tokens = int(dummy_tokens)
        self.dummy_rng = np.random.default_rng([int(env_cfg.seed), 0xD0])
        self.last = self.observe(None)

    def observe(self, res) -> TensorDict:
        if res is not None:  # envs that finished start a new window with this observation
            self.windows.reset(np.flatnonzero(res.done))
        batch = self.windows.window(self.raw_obs)
        win = np.concatenate([batch[s] for s in self.windows.sensors]
                             + [batch["pad"][..., None].astype(np.float32)], axis=-1)
        groups = self.groups(self.raw_obs)
        groups[STUDENT] = torch.from_numpy(win).to(self.device)
        if self.dummy_tokens:
            u = self.dummy_rng.random((self.num_envs, 4 * self.dummy_tokens), dtype=np.float32)
            groups[DUMMY] = torch.from_numpy(u).to(self.device)
        self.last = groups
        return groups

    def get_observations(self) -> TensorDict:
        return self.last


def split_window(policy: StudentPolicy, x: torch.Tensor) -> dict[str, torch.Tensor]:
    """The ``student`` group (B, T, channels + 1) -> the policy's raw batch (sensor windows
    and the bool "pad")."""
    batch, at = {}, 0
    for s in policy.required_sensors:
        dim = registry.get(s).dim
        batch[s] = x[..., at:at + dim]
        at += dim
    if at + 1 != x.shape[-1]:
        raise ValueError(f"the student group has {x.shape[-1]} columns; the student's sensors "
                         f"need {at} + 1 (pad)")
    batch["pad"] = x[..., at] > 0.5
    return batch


class MSTAActor(nn.Module):
    """An msta student as an rsl_rl actor: the action mean is the student's action (raw
    units, test mask 0) on the ``student`` group; rsl_rl's Gaussian adds the exploration
    noise (a learned per-joint std). Parameters outside ``trainable`` are frozen.

    Args:
        obs, obs_groups, obs_set, output_dim: as rsl_rl passes them to every model; the set
            is ``["student"]``, or ``["student", "dummy"]`` with dummy tokens appended (their
            draws read from the ``dummy`` group).
        policy_path: the student checkpoint (msta-finetune-ppo's ``start/``).
        trainable: msta-finetune's ``--trainable`` groups (``embeddings+head``).
        distribution_cfg: rsl_rl's ``GaussianDistribution`` options (``init_std`` ...).
    """

    is_recurrent = False

    def __init__(self, obs: TensorDict, obs_groups: dict[str, list[str]], obs_set: str,
                 output_dim: int, policy_path: str = "", trainable: str = "embeddings",
                 distribution_cfg: dict | None = None) -> None:
        super().__init__()
        groups = list(obs_groups[obs_set])
        if groups not in ([STUDENT], [STUDENT, DUMMY]):
            raise ValueError(f"MSTAActor reads the group {STUDENT!r} (and {DUMMY!r}); "
                             f"obs_groups[{obs_set!r}] = {groups}")
        self.dummy = DUMMY in groups
        self.policy = load_policy(policy_path)
        if self.dummy:
            self.policy.check_dummy_tokens(1)
        self.trained = freeze(self.policy, trainable_modules(trainable))
        split_window(self.policy, obs[STUDENT][:1])  # the group's width fits the student
        dist = dict(distribution_cfg or {})
        dist.pop("class_name", None)
        self.distribution = GaussianDistribution(output_dim, **dist)

    def action_mean(self, obs: TensorDict) -> torch.Tensor:
        """(B, 12) desired joint positions: the student's deterministic action."""
        batch = split_window(self.policy, obs[STUDENT])
        dummy: int | torch.Tensor = 0
        if self.dummy:
            u = obs[DUMMY]
            dummy = u.reshape(u.shape[0], -1, 4)
        return self.policy.processor.unnormalize_action(
            self.policy(batch, mask_ratio=0.0, dummy_tokens=dummy))

    def forward(self, obs: TensorDict, masks: torch.Tensor | None = None, hidden_state=None,
                stochastic_output: bool = False) -> torch.Tensor:
        mean = self.action_mean(obs)
        if stochastic_output:
            self.distribution.update(mean)
            return self.distribution.sample()
        return mean

    # rsl_rl's model interface (non-recurrent, no observation normalization)
    def reset(self, dones=None, hidden_state=None) -> None:
        pass

    def get_hidden_state(self):
        return None

    def detach_hidden_state(self, dones=None) -> None:
        pass

    def update_normalization(self, obs: TensorDict) -> None:
        pass

    @property
    def output_mean(self) -> torch.Tensor:
        return self.distribution.mean

    @property
    def output_std(self) -> torch.Tensor:
        return self.distribution.std

    @property
    def output_entropy(self) -> torch.Tensor:
        return self.distribution.entropy

    @property
    def output_distribution_params(self) -> tuple[torch.Tensor, ...]:
        return self.distribution.params

    def get_output_log_prob(self, outputs: torch.Tensor) -> torch.Tensor:
        return self.distribution.log_prob(outputs)

    def get_kl_divergence(self, old_params, new_params) -> torch.Tensor:
        return self.distribution.kl_divergence(old_params, new_params)

    def set_actor_frozen(self, frozen: bool) -> None:
        """Freeze the whole actor (critic warm-up), or restore ``trainable``'s split."""
        names = set(self.trained)
        for name, p in self.policy.named_parameters():
            p.requires_grad_(not frozen and name in names)
        for p in self.distribution.parameters():
            p.requires_grad_(not frozen)

    def __repr__(self) -> str:  # rsl_rl prints its models; the transformer's tree is long
        n = sum(p.numel() for p in self.policy.parameters())
        return (f"MSTAActor(msta student on {', '.join(self.policy.required_sensors)} at T = "
                f"{self.policy.config.history}, {n:,} parameters, trained: "
                f"{', '.join(sorted({module_of(k) for k in self.trained}))}; "
                f"{self.distribution.__class__.__name__})")

    def as_jit(self):  # rsl_rl's exports are for MLPs; the student exports with msta-export
        raise NotImplementedError("export the fine-tuned student with msta-export")

    as_onnx = as_jit


def student_runner_cfg(ppo: StudentPPOConfig, start: Path, trainable: str,
                       dummy_tokens: int = 0) -> dict:
    """rsl_rl ``OnPolicyRunner`` train_cfg with the student (``start``) as the actor."""
    groups = [STUDENT, DUMMY] if dummy_tokens else [STUDENT]
    actor = {"class_name": f"{MSTAActor.__module__}:{MSTAActor.__name__}",
             "policy_path": str(start), "trainable": trainable,
             "distribution_cfg": {"class_name": "GaussianDistribution",
                                  "init_std": ppo.init_std, "std_type": "scalar"}}
    return ppo.runner_cfg(actor, {"actor": groups, "critic": [PRIVILEGED, PROPRIO]})


def prepare_start(cfg: FinetunePPOConfig, out: Path) -> tuple[Path, dict[str, Any]]:
    """``out/start/``: the source restricted to the chosen inputs and T (written once;
    a resumed run reuses it); returns it and the finetune.json record."""
    ckpt = locate_checkpoint(cfg.policy.path, "--policy.path")
    config = load_config(ckpt)
    if config.type != "msta":
        raise ValueError(f"{ckpt} holds a {config.type!r} student; msta-finetune-ppo trains the "
                         "token embeddings of a frozen MSTA transformer, which the baselines "
                         "do not have")
    sensors = sensor_names(cfg.sensors, config.input_sensors)
    added = [s for s in sensors if s not in config.input_sensors]
    start = out / "start"
    if not (start / "model.safetensors").is_file():
        stats = None
        if added:
            if not cfg.dataset:
                raise ValueError(f"sensors adds {', '.join(added)}, which {ckpt} lacks; give "
                                 "--dataset=<a dataset recording it> for its statistics")
            stats = load_stats(Path(cfg.dataset))
        source = load_policy(ckpt)
        assert isinstance(source, MSTAPolicy)
        source.with_inputs(sensors, cfg.history, stats).save_pretrained(start)
    record = {"format": RECORD_FORMAT, "method": "ppo", "source": str(ckpt),
              "input_sensors": list(sensors), "added_sensors": added, "history": cfg.history,
              "trainable": cfg.trainable, "dummy_tokens": cfg.dummy_tokens}
    return start, record


#: options that define a run: a re-run into the same output_dir must repeat them
RESUME_FIELDS = ("policy", "sensors", "history", "trainable", "dataset", "dummy_tokens",
                 "seed")


def check_resume(cfg: FinetunePPOConfig, out: Path) -> None:
    """A re-run into an existing ``output_dir`` continues that run: its defining options
    (and the rollout's shape) must match the recorded ones (one-line error otherwise)."""
    path = out / "finetune_ppo.json"
    if not path.is_file():
        return
    old, new = json.loads(path.read_text()), json.loads(json.dumps(asdict(cfg)))
    pairs = [(k, old.get(k), new[k]) for k in RESUME_FIELDS]
    pairs += [("env.num_envs", old["env"]["num_envs"], new["env"]["num_envs"]),
              ("ppo.num_steps_per_env", old["ppo"]["num_steps_per_env"],
               new["ppo"]["num_steps_per_env"])]
    for name, was, now in pairs:
        if was != now:
            raise ValueError(f"{out} holds a run with {name}={was!r}, not {now!r}; re-run with "
                             "the same options to continue it, or choose another --output_dir")


def save_student(actor: MSTAActor, student: Path, record: dict[str, Any],
                 iteration: int) -> None:
    """The actor's student in ``student`` (``out/student/``, a snapshot) with its
    finetune.json."""
    actor.policy.save_pretrained(student)
    params = dict(actor.policy.named_parameters())
    atomic_json(student / RECORD, {
        **record, "iterations": iteration, "trained_parameters": actor.trained,
        "trained_numel": sum(params[k].numel() for k in actor.trained),
        "total_numel": sum(p.numel() for p in params.values()),
        "action_std": [round(float(s), 5) for s in actor.distribution.std_param.detach()]})


def open_runner(cfg: FinetunePPOConfig, start: Path, record: dict[str, Any], out: Path,
                log) -> tuple[ChunkLoop, int]:
    """rsl_rl's runner with the student as its actor on :class:`StudentVecEnv`, in the PPO
    chunk loop (:class:`msta.train.ppo.ChunkLoop`), resumed from the newest checkpoint in
    ``output_dir/ppo`` when there is one; returns the loop and the iterations done."""
    device = str(select_device(cfg.device))
    env = StudentVecEnv(cfg.env, load_policy(start), device=device,
                        dummy_tokens=cfg.dummy_tokens)
    runner = OnPolicyRunner(env, student_runner_cfg(cfg.ppo, start, cfg.trainable,
                                                            cfg.dummy_tokens),
                            log_dir=str(out / "ppo"), device=device)
    actor = runner.alg.get_policy()
    assert isinstance(actor, MSTAActor)

    def save(dirs: Sequence[Path], iteration: int) -> None:
        for d in dirs:
            save_student(actor, d, record, iteration)

    loop = ChunkLoop(
        runner, env, cfg.ppo, out, out / "student", save,
        critic_warmup=cfg.ppo.critic_warmup, label=PROG,
        detail=lambda row: f"lin. tracking {row['lin_vel_tracking_per_step']:.4f}/step",
        row_extra=lambda: {"action_std": float(actor.distribution.std_param.detach().mean())},
        log=log)
    done = loop.resume(device)
    if done:
        return loop, done
    n = sum(p.numel() for name, p in actor.policy.named_parameters() if name in actor.trained)
    total = sum(p.numel() for p in actor.policy.parameters())
    log(f"== {PROG}: {start} on {', '.join(record['input_sensors'])} at T = {cfg.history}; "
        f"training {cfg.trainable} ({n:,} of {total:,} parameters: "
        f"{', '.join(sorted({module_of(k) for k in actor.trained}))}) and the action "
        f"noise{f', {cfg.dummy_tokens} dummy tokens appended' if cfg.dummy_tokens else ''}; "
        f"{cfg.ppo.iterations} iterations x {cfg.env.num_envs} robots x "
        f"{cfg.ppo.num_steps_per_env} steps, device {device} ==")
    return loop, 0


def finetune_ppo(cfg: FinetunePPOConfig, log=print) -> Path:
    """Run (or resume) the fine-tune; return ``output_dir/student``. output_dir is locked
    for the run: another process on it fails at once, naming this one's pid."""
    with hold_directory(cfg.output_dir, f"another {PROG} run") as out:
        return _finetune_ppo_locked(cfg, out, log)


def _finetune_ppo_locked(cfg: FinetunePPOConfig, out: Path, log) -> Path:
    """:func:`finetune_ppo` once output_dir is locked."""
    torch.set_num_threads(resolve_threads(cfg.num_threads))
    torch.manual_seed(cfg.seed)
    check_resume(cfg, out)
    start, record = prepare_start(cfg, out)
    atomic_json(out / "finetune_ppo.json", asdict(cfg))
    loop, done = open_runner(cfg, start, record, out, log)
    loop.run(done)
    return out / "student"
