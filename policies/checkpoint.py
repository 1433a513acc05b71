"""Checkpoint files of a student: their names, size limits and the checks run on them.

Loading a checkpoint from someone else is checked before anything is allocated: the JSON
files have size limits (:data:`MAX_JSON_BYTES`), the model ``config.json`` describes is
built on PyTorch's ``meta`` device and its parameter count compared with
:func:`param_limit`, and the safetensors header (tensor names, shapes, offsets, file size)
must match that model (:func:`check_safetensors`). Every failure is a one-line
:class:`CheckpointError` naming the file.

A LeRobot checkpoint of ``--policy.type=msta`` (lerobot-train's ``pretrained_model/``, or
``python -m lerobot_policy_msta.convert``'s output) loads wherever an msta checkpoint does:
:func:`msta.policies.resolve.resolve_pretrained` gives an msta checkpoint made from it
(:mod:`msta.policies.lerobot_checkpoint`).
"""

from __future__ import annotations

import json
import os
import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file
from torch import Tensor, nn

from msta.data.revision import content_revision

CONFIG_NAME = "config.json"
WEIGHTS_NAME = "model.safetensors"
PROCESSOR_NAME = "processor.json"
#: Largest config.json / processor.json read (bytes).
MAX_JSON_BYTES = {CONFIG_NAME: 1 << 20, PROCESSOR_NAME: 64 << 20}
#: Default limit on the parameters a loaded checkpoint may describe (MSTA_MAX_PARAMS).
DEFAULT_MAX_PARAMS = 100_000_000
_SAFETENSORS_DTYPES = {"F64": 8, "F32": 4, "F16": 2, "BF16": 2, "I64": 8, "I32": 4, "I16": 2,
                       "I8": 1, "U8": 1, "BOOL": 1}


@dataclass
class PolicyPath:
    """A trained student to start from, as LeRobot names one: ``--policy.path=<checkpoint>``
    (``--policy.type`` is for a new one).

    Args:
        path: a student checkpoint directory (config.json + model.safetensors, e.g. a
            stage-1 ``final/``) or a hub id ``user/name[@revision]``.
    """

    path: str = ""


class CheckpointError(ValueError):
    """A checkpoint file is missing, unreadable, malformed or too large (file named)."""


def read_json_file(path: Path, limit: int | None = None) -> Any:
    """Parse a checkpoint JSON file with a size limit; errors name the file.

    Args:
        path: the file.
        limit: largest accepted size in bytes (default: ``MAX_JSON_BYTES`` by file name).
    """
    limit = limit or MAX_JSON_BYTES.get(path.name, 1 << 20)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    size = path.stat().st_size
    if size > limit:
        raise CheckpointError(f"{path}: {size:,} bytes, more than the {limit:,} accepted")
    try:
        data = json.loads(path.read_bytes())
    except (ValueError, UnicodeDecodeError) as e:
        raise CheckpointError(f"{path}: not valid JSON ({e})") from None
    return data


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


LEROBOT_PREPROCESSOR = "policy_preprocessor.json"


LEROBOT_POSTPROCESSOR = "policy_postprocessor.json"


def is_lerobot_checkpoint(directory: Path) -> bool:
    """Whether ``directory`` holds a LeRobot policy checkpoint (and not msta's files)."""
    return (directory / LEROBOT_PREPROCESSOR).is_file() and \
        not (directory / PROCESSOR_NAME).is_file()


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
