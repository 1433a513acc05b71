"""Pieces shared by stage 1 (``msta-train``) and stage 2 (``msta-correct``).

* :class:`LoopConfig`: the optimizer / schedule / logging flags of a training loop.
* :func:`parse_cli`: draccus parsing with ``--policy.preset=<name>`` and an implicit
  ``--policy.type=msta``.
* :func:`select_device`, :func:`make_optimizer`, :class:`WarmupCosine` (the LR schedule).
* :class:`WindowSampler`: seeded random windows whose position is part of the resume state.
* :func:`save_training_state` / :func:`load_training_state`: optimizer, scheduler, RNG and
  sampler state as safetensors + JSON (no pickle anywhere).
"""

from __future__ import annotations

import json
import math
import os
import random
import re
from collections.abc import Sequence
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from safetensors.torch import load_file, save_file

from msta_data.cli import parse_config, usage_error


@dataclass
class LoopConfig:
    """Args:
        steps: optimizer steps.
        batch_size: windows per step.
        lr: peak learning rate (AdamW).
        weight_decay: AdamW decoupled weight decay (not applied to biases, norms, embeddings).
        warmup_steps: linear warm-up from 0 to ``lr``, then cosine decay.
        min_lr_ratio: the cosine ends at ``lr * min_lr_ratio``.
        grad_clip: max global gradient norm (0 = no clipping).
        mask_ratio: training token-removal ratio; null = the policy config's (0.75 for MSTA).
        eval_every: validation every N steps (0 = only at the end).
        save_every: checkpoint every N steps (0 = only the final one).
        log_every: train metrics to CSV / TensorBoard every N steps.
        val_samples: validation windows evaluated (evenly spaced over the split).
        seed: seeds the model init, the sampler, the masks and every RNG.
        progress: show a tqdm progress bar.
        ema_decay: keep an exponential moving average of the weights (decay per step,
            e.g. 0.995: about the last 200 steps) and make it the result: the final
            validation and the final checkpoint use the averaged weights. 0 = off.
    """

    steps: int = 2000
    batch_size: int = 64
    lr: float = 1e-3
    weight_decay: float = 0.01
    warmup_steps: int = 100
    min_lr_ratio: float = 0.1
    grad_clip: float = 1.0
    mask_ratio: float | None = None
    eval_every: int = 500
    save_every: int = 1000
    log_every: int = 10
    val_samples: int = 1024
    seed: int = 0
    progress: bool = True
    ema_decay: float = 0.0

    def __post_init__(self) -> None:
        for name in ("steps", "batch_size", "log_every", "val_samples"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name}={getattr(self, name)} must be >= 1")
        for name in ("warmup_steps", "eval_every", "save_every", "grad_clip", "weight_decay"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name}={getattr(self, name)} must be >= 0")
        if not self.lr > 0:
            raise ValueError(f"lr={self.lr} must be > 0")
        if not 0.0 <= self.ema_decay < 1.0:
            raise ValueError(f"ema_decay={self.ema_decay} must be in [0, 1)")
        if not 0.0 <= self.min_lr_ratio <= 1.0:
            raise ValueError(f"min_lr_ratio={self.min_lr_ratio} must be in [0, 1]")
        if self.mask_ratio is not None and not 0.0 <= self.mask_ratio < 1.0:
            raise ValueError(f"mask_ratio={self.mask_ratio} must be in [0, 1)")

    def loop_part(self) -> LoopConfig:
        """Just the :class:`LoopConfig` fields (for subclasses carrying more)."""
        return LoopConfig(**{f.name: getattr(self, f.name) for f in fields(LoopConfig)})


# ----- command line ---------------------------------------------------------------------
_PRESET = re.compile(r"^--policy\.preset(?:=(.*))?$")


