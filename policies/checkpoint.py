"""Checkpoint files of a student: their names, size limits and the checks run on them.

Loading a checkpoint from someone else is checked before anything is allocated: the JSON
files have size limits (:data:`MAX_JSON_BYTES`), the model ``config.json`` describes is
built on PyTorch's ``meta`` device and its parameter count compared with
:func:`msta.policies.weights.param_limit`, and the safetensors header (tensor names,
shapes, offsets, file size) must match that model
(:func:`msta.policies.weights.check_safetensors`). Every failure is a one-line
:class:`CheckpointError` naming the file.

A LeRobot checkpoint of ``--policy.type=msta`` (lerobot-train's ``pretrained_model/``, or
``python -m lerobot_policy_msta.convert``'s output) loads wherever an msta checkpoint does:
:func:`msta.policies.resolve.resolve_pretrained` gives an msta checkpoint made from it
(:mod:`msta.policies.lerobot_checkpoint`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

CONFIG_NAME = "config.json"
WEIGHTS_NAME = "model.safetensors"
PROCESSOR_NAME = "processor.json"
#: Largest config.json / processor.json read (bytes).
MAX_JSON_BYTES = {CONFIG_NAME: 1 << 20, PROCESSOR_NAME: 64 << 20}


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


LEROBOT_PREPROCESSOR = "policy_preprocessor.json"


LEROBOT_POSTPROCESSOR = "policy_postprocessor.json"


def is_lerobot_checkpoint(directory: Path) -> bool:
    """Whether ``directory`` holds a LeRobot policy checkpoint (and not msta's files)."""
    return (directory / LEROBOT_PREPROCESSOR).is_file() and \
        not (directory / PROCESSOR_NAME).is_file()


