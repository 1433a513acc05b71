"""One optimizer step and one validation pass, shared by stage 1 and stage 2.

Both stages train the same way (behaviour cloning on teacher labels, ‖a − â‖²); they
differ only in where the data comes from and in the mask ratio.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
import torch

from msta.data.sensors import PHYSICAL_SENSORS, get
from msta.policies.base import StudentPolicy
from msta.policies.processor import Channels


def train_step(policy: StudentPolicy, optimizer: torch.optim.Optimizer,
               scheduler: torch.optim.lr_scheduler.LRScheduler | None,
               batch: Mapping[str, Any], grad_clip: float, mask_ratio: float | None,
               generator: torch.Generator | None = None,
               channels: Channels | None = None, dummy_tokens: int = 0,
               loss_fn: Callable[..., tuple[torch.Tensor, dict[str, float]]] | None = None,
               absent: Mapping[str, torch.Tensor] | None = None) -> dict[str, float]:
    """Forward, backward, clip, AdamW step, scheduler step.

    Args:
        policy: a student with ``loss(batch, channels, mask_ratio, generator)``.
        optimizer: over the policy's parameters.
        scheduler: stepped once after the optimizer (None: constant LR).
        batch: raw windows plus the ``action`` target (numpy or tensors).
        grad_clip: max global gradient norm; 0 disables clipping (the norm is still reported).
        mask_ratio: token-removal ratio (None: the policy config's).
        generator: RNG of the random token removal (on the policy's device).
        channels: per-sensor channel subsets present in the batch.
        dummy_tokens: random dummy tokens appended to every sample (token students only).
        loss_fn: called instead of ``policy.loss`` with the same arguments (under torchrun:
            the policy's loss inside DistributedDataParallel, :mod:`msta.train.ddp`).
        absent: per-sample channel removal (:func:`draw_sensor_dropout`; students with
            ``supports_absent`` only).

    Returns:
        the policy's metrics (``loss``, ``action_mse``, ...) plus ``grad_norm`` and ``lr``
        (the learning rate this step used).

    Raises:
        FloatingPointError: the loss or the gradient norm is not finite (weights untouched).
    """
    policy.train()
    fn = policy.loss if loss_fn is None else loss_fn
    if absent is not None:
        loss, metrics = fn(batch, channels, mask_ratio, generator, dummy_tokens, absent)
    elif dummy_tokens:
        loss, metrics = fn(batch, channels, mask_ratio, generator, dummy_tokens)
    else:
        loss, metrics = fn(batch, channels, mask_ratio, generator)
    if not torch.isfinite(loss):
        raise FloatingPointError(f"training loss is {float(loss.detach())}; metrics {metrics} "
                                 "(a smaller --lr may help)")
    optimizer.zero_grad(set_to_none=True)
    loss.backward()
    params = [p for g in optimizer.param_groups for p in g["params"] if p.grad is not None]
    norm = torch.nn.utils.clip_grad_norm_(params, grad_clip if grad_clip > 0 else math.inf)
    if not torch.isfinite(norm):
        optimizer.zero_grad(set_to_none=True)
        raise FloatingPointError(f"gradient norm is {float(norm)} (loss {float(loss)})")
    lr = float(optimizer.param_groups[0]["lr"])
    optimizer.step()
    if scheduler is not None:
        scheduler.step()
    return {**metrics, "grad_norm": float(norm), "lr": lr}


def draw_sensor_dropout(policy: StudentPolicy, batch_size: int, rate: float,
                        generator: torch.Generator) -> dict[str, torch.Tensor] | None:
    """Whole sensors removed per training sample: each sample loses, with probability
    ``rate``, every channel of one of the student's physical sensors (joint angles, joint
    velocities, gyro, gravity, foot contacts; uniformly chosen) for its whole window, as
    msta-eval's ``sensor_removal`` removes one at test time. Returns ``absent`` for
    :meth:`StudentPolicy.loss` (sensor -> (B, dim) bool), or None when no sample lost one.
    The draws come from ``generator`` (the run's mask generator: seeded, and resumed with
    it)."""
    sensors = [s for s in policy.required_sensors if s in PHYSICAL_SENSORS]
    if rate <= 0 or not sensors:
        return None
    dev = generator.device
    hit = torch.rand(batch_size, generator=generator, device=dev) < rate  # (B,)
    pick = torch.randint(len(sensors), (batch_size,), generator=generator, device=dev)
    if not bool(hit.any()):
        return None
    return {s: (hit & (pick == i))[:, None].expand(batch_size, get(s).dim).to(policy.device)
            for i, s in enumerate(sensors)}


def batch_absent(dataset: Any, indices: np.ndarray,
                 dropout: Mapping[str, torch.Tensor] | None = None
                 ) -> dict[str, torch.Tensor] | None:
    """The channels removed from a batch: those of the samples whose dataset does not record
    them (a :class:`~msta.data.window_union.WindowUnion`'s ``absent_of``; a single dataset has
    none) joined with ``dropout``'s (:func:`draw_sensor_dropout`); None when nothing is."""
    fn = getattr(dataset, "absent_of", None)
    got = fn(indices) if fn is not None else None
    if got is None:
        return dict(dropout) if dropout else None
    out = {s: torch.from_numpy(m) for s, m in got.items()}
    for s, m in (dropout or {}).items():
        out[s] = out[s].to(m.device) | m if s in out else m
    return out


def draw_step_mask(mask_ratio: float, unmasked_share: float,
                   generator: torch.Generator) -> float:
    """This step's training mask: 0 (every token) with probability ``unmasked_share``, else
    ``mask_ratio``; the draw comes from ``generator`` (the run's mask generator) only when
    ``unmasked_share`` > 0."""
    if unmasked_share and float(torch.rand((), generator=generator,
                                           device=generator.device)) < unmasked_share:
        return 0.0
    return mask_ratio


@torch.no_grad()
def validate(policy: StudentPolicy, dataset: Any, batch_size: int, max_samples: int,
             mask_ratio: float, seed: int = 0) -> dict[str, float]:
    """Mean loss over a fixed, evenly spaced subset of a window dataset.

    The masked loss uses its own generator seeded with ``seed``, so validation never
    touches the training RNG streams and is comparable across steps.

    Args:
        policy: the student (switched to eval mode and back to train mode).
        dataset: a ``WindowDataset`` (``len`` and ``get_batch``).
        batch_size: windows per forward pass.
        max_samples: at most this many windows.
        mask_ratio: the training mask ratio (``loss``); ``loss_unmasked`` uses 0.

    Returns:
        ``{"loss", "loss_unmasked", "action_mse"}`` (``action_mse`` is unmasked, raw units).
    """
    n = len(dataset)
    idx = np.unique(np.linspace(0, n - 1, min(n, max_samples)).round().astype(np.int64))
    gen = torch.Generator(device=policy.device).manual_seed(seed)
    sums = {"loss": 0.0, "loss_unmasked": 0.0, "action_mse": 0.0}
    policy.eval()
    try:
        for lo in range(0, len(idx), batch_size):
            part = idx[lo:lo + batch_size]
            batch = dataset.get_batch(part)
            gone = {"absent": a} if (a := batch_absent(dataset, part)) else {}
            _, m0 = policy.loss(batch, mask_ratio=0.0, **gone)
            _, mm = policy.loss(batch, mask_ratio=mask_ratio, generator=gen, **gone)
            sums["loss"] += mm["loss"] * len(part)
            sums["loss_unmasked"] += m0["loss"] * len(part)
            sums["action_mse"] += m0["action_mse"] * len(part)
    finally:
        policy.train()
    return {k: v / len(idx) for k, v in sums.items()}
