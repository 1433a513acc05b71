"""LeRobot checkpoints of the MSTA student, read by msta's own loaders (no LeRobot import).

``lerobot-train --policy.type=msta`` (the plugin in ``train/plugins/lerobot_policy_msta``)
writes LeRobot's layout, and ``python -m lerobot_policy_msta.convert`` writes it from an
msta checkpoint:

- ``config.json``: LeRobot's MSTA config, msta's fields plus LeRobot's (``state_sensors``,
  ``device``, the optimizer's, ...);
- ``model.safetensors``: the same ``model.*`` tensors an msta checkpoint holds;
- ``policy_preprocessor.json`` and its ``normalizer_processor`` step's ``.safetensors``: the
  mean / std of ``observation.state`` (the ``state_sensors`` concatenated);
- ``policy_postprocessor.json`` and its ``unnormalizer_processor`` step's: the action's.

msta's layout is ``config.json`` (msta's fields), ``model.safetensors`` and
``processor.json`` (per-sensor statistics). :func:`msta_config_dict` reads the first
``config.json`` as the second, and :func:`as_msta_checkpoint` makes the msta checkpoint of a
LeRobot one, the conversion ``python -m lerobot_policy_msta.convert`` does (it calls this):
the statistics move from slices of ``observation.state`` to their sensors, the weights are
linked, not copied. It is made once per process in a temporary directory deleted at exit,
so ``msta-eval``, ``msta-export``, ``msta-correct`` and every loader take lerobot-train's
``pretrained_model/`` as they take an msta checkpoint, with the same checks (sizes,
parameter limit, tensor names and shapes) and bit-identical actions.
"""

from __future__ import annotations

import atexit
import json
import os
import shutil
import tempfile
from collections.abc import Callable
from dataclasses import fields
from pathlib import Path
from typing import Any

from safetensors import SafetensorError

from msta.data import sensors
from msta.data.inside import PathOutsideRootError, inside
from msta.policies.checkpoint import (
    CONFIG_NAME,
    LEROBOT_POSTPROCESSOR,
    LEROBOT_PREPROCESSOR,
    MAX_JSON_BYTES,
    PROCESSOR_NAME,
    WEIGHTS_NAME,
    CheckpointError,
    is_lerobot_checkpoint,
    read_json_file,
)
from msta.policies.config import PolicyConfig

#: lerobot-train's run directory keeps the last checkpoint here.
LEROBOT_LAST = Path("checkpoints") / "last" / "pretrained_model"
#: Files of a LeRobot checkpoint the msta checkpoint made from it does not take over.
_NOT_LINKED = {CONFIG_NAME, PROCESSOR_NAME, "train_config.json"}
#: (source directory, its files' sizes and times) -> the msta checkpoint made from it.
_MADE: dict[tuple[str, tuple[tuple[str, int, int], ...]], Path] = {}


def msta_config_dict(data: dict[str, Any], path: Path, config_class: type) -> dict[str, Any]:
    """The msta config a LeRobot checkpoint's ``config.json`` holds: its msta fields.

    Args:
        data: the parsed file.
        path: the file (for messages).
        config_class: msta's config class of the student (its fields are kept).

    Raises:
        CheckpointError: the checkpoint is of another LeRobot policy type.
    """
    kind = data.get("type")
    if kind != "msta":
        raise CheckpointError(f"{path.parent} is a LeRobot {kind!r} policy checkpoint; msta's "
                              "tools load msta students (LeRobot checkpoints of "
                              "--policy.type=msta load as they are)")
    names = {f.name for f in fields(config_class)}
    return {"type": "msta", **{k: v for k, v in data.items() if k in names}}


def _step_stats(directory: Path, pipeline: str, step_name: str, key: str, dim: int
                ) -> dict[str, list[float]]:
    """mean / std of ``key`` in the ``step_name`` step of a saved LeRobot pipeline."""
    path = directory / pipeline
    spec = read_json_file(path)
    steps = spec.get("steps") if isinstance(spec, dict) else None
    step = next((s for s in steps if isinstance(s, dict) and s.get("registry_name") == step_name),
                None) if isinstance(steps, list) else None
    if step is None:
        raise CheckpointError(f"{path}: no {step_name} step")
    eps = (step.get("config") or {}).get("eps")
    if eps != 0.0:
        raise CheckpointError(f"{path}: {step_name} has eps={eps}; msta divides by the std "
                              "alone (eps=0), so the student's actions would differ")
    name = str(step.get("state_file", ""))
    if "\x00" in name or Path(name).name != name or name in ("", ".", ".."):
        raise CheckpointError(f"{path}: {step_name}'s state_file {name[:80]!r} must be a file "
                              "name in the checkpoint folder (no folder, no '..')")
    try:
        state = inside(directory, name, what="checkpoint")
    except PathOutsideRootError as e:
        raise CheckpointError(str(e)) from None
    if not state.is_file() or state.stat().st_size > MAX_JSON_BYTES[PROCESSOR_NAME]:
        raise CheckpointError(f"{state}: missing or larger than "
                              f"{MAX_JSON_BYTES[PROCESSOR_NAME]:,} bytes")
    # lazy: torch loads only when a LeRobot checkpoint is read (not for a command's --help)
    from safetensors.torch import load_file

    try:
        tensors = load_file(str(state))
    except (SafetensorError, OSError) as e:
        raise CheckpointError(f"{state}: cannot load ({e})") from None
    out = {}
    for stat in ("mean", "std"):
        t = tensors.get(f"{key}.{stat}")
        if t is None or tuple(t.shape) != (dim,):
            raise CheckpointError(f"{state}: no {key}.{stat} of shape ({dim},)")
        out[stat] = t.float().tolist()
    return out


