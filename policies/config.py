"""The config every student starts from: the fields all students have, checked once.

:class:`PolicyConfig` is a draccus choice type: a student's config subclasses it and is
registered under the policy's name by :func:`msta.policies.registry.register_policy`, so
``--policy.type=<name>`` selects it and ``config.json`` records it as ``"type"``. The fields
declared here (sensors, window length, mask ratio, action target, presets, the robots it was
trained on) exist on every student config, so code handed any student reads
``config.history`` directly.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, ClassVar, Self

import draccus

from msta.data import sensors
from msta.data.robot import LEGACY_ROBOT
from msta.policies.checkpoint import (
    CONFIG_NAME,
    CheckpointError,
    is_lerobot_checkpoint,
    read_json_file,
)

#: The longest window a student reads (steps): a window of 100,000 steps asked for 5 GB
#: before training began.
MAX_HISTORY = 250


def check_positive(**values: float) -> None:
    """Raise ``ValueError("<name> must be > 0, got <value>")`` for the first value <= 0."""
    for key, value in values.items():
        if not value > 0:
            raise ValueError(f"{key} must be > 0, got {value}")


def check_fraction(**values: float) -> None:
    """Raise ``ValueError("<name> must be in [0, 1), got <value>")`` for the first value
    outside [0, 1) (mask ratios, dropout)."""
    for key, value in values.items():
        if not 0.0 <= value < 1.0:
            raise ValueError(f"{key} must be in [0, 1), got {value}")


def check_student_sensors(names: tuple[str, ...]) -> None:
    """Non-empty, no duplicates, every name a registered non-privileged sensor."""
    if not names:
        raise ValueError("input_sensors is empty")
    if len(set(names)) != len(names):
        raise ValueError(f"input_sensors has duplicates: {names}")
    for name in names:
        if not sensors.get(name).is_student_input:  # get(): KeyError lists known sensors
            raise ValueError(f"sensor {name!r} is privileged (teacher only), not a student input")


def check_robot_names(names: tuple[str, ...]) -> None:
    """Non-empty, no duplicates, every name a non-empty printable text (``robots``)."""
    if not names or len(set(names)) != len(names):
        raise ValueError(f"robots must name one robot or more, each once, got {list(names)}")
    bad = [n for n in names if not isinstance(n, str) or not n.strip() or not n.isprintable()]
    if bad:
        raise ValueError(f"robots: {str(bad[0])[:80]!r} is not a robot's name")


def check_trained_on(robots: tuple[str, ...], robot: str, what: str, option: str) -> None:
    """One-line ``ValueError`` unless a student trained on ``robots`` (its config's) may run
    ``robot``.

    Args:
        robots: the student's robots (``PolicyConfig.robots``).
        robot: the name of the robot that would be simulated.
        what: the checkpoint, as the message names it (``--policy.path=<dir>``).
        option: the option that chose ``robot`` (``--env.robot``, ``--robot``).
    """
    if robot not in robots:
        trained = ", ".join(repr(r) for r in robots)
        which = f"robot {trained}" if len(robots) == 1 else f"robots {trained}"
        pick = "the" if len(robots) == 1 else "one of the"
        raise ValueError(f"{what} was trained on {which}, not {robot!r} ({option}): give "
                         f"{option} {pick} {which}, or a checkpoint trained on {robot!r}")


@dataclass
class PolicyConfig(draccus.ChoiceRegistry):
    """Base of every student config (the fields below are shared by all of them).

    Args:
        input_sensors: registry names the student reads, in its input order.
        history: window length T used in training (msta, gru, tert_* and rma_tcn with
            readout=mean accept other T at inference; mlp and rma_tcn's flatten do not).
        clip_std: z-scored inputs are clipped to [-clip_std, clip_std] (MSTA's bins cover
            that range).
        mask_ratio: fraction of the inputs hidden per sample during training (MSTA
            removes tokens, the timestep baselines substitute learnable placeholders).
        head_hidden_dim: hidden width of the action head (0: a linear head).
        action_key: dataset column of the target action.
        action_dim: number of joint targets.
        normalize_action: train on z-scored actions (the processor maps back).
        robots: names of the robots whose datasets trained the student
            (``RobotDescription.name``); training writes them (msta-train: the dataset's robot,
            a value given is replaced), msta-correct and msta-eval refuse another robot. A
            config.json without the field: the A1.
    """

    #: Preset name -> field overrides of the defaults (``--policy.preset=<name>``).
    PRESETS: ClassVar[dict[str, dict[str, Any]]] = {"paper": {}}
    #: A config.json written before a field existed means that field's value here
    #: (checkpoints saved then keep loading with the shapes and init they were trained with).
    LEGACY_DEFAULTS: ClassVar[dict[str, Any]] = {}

    input_sensors: tuple[str, ...] = sensors.STUDENT_SENSORS
    history: int = 15
    clip_std: float = 4.0
    mask_ratio: float = 0.0
    head_hidden_dim: int = 128
    action_key: str = "action"
    action_dim: int = sensors.ACTION_DIM
    normalize_action: bool = True
    robots: tuple[str, ...] = (LEGACY_ROBOT,)

    def __post_init__(self) -> None:
        self.input_sensors = tuple(self.input_sensors)
        check_student_sensors(self.input_sensors)
        self.robots = tuple(self.robots)
        check_robot_names(self.robots)
        check_positive(history=self.history, clip_std=self.clip_std, action_dim=self.action_dim)
        if not self.history <= MAX_HISTORY:
            raise ValueError(f"history must be <= {MAX_HISTORY} steps ({MAX_HISTORY // 50} s at "
                             f"50 Hz; the paper's students read 15), got {self.history}")
        if self.head_hidden_dim < 0:
            raise ValueError(f"head_hidden_dim must be >= 0, got {self.head_hidden_dim}")
        check_fraction(mask_ratio=self.mask_ratio)

    @property
    def type(self) -> str:
        return self.get_choice_name(self.__class__)

    @classmethod
    def from_preset(cls, name: str, **overrides: Any) -> Self:
        """A named preset with optional field overrides.

        Args:
            name: a key of the class's ``PRESETS`` (``paper``, ``cpu``, ``tiny``).
            overrides: field values replacing the preset's.
        """
        if name not in cls.PRESETS:
            known = cls.get_known_choices()
            label = next((k for k, v in known.items() if v is cls), cls.__name__)
            raise KeyError(f"unknown {label} preset {name!r}; known presets: {sorted(cls.PRESETS)}")
        return replace(cls(**cls.PRESETS[name]), **overrides)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict including the registered ``type``."""
        return draccus.encode(self, PolicyConfig)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> PolicyConfig:
        """Build a config from a dict with a ``type`` key; unknown keys and values that fail
        the checks raise ValueError.

        Args:
            data: e.g. the content of ``config.json``.
        """
        known = PolicyConfig.get_known_choices()
        if "type" not in data:
            raise ValueError(f"policy config has no 'type' key; known types: {sorted(known)}")
        if data["type"] not in known:
            raise ValueError(f"unknown policy type {data['type']!r}; known: {sorted(known)}")
        data = dict(data)
        legacy = known[data["type"]].LEGACY_DEFAULTS
        data.update({k: v for k, v in legacy.items() if k not in data})
        try:
            return draccus.decode(PolicyConfig, data)
        except draccus.utils.DecodingError as e:
            raise ValueError(f"invalid {data['type']!r} policy config: {e}") from None
        except draccus.utils.ParsingError as e:  # a check of __post_init__ failed
            raise ValueError(f"invalid {data['type']!r} policy config: {e.__cause__ or e}"
                             ) from None

    def save(self, directory: str | Path) -> Path:
        """Write ``<directory>/config.json``."""
        path = Path(directory) / CONFIG_NAME
        path.write_text(json.dumps(self.to_dict(), indent=2) + "\n")
        return path

    @classmethod
    def load(cls, directory: str | Path) -> PolicyConfig:
        """Read ``<directory>/config.json``; every error names the file."""
        path = Path(directory) / CONFIG_NAME
        if not path.is_file():
            raise FileNotFoundError(f"no {CONFIG_NAME} in {directory}")
        if is_lerobot_checkpoint(path.parent):
            raise CheckpointError(f"{directory} is a LeRobot checkpoint: read its config with "
                                  "msta.policies.factory.load_config")
        data = read_json_file(path)
        if not isinstance(data, dict):
            raise CheckpointError(f"{path}: expected a JSON object, got {type(data).__name__}")
        try:
            return cls.from_dict(data)
        except (ValueError, TypeError, KeyError) as e:
            raise CheckpointError(f"{path}: {e}") from None
