"""Device, seeds, optimizer and learning-rate schedule of a training loop."""

from __future__ import annotations

import math
import random
from pathlib import Path

import numpy as np
import torch
from safetensors import safe_open
from safetensors.torch import save_file

from msta.policies.base import StudentPolicy
from msta.policies.checkpoint import CheckpointError
from msta.policies.factory import select_device  # noqa: F401  (re-exported: train.optim.select_device)
from msta.train.config import LoopConfig, check_optimizer


def parameter_groups(model: torch.nn.Module, weight_decay: float) -> list[dict]:
    """Weight decay on matrices only: ``[{"params": matrices, "weight_decay": weight_decay},
    {"params": the rest, "weight_decay": 0.0}]``. Biases, norms and 1-D params are the rest,
    and so are embedding tables (2-D, but names containing ``embed``/``token``)."""
    decay, no_decay = [], []
    for name, p in model.named_parameters():
        if not p.requires_grad:
            continue
        skip = p.ndim < 2 or "embed" in name or "token" in name
        (no_decay if skip else decay).append(p)
    return [{"params": decay, "weight_decay": weight_decay},
            {"params": no_decay, "weight_decay": 0.0}]


def make_adamw(model: torch.nn.Module, lr: float, weight_decay: float) -> torch.optim.AdamW:
    """AdamW on :func:`parameter_groups` (weight decay on matrices only), fused: one kernel
    for every parameter instead of a loop over them (most of the cpu preset's weights are its
    value tables; ``make bench-train`` times a step)."""
    return torch.optim.AdamW(parameter_groups(model, weight_decay), lr=lr, betas=(0.9, 0.999),
                             eps=1e-8, fused=True)


class MuonAdamW(torch.optim.Optimizer):
    """Muon on the transformer blocks' weight matrices, fused AdamW on everything else.

    Muon (torch.optim.Muon, ``adjust_lr_fn="match_rms_adamw"``, so one ``lr`` suits both)
    orthogonalizes each matrix's momentum with Newton-Schulz steps; embeddings, value tables,
    norms, biases, readout tokens and the action head stay on AdamW, as Muon's authors
    advise. One optimizer to the loop: one ``param_groups`` list (the schedule scales every
    group) and one ``state`` (saved and resumed as any optimizer's).

    Args:
        muon_params: 2-D matrices for Muon.
        adamw_groups: :func:`parameter_groups`-style groups for AdamW.
        lr: peak learning rate of both.
        weight_decay: decoupled weight decay of the Muon matrices.
    """

    def __init__(self, muon_params: list[torch.nn.Parameter], adamw_groups: list[dict],
                 lr: float, weight_decay: float) -> None:
        self._muon = torch.optim.Muon(muon_params, lr=lr, weight_decay=weight_decay,
                                      adjust_lr_fn="match_rms_adamw")
        self._adamw = torch.optim.AdamW(adamw_groups, lr=lr, betas=(0.9, 0.999), eps=1e-8,
                                        fused=True)
        groups = self._muon.param_groups + self._adamw.param_groups
        super().__init__(groups, {"lr": lr})
        self._share()

    def _share(self) -> None:
        """The inner optimizers read and write this optimizer's groups and state."""
        n = len(self._muon.param_groups)
        self._muon.param_groups, self._adamw.param_groups = (self.param_groups[:n],
                                                             self.param_groups[n:])
        self._muon.state = self._adamw.state = self.state

    def load_state_dict(self, state_dict: dict) -> None:
        super().load_state_dict(state_dict)
        self._share()

    @torch.no_grad()
    def step(self, closure: None = None) -> None:
        """Muon's update, then AdamW's (neither needs a closure; one is refused)."""
        if closure is not None:
            raise ValueError("MuonAdamW.step takes no closure")
        self._muon.step()
        self._adamw.step()


def make_optimizer(model: torch.nn.Module, lr: float, weight_decay: float,
                   kind: str = "adamw") -> torch.optim.Optimizer:
    """``adamw``: :func:`make_adamw`. ``muon``: :class:`MuonAdamW`, Muon on the 2-D weights
    of the transformer blocks (``blocks.*``), AdamW on the rest; a student without
    transformer blocks gets :func:`make_adamw`."""
    if kind == "adamw":
        return make_adamw(model, lr, weight_decay)
    check_optimizer(kind)
    muon = [p for n, p in model.named_parameters()
            if p.requires_grad and p.ndim == 2 and ".blocks." in f".{n}"]
    if not muon:  # no transformer blocks (gru, rma_tcn, mlp): every weight on AdamW
        return make_adamw(model, lr, weight_decay)
    ids = {id(p) for p in muon}
    groups = [{**g, "params": [p for p in g["params"] if id(p) not in ids]}
              for g in parameter_groups(model, weight_decay)]
    return MuonAdamW(muon, [g for g in groups if g["params"]], lr, weight_decay)


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


# ----- weight averaging ------------------------------------------------------------------
class WeightEMA:
    """Exponential moving average of a policy's parameters (``LoopConfig.ema_decay``).

    After step t the average moves towards the weights by ``1 - min(decay, (1+t)/(10+t))``
    (the usual warm-up, so early steps do not freeze the start weights in). Its state is
    one safetensors file in the checkpoint's training state, so a resumed run averages on
    exactly as an uninterrupted one.

    Args:
        policy: the trained policy.
        decay: per-step decay in (0, 1).
    """

    FILE = "ema.safetensors"

    def __init__(self, policy: StudentPolicy, decay: float) -> None:
        self.decay = decay
        self.params = dict(policy.named_parameters())
        self.avg = {n: p.detach().clone() for n, p in self.params.items()}
        self.t = 0

    @torch.no_grad()
    def update(self) -> None:
        self.t += 1
        w = 1.0 - min(self.decay, (1.0 + self.t) / (10.0 + self.t))
        for n, p in self.params.items():
            self.avg[n].lerp_(p.detach(), w)

    @torch.no_grad()
    def apply(self) -> None:
        """Copy the averaged weights into the policy."""
        for n, p in self.params.items():
            p.copy_(self.avg[n])

    def save(self, directory: Path) -> None:
        save_file({n: v.contiguous() for n, v in self.avg.items()}, str(directory / self.FILE),
                  metadata={"t": str(self.t), "decay": repr(self.decay)})

    def load(self, directory: Path) -> None:
        path = directory / self.FILE
        if not path.is_file():
            raise CheckpointError(f"{directory}: no {self.FILE}, but this run averages weights "
                                  "(--ema_decay); resume with the --ema_decay it was started with")
        with safe_open(str(path), "pt", device="cpu") as f:
            meta = f.metadata() or {}
            if set(f.keys()) != set(self.avg):
                raise CheckpointError(f"{path}: its tensors are not this policy's parameters")
            for n in self.avg:
                self.avg[n].copy_(f.get_tensor(n))
        self.t = int(meta.get("t", 0))
