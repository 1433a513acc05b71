"""The dummy tokens of the paper's stress test (:mod:`msta.policies.msta.modeling_msta`'s
docstring says what they are): drawn from a model's own value tables, positions and sensor
types, so each part looks like a real token's."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch
from torch import Tensor

from msta.policies.msta.processor_msta import MSTAInputs


def draw_dummy_tokens(model: Any, inputs: MSTAInputs, pos: Tensor, sensor: Tensor,
                      B: int, dummy: int | Tensor, generator: torch.Generator | None
                      ) -> tuple[Tensor, Tensor]:
    """D random tokens per sample of an ``MSTATransformer`` ``model``: (B, D, d), drawn from
    ``generator`` (``dummy`` = D) or given by uniforms (``dummy``: (B, D, 4)), from the value
    tables of the present channels, the layout's positions ``pos`` and the present sensors'
    types ``sensor``, and the layout slot (B, D) whose position each took. Nothing is trained."""
    dev = model.bin_embed.weight.device
    if not inputs.channels:
        raise ValueError("dummy tokens draw their values from the value tables of scalar "
                         "inputs; this sample has none")
    nb = model.cfg.num_bins
    tables = torch.unique(torch.cat([  # (tables,) value tables of the present channels
        model.table_of(n, c.to(dev)) for n, c in inputs.channels.items()]))
    draw = dummy_draw(B, dummy, generator, dev)
    rows = tables[draw(len(tables), 0)] * nb + draw(nb, 1)  # (B, D) rows of bin_embed
    slot = draw(len(pos), 2)  # (B, D)
    with torch.no_grad():
        return model.bin_embed(rows) + pos[slot] + sensor[draw(len(sensor), 3)], slot


def dummy_draw(B: int, dummy: int | Tensor, generator: torch.Generator | None,
               device: torch.device) -> Callable[[int, int], Tensor]:
    """``draw(high, k)``: the k-th of a dummy token's random choices, (B, D) long in
    [0, high), on ``device``; drawn from ``generator`` (``dummy`` = D) or read from given
    uniforms (``dummy``: (B, D, 4), choice k from column k)."""
    if isinstance(dummy, Tensor):
        if dummy.dim() != 3 or dummy.shape[0] != B or dummy.shape[2] != 4:
            raise ValueError(f"dummy token draws must be (batch={B}, D, 4) uniforms in "
                             f"[0, 1), got {tuple(dummy.shape)}")
        u = dummy.to(device, torch.float32)

        def given(high: int, k: int) -> Tensor:  # (B, D) in [0, high) from given uniforms
            return (u[..., k] * high).long().clamp_(0, high - 1)
        return given
    gen_dev = generator.device if generator is not None else device

    def drawn(high: int, k: int) -> Tensor:  # (B, D) uniform in [0, high)
        return torch.randint(high, (B, dummy), generator=generator, device=gen_dev).to(device)
    return drawn
