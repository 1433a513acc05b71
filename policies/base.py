"""The student-policy protocol shared by MSTA and the baselines.

A student reads a batch of raw sensor windows keyed by registry name
(``{"joint_pos": (B, T, 12), ...}``, oldest step first, optional ``"pad": (B, T)`` bool)
and returns desired joint positions ``(B, 12)``. Every student owns a processor (the
statistics it normalizes with) that is saved next to its weights; models never normalize.

Checkpoint layout (LeRobot-style), written by :meth:`StudentPolicy.save_pretrained`::

    <dir>/config.json         {"type": "<name>", ...config fields}
    <dir>/model.safetensors   weights
    <dir>/processor.json      the processor's statistics and settings (no pickle)

Loading a checkpoint from someone else is checked before anything is allocated: the JSON
files have size limits, the model ``config.json`` describes is built on PyTorch's ``meta``
device and its parameter count compared with :func:`param_limit` (``MSTA_MAX_PARAMS``,
default 100 M; the paper preset has 2.2 M), and the safetensors header (tensor names,
shapes, offsets, file size) must match that model. Every failure is a one-line
:class:`CheckpointError` naming the file.
"""

from __future__ import annotations

import json
import os
import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Protocol, Self, runtime_checkable

import draccus
import torch
import torch.nn.functional as F
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file
from torch import Tensor, nn

CONFIG_NAME = "config.json"
WEIGHTS_NAME = "model.safetensors"
PROCESSOR_NAME = "processor.json"
#: Largest config.json / processor.json read (bytes).
MAX_JSON_BYTES = {CONFIG_NAME: 1 << 20, PROCESSOR_NAME: 64 << 20}
#: Default limit on the parameters a loaded checkpoint may describe (MSTA_MAX_PARAMS).
DEFAULT_MAX_PARAMS = 100_000_000
_SAFETENSORS_DTYPES = {"F64": 8, "F32": 4, "F16": 2, "BF16": 2, "I64": 8, "I32": 4, "I16": 2,
                       "I8": 1, "U8": 1, "BOOL": 1}


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
        return json.loads(path.read_bytes())
    except (ValueError, UnicodeDecodeError) as e:
        raise CheckpointError(f"{path}: not valid JSON ({e})") from None


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

#: Per-sensor channel subsets: ``{"joint_pos": [0, 1, 2, 4, ...]}`` lists the channel
#: indices present in the batch tensor (in that order). Sensors not listed carry all channels.
Channels = Mapping[str, Sequence[int]]
#: Sensor name -> (B, T, c) window; tensors or numpy arrays (converted on the policy's device).
Batch = Mapping[str, Any]