def parse_cli[T](config_class: type[T], argv: Sequence[str] | None, prog: str,
                 aliases: dict[str, str] | None = None) -> T:
    """:func:`msta_data.cli.parse_config` plus two conveniences for the ``policy`` field.

    ``--policy.preset=<name>`` starts from a named preset (``MSTAConfig.from_preset``);
    ``--policy.<field>=...`` flags given explicitly still override it. Without
    ``--policy.type`` but with other ``--policy.*`` flags, ``--policy.type=msta`` is implied.
    Unknown options and invalid values exit 2 with a one-line message.

    Args:
        config_class: a draccus dataclass with a ``policy: PolicyConfig`` field.
        argv: arguments (default ``sys.argv[1:]``).
        prog: program name for the usage message.
        aliases: nested option -> the top-level option that decides it (parse_config).
    """
    import sys

    from policies.factory import known_policies

    known_policies()  # registers every built-in policy type with draccus before parsing
    args = list(sys.argv[1:] if argv is None else argv)
    preset, rest = None, []
    for i, a in enumerate(args):
        m = _PRESET.match(a)
        if m and m.group(1) is None and i + 1 < len(args):
            raise usage_error(f"{prog}: error: write --policy.preset=<name> (with '=')")
        if m:
            preset = m.group(1)
        else:
            rest.append(a)
    policy_flags = [a for a in rest if a.startswith("--policy.")]
    if policy_flags and not any(a.startswith("--policy.type") for a in policy_flags):
        rest.insert(0, "--policy.type=msta")
    cfg = parse_config(config_class, rest, prog, extra_options=[("--policy.preset", (
        "start the policy config from a named preset (msta and the baselines: paper, cpu, "
        "tiny); explicit --policy.<field> flags still override it"))], aliases=aliases)
    if preset is not None:
        explicit = {a.split("=", 1)[0][len("--policy."):] for a in policy_flags} - {"type"}
        policy = cfg.policy  # type: ignore[attr-defined]
        if not hasattr(type(policy), "from_preset"):
            raise usage_error(f"{prog}: error: policy type {policy.type!r} has no presets")
        try:
            new = type(policy).from_preset(preset, **{k: getattr(policy, k) for k in explicit})
        except (KeyError, ValueError) as e:
            raise usage_error(f"{prog}: error: {e.args[0]}") from None
        cfg = replace(cfg, policy=new)  # type: ignore[type-var]
    return cfg


# ----- device, optimizer, schedule -------------------------------------------------------
def select_device(name: str = "auto") -> torch.device:
    """``auto``: CUDA when available, else CPU. Anything else is passed to torch.device.

    Args:
        name: "auto", "cpu", "cuda", "cuda:1", ...
    """
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    device = torch.device(name)
    if device.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"device {name!r} requested but CUDA is not available")
    return device


def make_optimizer(model: torch.nn.Module, lr: float, weight_decay: float) -> torch.optim.AdamW:
    """AdamW with weight decay on matrices only (no decay for biases, norms, 1-D params).

    Embedding tables are 2-D but are excluded too (names containing ``embed``/``token``).
    """
    decay, no_decay = [], []
    for name, p in model.named_parameters():
        if not p.requires_grad:
            continue
        skip = p.ndim < 2 or "embed" in name or "token" in name
        (no_decay if skip else decay).append(p)
    groups = [{"params": decay, "weight_decay": weight_decay},
              {"params": no_decay, "weight_decay": 0.0}]
    return torch.optim.AdamW(groups, lr=lr, betas=(0.9, 0.999), eps=1e-8)


class WarmupCosine:
    """LR multiplier: linear warm-up over ``warmup`` steps, then cosine to ``min_ratio``.

    A plain object (not a lambda) so ``LambdaLR.state_dict`` stores its fields.

    Args:
        warmup: warm-up steps.
        total: total steps of the schedule.
        min_ratio: final multiplier.
    """

    def __init__(self, warmup: int, total: int, min_ratio: float) -> None:
        self.warmup, self.total, self.min_ratio = int(warmup), int(total), float(min_ratio)

    def __call__(self, step: int) -> float:
        if step < self.warmup:
            return (step + 1) / self.warmup
        span = max(self.total - self.warmup, 1)
        progress = min(max(step - self.warmup, 0) / span, 1.0)
        return self.min_ratio + (1.0 - self.min_ratio) * 0.5 * (1.0 + math.cos(math.pi * progress))


