"""Warm start of the RMA teacher: imitation of the gait controller, with privileged inputs.

Iteration k starts fresh episodes on the training terrains (levels from the terrain
curriculum) and rolls out a mix of the gait controller and the current RMA network: each
robot executes the controller's action with probability ``beta_k`` per step, the network's
otherwise (``beta_k = max(beta_min, beta_decay ** k)``), plus Gaussian noise of std
``action_noise`` on every executed action. The controller labels every step with its clean
action (its own clock runs along, reset with every episode). The scaled (e_t, o_t) and the
labels go into one buffer (the newest ``buffer_size`` samples are kept) and the network is
fitted to the whole buffer by mean-squared error (``fit_steps`` Adam steps on random
mini-batches).

The defaults are DART (beta = 1, noise 0.3): the controller always drives and the noise
takes the robot off its path. DAgger proper (beta decaying to 0) was measured worse here:
the controller runs its own gait clock, so a robot driven by the network drifts out of phase
with it and the labels contradict the robot's gait (6 iterations of beta = 0.5^k: 273 of
512 robots fell within 5 s in the last one, and the fit got worse each iteration). The
comparison is in docs/results/2026-12-04-teacher-quality-rma.md.
"""

from __future__ import annotations

import json
import os
import pickle
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch
from safetensors import SafetensorError, safe_open
from safetensors.torch import save_file

from msta.collect.recorder import LabelledActor
from msta.collect.rollout import Step, rollout
from msta.collect.sim.env import REASONS
from msta.collect.sim.env_config import EnvConfig
from msta.policies.teacher.config import TeacherConfig, build_teacher
from msta.policies.teacher.rma import RMAConfig, RMATeacher
from msta.train.rsl_env import RslVecEnv
from msta.train.state import flatten_optimizer_state, unflatten_optimizer_state
from msta.train.teacher.config import WarmStartConfig

_FALL = REASONS.index("fall")


class _Buffer:
    """Fixed-capacity ring of (privileged, proprio, label) float32 rows."""

    def __init__(self, capacity: int, dims: tuple[int, int, int]) -> None:
        self.data = [np.zeros((capacity, d), dtype=np.float32) for d in dims]
        self.capacity, self.size, self.head = capacity, 0, 0

    def add(self, *rows: np.ndarray) -> None:
        n = len(rows[0])
        idx = (self.head + np.arange(n)) % self.capacity
        for buf, r in zip(self.data, rows):
            buf[idx] = r
        self.head = int((self.head + n) % self.capacity)
        self.size = min(self.capacity, self.size + n)


