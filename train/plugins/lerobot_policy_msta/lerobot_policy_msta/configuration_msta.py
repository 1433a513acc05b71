"""``--policy.type=msta`` for LeRobot: msta's MSTA config as a LeRobot ``PreTrainedConfig``.

:class:`MSTAConfig` is LeRobot's ``PreTrainedConfig`` *and* msta's own
:class:`msta.policies.msta.MSTAConfig` (it inherits every msta field, default and check), plus
what LeRobot's trainer needs: msta's presets (``--policy.preset=cpu``), the layout of
``observation.state`` (``state_sensors``, read from the dataset's feature names), msta-train's
training recipe as the optimizer and scheduler presets (AdamW with msta-train's decay groups,
linear warm-up then cosine: :class:`WarmupCosineSchedulerConfig`) and the CPU threads the
policy computes with. It asks LeRobot's dataset for one frame per sample
(``observation_delta_indices`` is None): the T-step windows come from msta's in-memory
reader (:mod:`lerobot_policy_msta.history`). :meth:`MSTAConfig.to_native` gives the plain
msta config (what msta's checkpoints store).
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass, fields
from typing import Any

from lerobot.configs import FeatureType, NormalizationMode, PolicyFeature, PreTrainedConfig
from lerobot.optim import AdamWConfig, LRSchedulerConfig
from lerobot.utils.constants import ACTION, OBS_STATE
from torch.optim import Optimizer
from torch.optim.lr_scheduler import LambdaLR

from msta.data import sensors
from msta.policies.msta import PRESETS
from msta.policies.msta import MSTAConfig as NativeMSTAConfig
from msta.train.config import LoopConfig
from msta.train.optim import WarmupCosine

#: msta-train's defaults (``msta.train.config.LoopConfig``), the presets below.
_LOOP = LoopConfig()
#: The fields msta's presets set (``msta.policies.msta.PRESETS``): declared ``None`` here, which
#: means "the preset's value, else msta's default" (a value given on the command line wins).
PRESET_FIELDS: tuple[str, ...] = tuple(sorted({k for p in PRESETS.values() for k in p}))
_NATIVE_DEFAULTS = {f.name: f.default for f in fields(NativeMSTAConfig)}


@LRSchedulerConfig.register_subclass("msta_warmup_cosine")
@dataclass
class WarmupCosineSchedulerConfig(LRSchedulerConfig):
    """msta-train's schedule (``msta.train.optim.WarmupCosine``): linear warm-up from 0 to the
    optimizer's lr over ``num_warmup_steps``, then a cosine down to ``lr * min_lr_ratio`` at
    the last training step."""

    num_warmup_steps: int = _LOOP.warmup_steps
    min_lr_ratio: float = _LOOP.min_lr_ratio

    def build(self, optimizer: Optimizer, num_training_steps: int) -> LambdaLR:
        return LambdaLR(optimizer, WarmupCosine(self.num_warmup_steps, num_training_steps,
                                                self.min_lr_ratio))


def state_layout(names: list[str]) -> tuple[str, ...]:
    """Sensors concatenated in ``observation.state``, from its channel names.

    Args:
        names: the feature's names, ``<sensor>.<channel>`` (``msta.data.derived``).

    Raises:
        ValueError: a name is not a registered sensor channel, or the channels of a sensor
            are not all there, contiguous and in registry order.
    """
    layout: list[str] = []
    i = 0
    while i < len(names):
        sensor = str(names[i]).split(".", 1)[0]
        if sensor not in sensors.SENSORS:
            raise ValueError(f"observation.state channel {names[i]!r} is not <sensor>.<channel> "
                             f"of a registered sensor (known: {sorted(sensors.SENSORS)})")
        spec = sensors.get(sensor)
        want = [f"{sensor}.{ch}" for ch in spec.names]
        if list(names[i:i + spec.dim]) != want:
            raise ValueError(f"observation.state holds part of sensor {sensor!r} at channel {i}: "
                             f"expected {want}")
        layout.append(sensor)
        i += spec.dim
    return tuple(layout)


@PreTrainedConfig.register_subclass("msta")
@dataclass
class MSTAConfig(PreTrainedConfig, NativeMSTAConfig):
    """The MSTA student for LeRobot (--policy.type=msta). It has every field of msta's own
    MSTAConfig (--policy.dim, --policy.mask_ratio, --policy.history, ...) with its default
    and checks; their descriptions are in `msta-train --help` (the same --policy.* options)
    and docs/msta_model.md. --policy.preset=cpu starts from msta's cpu preset (d 64, 2
    layers, 4 heads, a 256-wide head, 8 state tokens, sin-cos base 10, sensor tokens); the defaults are the
    paper preset.
    """

    preset: str = ""
    """msta's preset the model fields start from: cpu, paper or tiny (empty: msta's defaults,
    which are the paper preset); a field given as well (--policy.dim=...) wins."""
    dim: int | None = None
    """token width d (paper 128, cpu 64)."""
    num_layers: int | None = None
    """transformer blocks (paper 4, cpu 2)."""
    num_heads: int | None = None
    """attention heads; dim must be divisible by it (paper 4, cpu 4)."""
    head_hidden_dim: int | None = None
    """hidden width of the action head, 0: linear (paper 128, cpu 256)."""
    state_tokens: int | None = None
    """learnable readout tokens the head reads (paper 1, cpu 8)."""
    pos_base: float | None = None
    """base of the sin-cos frequencies (paper 10000, cpu 10)."""
    tokens: str | None = None
    """scalar: one token per reading (paper); sensor: one per sensor and step, removal still
    per reading (cpu)."""
    complete_share: float | None = None
    """sensor tokens: share of training samples that keep every reading (paper 0, cpu 0.25)."""
    state_sensors: tuple[str, ...] = sensors.STUDENT_SENSORS
    """sensors concatenated in observation.state, in order; lerobot-train reads them from the
    dataset's feature names (every msta dataset: the 7 student sensors, 49 scalars)."""
    num_threads: int = 0
    """torch CPU threads, set when the policy is built (lerobot-train, lerobot-eval); 0: half
    the CPU cores, at least 1 (1 on a 2-core machine, where two threads waiting on each
    other made a cpu-preset update, and lerobot-eval, several times slower), leaving the rest
    to data loading and the simulator."""
    optimizer_lr: float = _LOOP.lr
    """peak learning rate (AdamW), msta-train's --lr."""
    optimizer_weight_decay: float = _LOOP.weight_decay
    """AdamW decoupled weight decay on matrices (not biases, norms, embeddings), as
    msta-train's --weight_decay."""
    optimizer_grad_clip_norm: float = _LOOP.grad_clip
    """max global gradient norm, msta-train's --grad_clip."""
    scheduler_warmup_steps: int = _LOOP.warmup_steps
    """linear warm-up steps, then cosine decay (msta-train's --warmup_steps)."""
    scheduler_min_lr_ratio: float = _LOOP.min_lr_ratio
    """the cosine ends at lr * min_lr_ratio (msta-train's --min_lr_ratio)."""
    push_to_hub: bool = False
    """push the trained policy to the hub (needs --policy.repo_id)."""

    def __post_init__(self) -> None:
        try:
            self._check()
        except (ValueError, KeyError) as e:
            # draccus (lerobot-train's parser) keeps only "Couldn't instantiate class
            # MSTAConfig": msta's own line goes to stderr first
            print(f"msta policy: error: {e.args[0] if e.args else e}", file=sys.stderr)
            raise

    def _check(self) -> None:
        PreTrainedConfig.__post_init__(self)  # device, amp
        self.apply_preset()
        NativeMSTAConfig.__post_init__(self)  # msta's checks
        if self.num_threads < 0:
            raise ValueError(f"num_threads must be >= 0, got {self.num_threads}")
        self.state_sensors = tuple(self.state_sensors)
        for name in self.state_sensors:
            sensors.get(name)  # KeyError listing the known sensors
        missing = [s for s in self.input_sensors if s not in self.state_sensors]
        if missing:
            raise ValueError(f"input sensors {missing} are not in observation.state "
                             f"(state_sensors: {list(self.state_sensors)})")

    def apply_preset(self) -> None:
        """Fill the model fields left unset (None) from ``preset``, else msta's defaults."""
        if self.preset and self.preset not in PRESETS:
            raise ValueError(f"unknown msta preset {self.preset!r}; known presets: "
                             f"{sorted(PRESETS)}")
        values = PRESETS.get(self.preset, {})
        for name in PRESET_FIELDS:
            if getattr(self, name) is None:
                setattr(self, name, values.get(name, _NATIVE_DEFAULTS[name]))

    def cpu_threads(self) -> int:
        """The torch CPU threads the policy sets: ``num_threads``, or half the cores this
        process may use (at least 1) when it is 0."""
        if self.num_threads:
            return self.num_threads
        cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (
            os.cpu_count() or 1)
        return max(1, cores // 2)

    # --- what LeRobot's trainer asks ---------------------------------------------------
    @property
    def observation_delta_indices(self) -> None:
        """None: one frame per sample from LeRobot's dataset. LeRobot would window every
        ``observation.*`` column (it has no per-column setting), ~40 ms a sample on an msta
        dataset; the preprocessor's ``msta_history_processor`` step gathers the T-step window
        of ``observation.state`` from msta's in-memory reader instead
        (:mod:`lerobot_policy_msta.history`)."""
        return None

    @property
    def action_delta_indices(self) -> None:
        return None

    @property
    def reward_delta_indices(self) -> None:
        return None

    @property
    def normalization_mapping(self) -> dict[FeatureType, NormalizationMode]:
        """z-scores for the state (binary channels pass through: ``processor_msta``) and,
        with ``normalize_action``, the action."""
        action = NormalizationMode.MEAN_STD if self.normalize_action else NormalizationMode.IDENTITY
        return {FeatureType.STATE: NormalizationMode.MEAN_STD, FeatureType.ACTION: action}

    def get_optimizer_preset(self) -> AdamWConfig:
        return AdamWConfig(lr=self.optimizer_lr, betas=(0.9, 0.999), eps=1e-8,
                           weight_decay=self.optimizer_weight_decay,
                           grad_clip_norm=self.optimizer_grad_clip_norm)

    def get_scheduler_preset(self) -> WarmupCosineSchedulerConfig:
        return WarmupCosineSchedulerConfig(num_warmup_steps=self.scheduler_warmup_steps,
                                           min_lr_ratio=self.scheduler_min_lr_ratio)

    def set_dataset_feature_metadata(self, features: dict[str, dict[str, Any]]) -> None:
        """lerobot's ``make_policy`` hands over the dataset's features: the layout of
        ``observation.state`` comes from its channel names.

        Args:
            features: the dataset's ``info.json`` features.

        msta's default inputs that the dataset lacks (a robot without foot-contact switches)
        are left out, with one line on stderr, as msta-train does; other inputs must all be
        there.
        """
        if OBS_STATE not in features:
            raise ValueError(f"the dataset has no {OBS_STATE} (msta datasets of schema >= 2 "
                             "have it; append to an old one with msta-collect to add it)")
        self.state_sensors = state_layout(list(features[OBS_STATE]["names"]))
        missing = [n for n in self.input_sensors if n not in self.state_sensors]
        kept = tuple(n for n in self.input_sensors if n not in missing)
        if missing and kept and self.input_sensors == _NATIVE_DEFAULTS["input_sensors"]:
            # msta-train's rule: a robot without a default sensor (the Go1's foot contacts)
            print(f"msta policy: the dataset's {OBS_STATE} lacks {', '.join(missing)}: the "
                  f"student reads the default inputs it has, --policy.input_sensors="
                  f"[{','.join(kept)}]", file=sys.stderr, flush=True)
            self.input_sensors = kept
        self.__post_init__()

    def msta_features(self) -> tuple[dict[str, PolicyFeature], dict[str, PolicyFeature]]:
        """The features of an msta dataset for this config: ``observation.state`` of
        ``state_sensors`` in, a ``(action_dim,)`` action out."""
        return ({OBS_STATE: PolicyFeature(FeatureType.STATE,
                                          (sensors.total_dim(self.state_sensors),))},
                {ACTION: PolicyFeature(FeatureType.ACTION, (self.action_dim,))})

    def validate_features(self) -> None:
        """Keep only the inputs MSTA reads (``observation.state``; the command is in it) and
        check its size against ``state_sensors``. Without any features (a config.json
        written by msta itself) they are :meth:`msta_features`."""
        if not self.input_features and not self.output_features:  # a native msta config
            self.input_features, self.output_features = self.msta_features()
        feats = self.input_features or {}
        if OBS_STATE not in feats:
            raise ValueError(f"msta reads {OBS_STATE}; the inputs are {sorted(feats)}")
        want = sensors.total_dim(self.state_sensors)
        if tuple(feats[OBS_STATE].shape) != (want,):
            raise ValueError(f"{OBS_STATE} has shape {tuple(feats[OBS_STATE].shape)}, "
                             f"state_sensors {list(self.state_sensors)} make ({want},)")
        self.input_features = {OBS_STATE: feats[OBS_STATE]}
        act = (self.output_features or {}).get(ACTION)
        if act is None or tuple(act.shape) != (self.action_dim,):
            raise ValueError(f"msta predicts a ({self.action_dim},) {ACTION}; the outputs are "
                             f"{self.output_features}")

    # --- msta's side ---------------------------------------------------------------------
    def to_native(self) -> NativeMSTAConfig:
        """The same student as msta's own config (what an msta checkpoint's config.json
        holds)."""
        return NativeMSTAConfig(**{f.name: getattr(self, f.name)
                                   for f in fields(NativeMSTAConfig)})

    @classmethod
    def from_native(cls, native: NativeMSTAConfig, **lerobot_fields: Any) -> MSTAConfig:
        """A LeRobot config for msta's ``native`` config, with the standard msta features
        (``observation.state`` of ``state_sensors``, a 12-dim action).

        Args:
            native: msta's config (e.g. ``load_policy(path).config``).
            lerobot_fields: other fields of this class (device, state_sensors, ...).
        """
        values = {f.name: getattr(native, f.name) for f in fields(NativeMSTAConfig)}
        cfg = cls(**values, **lerobot_fields)
        cfg.input_features, cfg.output_features = cfg.msta_features()
        return cfg