@dataclass
class PolicyConfig(draccus.ChoiceRegistry):
    """Base of every student config. Subclasses register by name with
    ``@PolicyConfig.register_subclass("<name>")`` so draccus parses ``--policy.type=<name>``."""

    @property
    def type(self) -> str:
        return self.get_choice_name(self.__class__)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict including the registered ``type``."""
        return draccus.encode(self, PolicyConfig)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> PolicyConfig:
        """Build a config from a dict with a ``type`` key; unknown keys raise.

        Args:
            data: e.g. the content of ``config.json``.
        """
        if "type" not in data:
            raise ValueError(
                f"policy config has no 'type' key; known types: {sorted(cls.get_known_choices())}"
            )
        if data["type"] not in cls.get_known_choices():
            raise ValueError(
                f"unknown policy type {data['type']!r}; known: {sorted(cls.get_known_choices())}"
            )
        data = dict(data)
        legacy = getattr(cls.get_choice_class(data["type"]), "LEGACY_DEFAULTS", {})
        data.update({k: v for k, v in legacy.items() if k not in data})
        try:
            return draccus.decode(PolicyConfig, data)
        except draccus.utils.DecodingError as e:
            raise ValueError(f"invalid {data['type']!r} policy config: {e}") from None

    def save(self, directory: str | Path) -> Path:
        path = Path(directory) / CONFIG_NAME
        path.write_text(json.dumps(self.to_dict(), indent=2) + "\n")
        return path

    @classmethod
    def load(cls, directory: str | Path) -> PolicyConfig:
        """Read ``<directory>/config.json``; every error names the file."""
        path = Path(directory) / CONFIG_NAME
        if not path.is_file():
            raise FileNotFoundError(f"no {CONFIG_NAME} in {directory}")
        data = read_json_file(path)
        if not isinstance(data, dict):
            raise CheckpointError(f"{path}: expected a JSON object, got {type(data).__name__}")
        try:
            return cls.from_dict(data)
        except (ValueError, TypeError, KeyError) as e:
            raise CheckpointError(f"{path}: {e}") from None


@runtime_checkable
class Processor(Protocol):
    """Statistics owner of a student: raw batch -> model inputs, saved with the weights."""

    def to_dict(self) -> dict[str, Any]: ...

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Self: ...


@runtime_checkable
class Policy(Protocol):
    """What rollout, training and evaluation rely on for any student."""

    config: PolicyConfig

    @property
    def required_sensors(self) -> tuple[str, ...]:
        """Registry names the policy reads (MSTA also accepts any subset of them)."""
        ...

    def act(self, batch: Batch, channels: Channels | None = None) -> Tensor:
        """Raw sensor windows -> desired joint positions (B, 12), no gradient."""
        ...

    def loss(
        self, batch: Batch, channels: Channels | None = None
    ) -> tuple[Tensor, dict[str, float]]:
        """Batch with an ``"action"`` target (B, 12) -> (scalar loss, metrics)."""
        ...

    def save_pretrained(self, directory: str | Path) -> Path: ...


def resolve_pretrained(path_or_repo_id: str | Path, revision: str | None = None) -> Path:
    """A local checkpoint directory for ``path_or_repo_id``.

    Args:
        path_or_repo_id: a local directory, or a hub id ``user/name[@revision]`` pulled
            (once per commit, hash-verified) through ``msta_data.hub.materialize`` from
            ``HF_ENDPOINT``.
        revision: hub revision (branch, tag or commit) when the id carries none.
    """
    from msta_data.locate import locate

    spec = str(path_or_repo_id)
    if revision and "@" not in spec and not Path(spec).expanduser().exists():
        spec = f"{spec}@{revision}"
    path = locate(spec, "model", "checkpoint")
    if not path.is_dir():
        raise CheckpointError(f"{path}: not a checkpoint directory")
    return path


class StudentPolicy(nn.Module):
    """Shared save / load for students: config + processor + weights.

    Subclasses set ``config_class`` and ``processor_class`` and build their modules in
    ``__init__(config, processor)``.
    """

    config_class: ClassVar[type[PolicyConfig]]
    processor_class: ClassVar[type]

    def __init__(self, config: PolicyConfig, processor: Any) -> None:
        super().__init__()
        self.config = config
        self.processor = processor

    @property
    def device(self) -> torch.device:
        return next(self.parameters()).device

    def as_tensors(self, batch: Mapping[str, Any]) -> dict[str, Tensor]:
        """Numpy arrays or tensors -> tensors on the policy's device (no copy when possible).

        Args:
            batch: e.g. ``WindowDataset.get_batch`` output or a rollout's observations.
        """
        device = self.device
        return {k: torch.as_tensor(v).to(device, non_blocking=True) for k, v in batch.items()}

    def resolve_mask_ratio(self, mask_ratio: float | None) -> float:
        """``None`` -> the config's ratio in training mode, 0 in eval mode; checked range."""
        if mask_ratio is None:
            mask_ratio = self.config.mask_ratio if self.training else 0.0
        if not 0.0 <= mask_ratio < 1.0:
            raise ValueError(f"mask_ratio must be in [0, 1), got {mask_ratio}")
        return mask_ratio

    @torch.no_grad()
    def act(
        self,
        batch: Batch,
        channels: Channels | None = None,
        mask_ratio: float = 0.0,
        generator: torch.Generator | None = None,
    ) -> Tensor:
        """Desired joint positions (B, 12) in raw units.

        Args:
            batch: sensor name -> (B, T, c) raw windows (any subset of required_sensors,
                any T), optional "pad" (B, T).
            channels: per-sensor channel subsets present, e.g. {"joint_pos": [0, 1, 3]}.
            mask_ratio: test-time random input removal (the paper's 25 % / 50 % tests);
                what "removal" means is the subclass's ``forward`` (MSTA drops tokens,
                timestep baselines substitute placeholders).
            generator: RNG for the test-time mask.
        """
        return self.processor.unnormalize_action(self(batch, channels, mask_ratio, generator))

    def loss(
        self,
        batch: Batch,
        channels: Channels | None = None,
        mask_ratio: float | None = None,
        generator: torch.Generator | None = None,
    ) -> tuple[Tensor, dict[str, float]]:
        """MSE between predicted and target actions in the processor's target space.

        Args:
            batch: as :meth:`act`, plus the target under ``config.action_key``: (B, 12).
            channels, mask_ratio, generator: as the subclass's ``forward``.
        """
        key = self.config.action_key
        if key not in batch:
            raise KeyError(f"batch has no target {key!r}; keys: {sorted(batch)}")
        batch = self.as_tensors(batch)
        target = self.processor.normalize_target(batch[key])  # (B, A)
        pred = self(batch, channels, mask_ratio, generator)  # (B, A)
        loss = F.mse_loss(pred, target)
        with torch.no_grad():
            raw = F.mse_loss(self.processor.unnormalize_action(pred.float()), batch[key].float())
        return loss, {"loss": float(loss.detach()), "action_mse": float(raw)}

    def save_pretrained(self, directory: str | Path) -> Path:
        """Write config.json, model.safetensors and processor.json into ``directory``.

        Args:
            directory: created if missing; existing files of the same names are replaced.
        """
        out = Path(directory)
        out.mkdir(parents=True, exist_ok=True)
        self.config.save(out)
        state = {k: v.detach().contiguous().cpu() for k, v in self.state_dict().items()}
        save_file(state, str(out / WEIGHTS_NAME), metadata={"type": self.config.type})
        (out / PROCESSOR_NAME).write_text(json.dumps(self.processor.to_dict(), indent=1) + "\n")
        return out

    @classmethod
    def from_pretrained(
        cls,
        path_or_repo_id: str | Path,
        revision: str | None = None,
        device: str | torch.device = "cpu",
        max_params: int | None = None,
    ) -> Self:
        """Load a checkpoint written by :meth:`save_pretrained` (checked: module docstring).

        Args:
            path_or_repo_id: checkpoint directory, or hub id ``user/name[@revision]``.
            revision: hub revision (branch, tag or commit) for repo ids.
            device: where to put the weights.
            max_params: refuse configs describing more parameters (default
                :func:`param_limit`: ``MSTA_MAX_PARAMS`` or 100 M).

        Raises:
            CheckpointError: a malformed, oversized or mismatched file (named).
        """
        directory = resolve_pretrained(path_or_repo_id, revision)
        config = PolicyConfig.load(directory)
        if not isinstance(config, cls.config_class):
            raise TypeError(f"{directory} holds a {config.type!r} policy, not {cls.__name__}")
        proc_path = directory / PROCESSOR_NAME
        if not proc_path.is_file():
            raise FileNotFoundError(f"no {PROCESSOR_NAME} in {directory}")
        try:
            processor = cls.processor_class.from_dict(read_json_file(proc_path))
        except (ValueError, TypeError, KeyError, AttributeError) as e:
            raise CheckpointError(f"{proc_path}: {type(e).__name__}: {e}") from None
        limit = max_params if max_params is not None else param_limit()
        config_path = directory / CONFIG_NAME
        try:
            with torch.device("meta"):  # sizes only: nothing is allocated
                n = sum(t.numel() for t in cls(config, processor).state_dict().values())
        except (ValueError, TypeError, KeyError, RuntimeError) as e:
            raise CheckpointError(f"{config_path}: cannot build the model it describes "
                                  f"({type(e).__name__}: {e})") from None
        if n > limit:
            raise CheckpointError(
                f"{config_path}: describes a {n:,}-parameter {config.type} model, more than "
                f"the limit of {limit:,} (set MSTA_MAX_PARAMS or pass max_params to load it)")
        weights = directory / WEIGHTS_NAME
        if not weights.is_file():
            raise FileNotFoundError(f"no {WEIGHTS_NAME} in {directory}")
        policy = cls(config, processor)
        load_weights(policy, weights)
        return policy.to(device).eval()
