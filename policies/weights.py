"""Model weights on disk and in memory: the safetensors check against a module's expected
shapes (before anything is loaded), loading them, and the revision of a module's weights.
torch is loaded here, not by :mod:`msta.policies.checkpoint`, which config readers import."""

from __future__ import annotations

import json
import os
import struct
from collections.abc import Mapping, Sequence
from pathlib import Path

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file
from torch import Tensor, nn

from msta.data.revision import content_revision
from msta.policies.checkpoint import CONFIG_NAME, CheckpointError

#: Default limit on the parameters a loaded checkpoint may describe (MSTA_MAX_PARAMS).
DEFAULT_MAX_PARAMS = 100_000_000
_SAFETENSORS_DTYPES = {"F64": 8, "F32": 4, "F16": 2, "BF16": 2, "I64": 8, "I32": 4, "I16": 2,
                       "I8": 1, "U8": 1, "BOOL": 1}


def param_limit() -> int:
    """The parameter limit for loaded checkpoints: ``MSTA_MAX_PARAMS`` or 100 M."""
    raw = os.environ.get("MSTA_MAX_PARAMS", "")
    try:
        return int(raw) if raw else DEFAULT_MAX_PARAMS
    except ValueError:
        raise ValueError(f"MSTA_MAX_PARAMS={raw!r} is not an integer") from None


def check_safetensors(path: Path, expected: Mapping[str, Tensor]) -> None:
    """Check a safetensors file's header against the tensors a model expects, reading only
    the header (a truncated file, a pickle under that name or other shapes fail here).

    Raises:
        CheckpointError: naming the file and the first problem.
    """
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    size = path.stat().st_size
    with open(path, "rb") as f:
        head = f.read(8)
        n = struct.unpack("<Q", head)[0] if len(head) == 8 else -1
        if not 0 < n <= min(size - 8, 100 << 20):
            raise CheckpointError(f"{path}: not a safetensors file (header length {n}, file "
                                  f"{size} bytes; truncated, or another format renamed?)")
        try:
            header = json.loads(f.read(n))
            tensors = {k: v for k, v in header.items() if k != "__metadata__"}
            spans = {k: (v["dtype"], [int(d) for d in v["shape"]], *map(int, v["data_offsets"]))
                     for k, v in tensors.items()}
        except (ValueError, UnicodeDecodeError, KeyError, TypeError, AttributeError) as e:
            raise CheckpointError(f"{path}: malformed safetensors header ({e})") from None
    body = size - 8 - n
    if max((end for *_, end in spans.values()), default=0) != body:
        raise CheckpointError(f"{path}: the header describes a different data size than the "
                              f"{body} bytes after it (truncated?)")
    missing = sorted(set(expected) - set(spans))
    extra = sorted(set(spans) - set(expected))
    if missing or extra:
        raise CheckpointError(f"{path}: tensors do not match the model of {CONFIG_NAME}: "
                              f"missing {missing[:5]}, unexpected {extra[:5]}")
    for k, (dtype, shape, start, end) in spans.items():
        width = _SAFETENSORS_DTYPES.get(dtype)
        want = list(expected[k].shape)
        if shape != want or width is None or end - start != width * _numel(shape):
            raise CheckpointError(f"{path}: tensor {k!r} is {dtype}{shape}, the model of "
                                  f"{CONFIG_NAME} has {want}")


def _numel(shape: Sequence[int]) -> int:
    n = 1
    for d in shape:
        n *= d
    return n


def load_weights(module: nn.Module, path: Path) -> None:
    """``module.load_state_dict`` from a safetensors file after :func:`check_safetensors`."""
    check_safetensors(path, module.state_dict())
    try:
        state = load_file(str(path), device=str(next(module.parameters()).device))
        module.load_state_dict(state, strict=True)
    except (SafetensorError, RuntimeError, OSError, ValueError) as e:  # one line, file named
        raise CheckpointError(f"{path}: cannot load ({type(e).__name__}: "
                              f"{str(e).splitlines()[0] if str(e) else ''})") from None


def weights_revision(policy: nn.Module) -> str:
    """``<type>-<12 hex>``: a hash of a student's weights in memory (names, dtypes, shapes,
    bytes; ``<type>`` its ``config.type``), the revision stage 2 records for the episodes a
    student drove. A checkpoint directory's is :func:`msta.data.revision.checkpoint_revision`
    (its files)."""
    parts: list[bytes | str] = []
    for name, t in sorted(policy.state_dict().items()):
        t = t.detach().cpu().contiguous()
        parts += [f"{name}:{t.dtype}:{tuple(t.shape)}",
                  t.view(torch.uint8).numpy().tobytes() if t.numel() else b""]
    return content_revision(parts, prefix=policy.config.type)
