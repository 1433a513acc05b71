"""The student-policy protocol shared by MSTA and the baselines.

A student reads a batch of raw sensor windows keyed by registry name
(``{"joint_pos": (B, T, 12), ...}``, oldest step first, optional ``"pad": (B, T)`` bool)
and returns desired joint positions ``(B, 12)``. Every student owns a processor (the
statistics it normalizes with) that is saved next to its weights; models never normalize.

Checkpoint layout (LeRobot-style), written by :meth:`StudentPolicy.save_pretrained`::

    <dir>/config.json         {"type": "<name>", ...config fields}
    <dir>/model.safetensors   weights
    <dir>/processor.json      the processor's statistics and settings (no pickle)
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Protocol, Self, runtime_checkable

import draccus
import torch
import torch.nn.functional as F
from safetensors.torch import load_file, save_file
from torch import Tensor, nn

CONFIG_NAME = "config.json"
WEIGHTS_NAME = "model.safetensors"
PROCESSOR_NAME = "processor.json"

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
        path = Path(directory) / CONFIG_NAME
        if not path.is_file():
            raise FileNotFoundError(f"no {CONFIG_NAME} in {directory}")
        return cls.from_dict(json.loads(path.read_text()))


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
    path = Path(path_or_repo_id)
    if path.is_dir():
        return path
    spec = str(path_or_repo_id)
    from msta_data.hub import is_hub_id, materialize

    if not is_hub_id(spec):
        raise FileNotFoundError(f"checkpoint directory {spec!r} does not exist (and it is not "
                                f"a hub id user/name[@revision])")
    if revision and "@" not in spec:
        spec = f"{spec}@{revision}"
    try:
        return materialize(spec, repo_type="model")
    except Exception as exc:  # network, auth, missing repo: say both readings failed
        import os

        raise FileNotFoundError(
            f"{spec!r} is neither an existing checkpoint directory nor a hub repo reachable at "
            f"HF_ENDPOINT={os.environ.get('HF_ENDPOINT', '(huggingface_hub default)')}: "
            f"{type(exc).__name__}: {exc}") from exc


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
    ) -> Self:
        """Load a checkpoint written by :meth:`save_pretrained`.

        Args:
            path_or_repo_id: checkpoint directory (hub repo ids later).
            revision: hub revision (branch, tag or commit) for repo ids.
            device: where to put the weights.
        """
        directory = resolve_pretrained(path_or_repo_id, revision)
        config = PolicyConfig.load(directory)
        if not isinstance(config, cls.config_class):
            raise TypeError(f"{directory} holds a {config.type!r} policy, not {cls.__name__}")
        proc_path = directory / PROCESSOR_NAME
        if not proc_path.is_file():
            raise FileNotFoundError(f"no {PROCESSOR_NAME} in {directory}")
        processor = cls.processor_class.from_dict(json.loads(proc_path.read_text()))
        policy = cls(config, processor)
        weights = directory / WEIGHTS_NAME
        if not weights.is_file():
            raise FileNotFoundError(f"no {WEIGHTS_NAME} in {directory}")
        policy.load_state_dict(load_file(str(weights)), strict=True)
        return policy.to(device).eval()