def make_scheduler(optimizer: torch.optim.Optimizer, cfg: LoopConfig
                   ) -> torch.optim.lr_scheduler.LambdaLR:
    return torch.optim.lr_scheduler.LambdaLR(
        optimizer, WarmupCosine(cfg.warmup_steps, cfg.steps, cfg.min_lr_ratio))


def seed_everything(seed: int) -> None:
    """Seed python, numpy's global RNG and torch (CPU and CUDA)."""
    random.seed(seed)
    np.random.seed(seed % 2**32)
    torch.manual_seed(seed)


# ----- sampling --------------------------------------------------------------------------
class WindowSampler:
    """Batches of sample indices in ``[0, n)``, as a resumable stream.

    Unweighted: every epoch is a fresh permutation of all windows. Weighted: every epoch is
    ``n`` draws with replacement with probabilities ``weights``. Epoch ``e`` depends only
    on ``(seed, e)``, so the position ``(epoch, offset)`` is the whole state.

    Args:
        n: number of windows.
        batch_size: indices per batch (batches may straddle epochs).
        seed: base seed.
        weights: optional per-window sampling weights (normalized here).
    """

    def __init__(self, n: int, batch_size: int, seed: int,
                 weights: np.ndarray | None = None) -> None:
        if n < 1:
            raise ValueError("no training windows to sample from")
        self.n, self.batch_size, self.seed = n, batch_size, seed
        self.p = None
        if weights is not None:
            w = np.asarray(weights, np.float64)
            if w.shape != (n,) or (w < 0).any() or not w.sum() > 0:
                raise ValueError(f"weights must be {n} non-negative values with a positive sum")
            self.p = w / w.sum()
        self.epoch, self.offset = 0, 0
        self._order = self._epoch_order(0)

    def _epoch_order(self, epoch: int) -> np.ndarray:
        rng = np.random.default_rng([self.seed, epoch])
        if self.p is None:
            return rng.permutation(self.n)
        return rng.choice(self.n, size=self.n, p=self.p)

    def next_batch(self) -> np.ndarray:
        parts, need = [], self.batch_size
        while need:
            take = self._order[self.offset:self.offset + need]
            parts.append(take)
            need -= len(take)
            self.offset += len(take)
            if self.offset == self.n:
                self.epoch, self.offset = self.epoch + 1, 0
                self._order = self._epoch_order(self.epoch)
        return np.concatenate(parts)

    def state_dict(self) -> dict[str, int]:
        return {"seed": self.seed, "epoch": self.epoch, "offset": self.offset, "n": self.n}

    def load_state_dict(self, state: dict[str, int]) -> None:
        if state["n"] != self.n or state["seed"] != self.seed:
            raise ValueError(f"sampler state is for n={state['n']}, seed={state['seed']}; "
                             f"this run has n={self.n}, seed={self.seed} (dataset changed?)")
        self.epoch, self.offset = int(state["epoch"]), int(state["offset"])
        self._order = self._epoch_order(self.epoch)


# ----- training state on disk (safetensors + JSON, no pickle) ----------------------------
def atomic_json(path: Path, obj: Any) -> None:
    """Write JSON to ``path`` via a fsync-ed temporary file and a rename."""
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w") as f:
        f.write(json.dumps(obj, indent=2) + "\n")
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def flatten_optimizer_state(state: dict[str, Any]) -> tuple[dict[str, torch.Tensor], dict]:
    """``optimizer.state_dict()`` -> (tensors for safetensors, JSON-ready structure)."""
    tensors: dict[str, torch.Tensor] = {}
    per_param: dict[str, dict[str, Any]] = {}
    for pid, entry in state["state"].items():
        out: dict[str, Any] = {}
        for key, value in entry.items():
            if isinstance(value, torch.Tensor):
                name = f"state.{pid}.{key}"
                tensors[name] = value.detach().cpu().contiguous()
                out[key] = {"__tensor__": name}
            else:
                out[key] = value
        per_param[str(pid)] = out
    return tensors, {"state": per_param, "param_groups": state["param_groups"]}