def msta_stats(directory: Path, config_class: type) -> dict[str, dict[str, list[float]]]:
    """msta's per-sensor (and action) statistics of a LeRobot msta checkpoint: the input
    sensors' slices of the ``observation.state`` normalizer, the action unnormalizer's
    (``config_class``: as :func:`msta_config_dict`'s)."""
    raw = read_json_file(directory / CONFIG_NAME)
    config = msta_config_dict(raw, directory / CONFIG_NAME, config_class)
    layout = raw.get("state_sensors", sensors.STUDENT_SENSORS)
    try:
        dims = {name: sensors.get(name).dim for name in layout}
    except (KeyError, TypeError) as e:
        raise CheckpointError(f"{directory / CONFIG_NAME}: state_sensors: {e}") from None
    state = _step_stats(directory, LEROBOT_PREPROCESSOR, "normalizer_processor",
                        "observation.state", sum(dims.values()))
    offsets, start = {}, 0
    for name, dim in dims.items():
        offsets[name], start = (start, start + dim), start + dim
    stats = {}
    for name in config.get("input_sensors", sensors.STUDENT_SENSORS):
        if name not in offsets:
            raise CheckpointError(f"{directory / CONFIG_NAME}: input sensor {name!r} is not in "
                                  f"state_sensors {list(layout)}")
        a, b = offsets[name]
        stats[sensors.get(name).column] = {k: v[a:b] for k, v in state.items()}
    if config.get("normalize_action", True):
        stats[config.get("action_key", "action")] = _step_stats(
            directory, LEROBOT_POSTPROCESSOR, "unnormalizer_processor", "action",
            int(config.get("action_dim", sensors.ACTION_DIM)))
    return stats


def _signature(directory: Path) -> tuple[tuple[str, int, int], ...]:
    return tuple((f.name, f.stat().st_size, f.stat().st_mtime_ns)
                 for f in sorted(directory.iterdir()) if f.is_file())


def as_msta_checkpoint(directory: Path, policy_class: Callable[[str], Any]) -> Path:
    """``directory`` itself, or for a LeRobot msta checkpoint the msta checkpoint made from
    it (module docstring; made once per process, deleted at exit).

    Args:
        directory: a checkpoint directory.
        policy_class: policy name -> the registered student class (its ``config_class`` and
            ``processor_class`` read a LeRobot checkpoint; :func:`msta.policies.factory
            .get_policy_class`).

    Raises:
        CheckpointError: a LeRobot checkpoint of another policy type or with missing or
            malformed statistics; a lerobot-train run directory (its checkpoint is named).
    """
    if not is_lerobot_checkpoint(directory):
        if not (directory / CONFIG_NAME).is_file() and \
                (directory / LEROBOT_LAST / LEROBOT_PREPROCESSOR).is_file():
            raise CheckpointError(f"{directory} is a lerobot-train run directory; its last "
                                  f"checkpoint is {directory / LEROBOT_LAST}")
        return directory
    key = (str(directory.resolve()), _signature(directory))
    if key in _MADE and _MADE[key].is_dir():
        return _MADE[key]
    path = directory / CONFIG_NAME
    raw = read_json_file(path)
    if not isinstance(raw, dict):
        raise CheckpointError(f"{path}: expected a JSON object, got {type(raw).__name__}")
    cls = policy_class("msta")  # msta_config_dict refuses the other types
    try:
        config = PolicyConfig.from_dict(msta_config_dict(raw, path, cls.config_class))
    except (ValueError, TypeError, KeyError) as e:
        raise CheckpointError(f"{path}: {e}") from None
    processor = cls.processor_class.from_stats(config, msta_stats(directory, cls.config_class))
    parent = Path(tempfile.mkdtemp(prefix="msta-lerobot-"))
    atexit.register(shutil.rmtree, parent, ignore_errors=True)
    out = parent / directory.name
    out.mkdir()
    config.save(out)
    (out / PROCESSOR_NAME).write_text(json.dumps(processor.to_dict(), indent=1) + "\n")
    for f in directory.iterdir():  # the weights, a guard, ...: linked
        if f.is_file() and f.name not in _NOT_LINKED and not f.name.startswith("policy_"):
            try:
                os.symlink(f.resolve(), out / f.name)
            except OSError:
                shutil.copyfile(f, out / f.name)
    if not (out / WEIGHTS_NAME).exists():
        raise FileNotFoundError(f"no {WEIGHTS_NAME} in {directory}")
    _MADE[key] = out
    return out
