"""The student-policy protocol shared by MSTA and the baselines.

A student reads a batch of raw sensor windows keyed by registry name
(``{"joint_pos": (B, T, 12), ...}``, oldest step first, optional ``"pad": (B, T)`` bool)
and returns desired joint positions ``(B, 12)``. Every student owns a processor (the
statistics it normalizes with) that is saved next to its weights; models never normalize.

Checkpoint layout (LeRobot-style), written by :meth:`StudentPolicy.save_pretrained`::

    <dir>/config.json         {"type": "<name>", ...config fields}
    <dir>/model.safetensors   weights
    <dir>/processor.json      the processor's statistics and settings (no pickle)

Loading a checkpoint from someone else is checked before anything is allocated (file size
limits, a parameter limit, the safetensors header against the model; one-line
:class:`CheckpointError` naming the file): :mod:`msta.policies.checkpoint` holds those checks,
:mod:`msta.policies.config` the config every student starts from; the names students and
trainers use from both are re-exported here.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any, ClassVar, Protocol, Self, runtime_checkable

import torch
import torch.nn.functional as F
from safetensors.torch import save_file
from torch import Tensor, nn

from msta.data.sensors import get as get_sensor
from msta.policies.checkpoint import (
    CONFIG_NAME,
    PROCESSOR_NAME,
    WEIGHTS_NAME,
    CheckpointError,
    read_json_file,
)
from msta.policies.config import PolicyConfig, check_fraction
from msta.policies.processor import Batch, Channels, StudentProcessor
from msta.policies.resolve import resolve_pretrained
from msta.policies.weights import load_weights, param_limit

#: Per-sample channel removal: sensor name -> (B, dim) bool over the sensor's full channels
#: (tensor or numpy), True = removed at every step of that sample's window.
Absent = Mapping[str, Any]

__all__ = [
    "CONFIG_NAME", "PROCESSOR_NAME", "WEIGHTS_NAME", "Absent", "Batch", "Channels", "CheckpointError",
    "Policy", "PolicyConfig", "Processor", "StudentPolicy", "StudentProcessor", "load_weights",
    "uniform",
]


def uniform(B: int, N: int, generator: torch.Generator | None, device: torch.device) -> Tensor:
    """(B, N) uniforms in [0, 1) for random input removal, drawn on the generator's device
    (``device`` without one) and moved to ``device``: a CPU generator (StudentActor's)
    drives a policy on CUDA, and the same seed removes the same inputs on either device."""
    gen_dev = generator.device if generator is not None else device
    return torch.rand(B, N, generator=generator, device=gen_dev).to(device)


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


class StudentPolicy(nn.Module):
    """Shared save / load for students: config + processor + weights.

    Subclasses set ``config_class`` and ``processor_class`` and build their modules in
    ``__init__(config, processor)``.

    Args:
        config: the student's config (a registered :class:`PolicyConfig`).
        processor: its processor, built for the same input sensors.
    """

    config_class: ClassVar[type[PolicyConfig]]
    processor_class: ClassVar[type[StudentProcessor]]
    #: whether ``forward`` takes ``dummy_tokens`` (token students: MSTA); msta-eval's
    #: dummy_tokens scenario is not applicable to the others
    supports_dummy_tokens: ClassVar[bool] = False
    #: whether ``act`` / ``forward`` / ``loss`` take ``absent`` (per-sample channel removal,
    #: :meth:`absent_masks`); the others raise ``NotImplementedError`` when it is given
    supports_absent: ClassVar[bool] = False

    def check_dummy_tokens(self, n: int) -> None:
        """Raise ``NotImplementedError`` when ``n`` > 0 dummy tokens are asked of a student
        without token inputs (msta-eval reports that condition as not applicable)."""
        if n and not self.supports_dummy_tokens:
            raise NotImplementedError(f"{type(self).__name__} has no token input to append "
                                      "dummy tokens to (MSTA students only)")

    def check_absent(self) -> None:
        """Raise ``NotImplementedError`` for a student that cannot remove channels per
        sample (``supports_absent`` False)."""
        if not self.supports_absent:
            raise NotImplementedError(f"{type(self).__name__} cannot remove channels per sample")

    def absent_masks(self, absent: Absent | None, batch_size: int) -> dict[str, Tensor] | None:
        """Checked per-sample channel removal: sensor -> (B, dim) bool on the policy's device,
        True = that sample's channel is removed at every step of its window. ``dim`` counts
        the sensor's full channels (registry order), whatever ``channels`` the batch has.
        None when nothing is removed (``absent`` None or all False): the student then acts
        exactly as without it.

        Raises:
            NotImplementedError: the student cannot remove channels per sample.
            ValueError: an unknown / non-input sensor, or a mask of the wrong shape or dtype.
        """
        if absent is None:
            return None
        self.check_absent()
        out = {}
        for name, mask in absent.items():
            self.processor._check_input_sensor(name)
            mask = torch.as_tensor(mask).to(self.device)
            shape = (batch_size, get_sensor(name).dim)
            if mask.dtype != torch.bool or tuple(mask.shape) != shape:
                raise ValueError(f"absent[{name!r}] must be a bool array of shape {shape}, got "
                                 f"{mask.dtype} {tuple(mask.shape)}")
            out[name] = mask
        return out if any(bool(m.any()) for m in out.values()) else None

    def __init__(self, config: PolicyConfig, processor: StudentProcessor) -> None:
        super().__init__()
        if tuple(processor.input_sensors) != tuple(config.input_sensors):
            raise ValueError(
                f"processor sensors {processor.input_sensors} != config {config.input_sensors}"
            )
        self.config = config
        self.processor = processor

    @property
    def required_sensors(self) -> tuple[str, ...]:
        """Registry names the policy reads (any subset of them is accepted)."""
        return self.config.input_sensors

    @property
    def target_columns(self) -> tuple[str, ...]:
        """Dataset columns training reads at the window's newest step besides the inputs:
        the action target (a student may add its own, e.g. MSTA's ``aux_target``)."""
        return (self.config.action_key,)

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
        check_fraction(mask_ratio=mask_ratio)
        return mask_ratio

    @torch.no_grad()
    def act(
        self,
        batch: Batch,
        channels: Channels | None = None,
        mask_ratio: float = 0.0,
        generator: torch.Generator | None = None,
        dummy_tokens: int = 0,
        absent: Absent | None = None,
    ) -> Tensor:
        """Desired joint positions (B, 12) in raw units.

        Args:
            batch: sensor name -> (B, T, c) raw windows (any subset of required_sensors,
                any T), optional "pad" (B, T).
            channels: per-sensor channel subsets present, e.g. {"joint_pos": [0, 1, 3]}.
            mask_ratio: test-time random input removal (the paper's 25 % / 50 % tests);
                what "removal" means is the subclass's ``forward`` (MSTA drops tokens,
                timestep baselines substitute placeholders).
            generator: RNG for the test-time mask (and the dummy tokens).
            dummy_tokens: random tokens appended to every sample (the paper's stress test);
                only students with ``supports_dummy_tokens`` take them.
            absent: sensor -> (B, dim) bool over the sensor's full channels: True removes
                that sample's channel at every step of its window, as ``channels`` would
                remove it for the whole batch (:meth:`absent_masks`; students with
                ``supports_absent`` only). ``mask_ratio`` then removes its fraction of each
                sample's remaining inputs.
        """
        return self.processor.unnormalize_action(
            self._predict(batch, channels, mask_ratio, generator, dummy_tokens, absent))

    def _predict(self, batch: Batch, channels: Channels | None, mask_ratio: float | None,
                 generator: torch.Generator | None, dummy_tokens: int,
                 absent: Absent | None) -> Tensor:
        """``forward`` with only the optional inputs that are used (a student without
        dummy tokens or per-sample removal never sees those arguments)."""
        kwargs: dict[str, Any] = {}
        if dummy_tokens:
            self.check_dummy_tokens(dummy_tokens)
            kwargs["dummy_tokens"] = dummy_tokens
        if absent is not None:
            self.check_absent()
            kwargs["absent"] = absent
        return self(batch, channels, mask_ratio, generator, **kwargs)

    def loss(
        self,
        batch: Batch,
        channels: Channels | None = None,
        mask_ratio: float | None = None,
        generator: torch.Generator | None = None,
        dummy_tokens: int = 0,
        absent: Absent | None = None,
    ) -> tuple[Tensor, dict[str, float]]:
        """MSE between predicted and target actions in the processor's target space.

        Args:
            batch: as :meth:`act`, plus the target under ``config.action_key``: (B, 12).
            channels, mask_ratio, generator: as the subclass's ``forward``.
            dummy_tokens: random tokens appended to every sample (training with the
                stress test's distractors; students with ``supports_dummy_tokens`` only).
            absent: per-sample channel removal, as :meth:`act`.
        """
        key = self.config.action_key
        if key not in batch:
            raise KeyError(f"batch has no target {key!r}; keys: {sorted(batch)}")
        batch = self.as_tensors(batch)
        pred = self._predict(batch, channels, mask_ratio, generator, dummy_tokens, absent)
        return self.action_loss(pred, batch[key])

    def action_loss(self, pred: Tensor, action: Tensor) -> tuple[Tensor, dict[str, float]]:
        """MSE of model-space predictions ``pred`` (B, A) against the raw target ``action``
        (B, A) in the processor's target space, and the metrics ``loss`` and
        ``action_mse`` (raw units)."""
        loss = F.mse_loss(pred, self.processor.normalize_target(action))
        with torch.no_grad():
            raw = F.mse_loss(self.processor.unnormalize_action(pred.float()), action.float())
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
        directory = resolve_pretrained(path_or_repo_id, revision, policy_class=lambda _: cls)
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