def unflatten_optimizer_state(tensors: dict[str, torch.Tensor], meta: dict) -> dict[str, Any]:
    """Inverse of :func:`flatten_optimizer_state`."""
    state = {}
    for pid, entry in meta["state"].items():
        state[int(pid)] = {k: tensors[v["__tensor__"]] if isinstance(v, dict) and "__tensor__"
                           in v else v for k, v in entry.items()}
    groups = [{k: tuple(v) if k == "betas" else v for k, v in g.items()}
              for g in meta["param_groups"]]
    return {"state": state, "param_groups": groups}


def rng_state(mask_generator: torch.Generator) -> tuple[dict[str, torch.Tensor], dict]:
    """Every RNG the loop touches: (tensors, JSON)."""
    tensors = {"torch": torch.get_rng_state(), "mask_generator": mask_generator.get_state()}
    if torch.cuda.is_available():
        for i, s in enumerate(torch.cuda.get_rng_state_all()):
            tensors[f"cuda.{i}"] = s
    py = random.getstate()
    np_state = np.random.get_state()
    meta = {"python": [py[0], list(py[1]), py[2]],
            "numpy": [np_state[0], np_state[1].tolist(), *[x for x in np_state[2:]]]}
    return tensors, meta


def set_rng_state(tensors: dict[str, torch.Tensor], meta: dict,
                  mask_generator: torch.Generator) -> None:
    torch.set_rng_state(tensors["torch"])
    mask_generator.set_state(tensors["mask_generator"])
    cuda = [tensors[k] for k in sorted(tensors) if k.startswith("cuda.")]
    if cuda and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(cuda)
    v, s, g = meta["python"]
    random.setstate((v, tuple(s), g))
    name, keys, pos, has_gauss, cached = meta["numpy"]
    np.random.set_state((name, np.asarray(keys, np.uint32), pos, has_gauss, cached))


def save_training_state(directory: Path, step: int, optimizer: torch.optim.Optimizer,
                        scheduler: torch.optim.lr_scheduler.LRScheduler,
                        sampler: WindowSampler, mask_generator: torch.Generator) -> None:
    """Write ``optimizer.safetensors/.json``, ``scheduler.json``, ``rng.safetensors/.json``
    and ``training_step.json`` (step + sampler position) into ``directory``."""
    directory.mkdir(parents=True, exist_ok=True)
    tensors, meta = flatten_optimizer_state(optimizer.state_dict())
    save_file(tensors, str(directory / "optimizer.safetensors"))
    (directory / "optimizer.json").write_text(json.dumps(meta) + "\n")
    (directory / "scheduler.json").write_text(json.dumps(scheduler.state_dict()) + "\n")
    tensors, meta = rng_state(mask_generator)
    save_file(tensors, str(directory / "rng.safetensors"))
    (directory / "rng.json").write_text(json.dumps(meta) + "\n")
    (directory / "training_step.json").write_text(
        json.dumps({"step": step, "sampler": sampler.state_dict()}) + "\n")


def load_training_state(directory: Path, optimizer: torch.optim.Optimizer,
                        scheduler: torch.optim.lr_scheduler.LRScheduler,
                        sampler: WindowSampler, mask_generator: torch.Generator) -> int:
    """Restore what :func:`save_training_state` wrote; returns the step reached."""
    missing = [n for n in ("optimizer.safetensors", "optimizer.json", "scheduler.json",
                           "rng.safetensors", "rng.json", "training_step.json")
               if not (directory / n).is_file()]
    if missing:
        raise FileNotFoundError(f"training state {directory} is incomplete: missing {missing}")
    meta = json.loads((directory / "optimizer.json").read_text())
    optimizer.load_state_dict(
        unflatten_optimizer_state(load_file(str(directory / "optimizer.safetensors")), meta))
    scheduler.load_state_dict(json.loads((directory / "scheduler.json").read_text()))
    set_rng_state(load_file(str(directory / "rng.safetensors")),
                  json.loads((directory / "rng.json").read_text()), mask_generator)
    step_info = json.loads((directory / "training_step.json").read_text())
    sampler.load_state_dict(step_info["sampler"])
    return int(step_info["step"])