def fit(net: RMATeacher, buffer: _Buffer, cfg: WarmStartConfig, opt: torch.optim.Optimizer,
        rng: np.random.Generator) -> float:
    """``cfg.fit_steps`` steps of MSE regression on random mini-batches of the buffer; the
    mean loss of the last tenth of them."""
    net.train()
    losses = []
    for _ in range(cfg.fit_steps):
        i = rng.integers(0, buffer.size, min(cfg.batch_size, buffer.size))
        priv, prop, lab = (torch.from_numpy(b[i]) for b in buffer.data)
        loss = torch.nn.functional.mse_loss(net(priv, prop), lab)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
    net.eval()
    return float(np.mean(losses[-max(1, len(losses) // 10):]))


def _dagger_rollout(vec: RslVecEnv, net: RMATeacher, gait, buffer: _Buffer, beta: float,
                    steps: int, seed: int, noise: float = 0.0) -> tuple[float, int, int]:
    """One iteration's rollout from fresh episodes (the gait clock starts with each): the
    gait controller labels every step, and drives with probability ``beta`` per step; the
    samples go to ``buffer``. Returns the network's MSE to the labels on this rollout, the
    episodes ended and the falls among them."""
    actor = LabelledActor(net, label=gait, beta=beta, seed=seed, noise=noise)
    mse: list[float] = []
    ends = np.zeros(2, dtype=np.int64)   # episodes ended, of which falls

    def on_step(step: Step) -> None:
        lab = actor.label_action
        priv, prop = vec.priv_in(step.obs), vec.proprio_in(step.obs)
        buffer.add(priv, prop, lab)
        mse.append(float(((actor.actor_action - lab) ** 2).mean()))  # the network's own
        done = step.res.done
        ends[0] += int(done.sum())
        ends[1] += int((step.res.reason[done] == _FALL).sum())

    vec.sim.reset()
    rollout(vec.sim, actor, on_step, max_steps=steps)
    return float(np.mean(mse)), int(ends[0]), int(ends[1])


def warm_start(env_cfg: EnvConfig, rma: RMAConfig, cfg: WarmStartConfig, out: Path,
               seed: int = 0, log: Callable[[str], None] = print) -> RMATeacher:
    """Run the warm start; write the ``rma`` checkpoint to ``out`` (with
    ``warmstart.json``: per-iteration label loss, fall rate and beta) and return it.
    A finished ``out`` (config.json present) is loaded instead of trained again; an
    interrupted one continues after its last finished iteration (``out/partial.safetensors``:
    the network, the optimizer and the history, :func:`save_partial`; the sample buffer
    starts empty again)."""
    if (out / "config.json").is_file() and (out / "warmstart.json").is_file():
        log(f"warm start: {out} exists, loaded")
        return RMATeacher.from_pretrained(out)
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    vec = RslVecEnv(env_cfg, rma)
    net = RMATeacher(rma)
    gait = build_teacher(TeacherConfig(type="gait"), env_cfg.teacher_robot)
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    buffer = _Buffer(cfg.buffer_size, (vec.priv_in.dim, vec.proprio_in.dim, 12))
    history: list[dict] = []
    if (out / PARTIAL).is_file() or (out / LEGACY_PARTIAL).is_file():
        history = load_partial(out, net, opt)
        log(f"warm start: resuming after iteration {len(history)}/{cfg.iterations}")
    for k in range(len(history), cfg.iterations):
        beta = max(cfg.beta_min, cfg.beta_decay ** k)
        mse, ends, falls = _dagger_rollout(vec, net, gait, buffer, beta, cfg.steps,
                                           seed * 1000 + k, cfg.action_noise)
        loss = fit(net, buffer, cfg, opt, rng)
        row = {"iteration": k, "beta": beta, "samples": buffer.size,
               "label_mse_on_rollout": mse, "fit_mse": loss,
               "episodes_ended": ends, "falls": falls}
        history.append(row)
        log(f"warm start {k + 1}/{cfg.iterations}: beta {beta:.3f}, label MSE on its rollout "
            f"{mse:.4f}, fit {loss:.4f}, falls {falls}/{ends} "
            f"episodes ended, buffer {buffer.size}")
        save_partial(out, net, opt, history)
    net.save_pretrained(out)
    (out / "warmstart.json").write_text(json.dumps({"config": asdict(cfg), "seed": seed,
                                                    "history": history}, indent=2) + "\n")
    for name in (PARTIAL, LEGACY_PARTIAL):
        (out / name).unlink(missing_ok=True)
    return net


#: The resume state of an interrupted warm start (no pickle), and the format before it.
PARTIAL, LEGACY_PARTIAL = "partial.safetensors", "partial.pt"


def save_partial(out: Path, net: RMATeacher, opt: torch.optim.Optimizer,
                 history: list[dict]) -> None:
    """``out/partial.safetensors``: the network's and the optimizer's tensors, with the
    optimizer's other state and the history as JSON in its metadata; nothing in it is
    pickled, so loading it runs no code. Written under a temporary name, then renamed."""
    out.mkdir(parents=True, exist_ok=True)
    tensors, opt_meta = flatten_optimizer_state(opt.state_dict())
    tensors = {f"opt.{k}": v for k, v in tensors.items()}
    tensors.update({f"net.{k}": v.detach().cpu().contiguous()
                    for k, v in net.state_dict().items()})
    tmp = out / (PARTIAL + ".tmp")
    save_file(tensors, str(tmp), metadata={"optimizer": json.dumps(opt_meta),
                                           "history": json.dumps(history)})
    os.replace(tmp, out / PARTIAL)
    (out / LEGACY_PARTIAL).unlink(missing_ok=True)


def load_partial(out: Path, net: RMATeacher, opt: torch.optim.Optimizer) -> list[dict]:
    """Restore :func:`save_partial`'s state into ``net`` and ``opt``; returns the history.

    A ``partial.pt`` of the format before is read with ``torch.load(weights_only=True)``,
    which refuses anything but tensors and plain types, so a pickle that would run code
    is an error, never executed.

    Raises:
        ValueError: one line naming the file, when it cannot be restored.
    """
    path = out / PARTIAL if (out / PARTIAL).is_file() else out / LEGACY_PARTIAL
    try:
        if path.name == PARTIAL:
            with safe_open(str(path), "pt", device="cpu") as f:
                meta = f.metadata() or {}
                tensors = {k: f.get_tensor(k) for k in f.keys()}  # noqa: SIM118
            part = {p: {k[len(p) + 1:]: v for k, v in tensors.items() if k.startswith(p + ".")}
                    for p in ("net", "opt")}
            state = {"net": part["net"], "history": json.loads(meta["history"]),
                     "opt": unflatten_optimizer_state(part["opt"], json.loads(meta["optimizer"]))}
        else:
            state = torch.load(path, weights_only=True)
        net.load_state_dict(state["net"])
        opt.load_state_dict(state["opt"])
        history = state["history"]
        if not isinstance(history, list) or not all(isinstance(h, dict) for h in history):
            raise TypeError("its history is not a list of iteration records")
    except (pickle.UnpicklingError, SafetensorError, RuntimeError, KeyError, TypeError,
            ValueError, EOFError, AttributeError) as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else ""
        raise ValueError(f"{path}: cannot resume the warm start from it ({type(e).__name__}: "
                         f"{first}); delete it to start the warm start again") from None
    return history
