"""Convert MSTA checkpoints between msta's format and LeRobot's, both ways.

Both formats hold the same ``model.*`` tensors (one ``MSTATransformer`` named ``model``),
so a conversion copies the weights and moves the statistics:

- msta: ``config.json`` (msta's config), ``model.safetensors``, ``processor.json`` (per-sensor
  and action mean / std);
- LeRobot: ``config.json`` (LeRobot's ``MSTAConfig``: msta's fields plus LeRobot's),
  ``model.safetensors``, ``policy_preprocessor.json`` + its normalizer's ``.safetensors``
  (``observation.state`` mean / std), ``policy_postprocessor.json`` + its unnormalizer's
  (action mean / std).

Actions are bit-identical across a conversion (msta computes in float32, LeRobot stores
float32; ``tests/train/test_lerobot_policy_plugin.py`` round-trips both ways). msta's own
loaders read a LeRobot MSTA checkpoint directly (:mod:`msta.policies.lerobot_checkpoint`, which
the LeRobot -> msta direction calls), so this command only writes that conversion down::

    python -m lerobot_policy_msta.convert --policy.path=outputs/stage1/final --output_dir=outputs/lerobot/msta_stage1
    python -m lerobot_policy_msta.convert --policy.path=outputs/lerobot/msta/checkpoints/last/pretrained_model --output_dir=outputs/msta_from_lerobot

The direction follows the input (a directory or a hub id): one with ``processor.json`` is
msta's, one with ``policy_preprocessor.json`` is LeRobot's.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lerobot.utils.constants import ACTION, OBS_STATE

from lerobot_policy_msta.configuration_msta import MSTAConfig
from lerobot_policy_msta.modeling_msta import MSTAPolicy
from lerobot_policy_msta.processor_msta import make_msta_pre_post_processors
from msta.data import sensors
from msta.data.cli import parse_config
from msta.data.locate import locate_checkpoint
from msta.policies.checkpoint import (
    LEROBOT_PREPROCESSOR,
    PROCESSOR_NAME,
    PolicyPath,
    is_lerobot_checkpoint,
)
from msta.policies.factory import load_policy
from msta.policies.msta import MSTAPolicy as NativeMSTAPolicy

PREPROCESSOR_FILE = LEROBOT_PREPROCESSOR  # lerobot's POLICY_PREPROCESSOR_DEFAULT_NAME + .json


def checkpoint_format(path: str | Path) -> str:
    """``"msta"`` or ``"lerobot"`` for a checkpoint directory (or an msta hub id).

    Raises:
        FileNotFoundError: no such directory, or neither kind of processor file in it.
    """
    directory = locate_checkpoint(str(path), "--policy.path")  # a directory or a hub id
    if (directory / PROCESSOR_NAME).is_file():
        return "msta"
    if (directory / PREPROCESSOR_FILE).is_file():
        return "lerobot"
    raise FileNotFoundError(f"{directory} is neither an msta checkpoint ({PROCESSOR_NAME}) nor "
                            f"a LeRobot one ({PREPROCESSOR_FILE})")


def _new_dir(path: str | Path) -> Path:
    out = Path(path)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise FileExistsError(f"{out} exists and is not empty; choose another --output_dir")
    out.mkdir(parents=True, exist_ok=True)
    return out


# ----- msta -> LeRobot -------------------------------------------------------------------
def msta_to_lerobot(src: str | Path, dst: str | Path, device: str = "cpu") -> Path:
    """Write msta checkpoint ``src`` as a LeRobot checkpoint in ``dst``.

    Args:
        src: an msta checkpoint directory (or hub id) of an ``msta`` student.
        dst: new or empty directory (lerobot-eval's ``--policy.path``).
        device: the ``device`` the LeRobot config records.
    """
    native = load_policy(src)
    if not isinstance(native, NativeMSTAPolicy):
        raise TypeError(f"{src} holds a {native.config.type!r} student; only msta converts")
    cfg = MSTAConfig.from_native(native.config, device=device)
    policy = MSTAPolicy(cfg)
    policy.model.load_state_dict(native.model.state_dict())
    pre, post = make_msta_pre_post_processors(cfg, dataset_stats=lerobot_stats(native, cfg))
    out = _new_dir(dst)
    policy.save_pretrained(out)
    pre.save_pretrained(out)
    post.save_pretrained(out)
    return out


def lerobot_stats(native: NativeMSTAPolicy, cfg: MSTAConfig) -> dict[str, dict[str, Any]]:
    """A native processor's statistics laid out as a dataset's ``observation.state`` / action
    statistics (channels the student does not read, and binary ones: mean 0, std 1)."""
    mean: list[float] = []
    std: list[float] = []
    for name in cfg.state_sensors:
        spec = sensors.get(name)
        s = native.processor.stats.get(spec.column) if name in cfg.input_sensors else None
        mean += s["mean"] if s else [0.0] * spec.dim
        std += s["std"] if s else [1.0] * spec.dim
    out = {OBS_STATE: {"mean": mean, "std": std}}
    if cfg.normalize_action:
        out[ACTION] = native.processor.stats[cfg.action_key]
    return out


# ----- LeRobot -> msta -------------------------------------------------------------------
def lerobot_to_msta(src: str | Path, dst: str | Path) -> Path:
    """Write LeRobot MSTA checkpoint ``src`` (e.g. lerobot-train's ``pretrained_model/``) as an
    msta checkpoint in ``dst``. msta's loaders read such a checkpoint directly
    (:mod:`msta.policies.lerobot_checkpoint`, which this calls), so msta's commands need no
    conversion; this writes the result down.

    Args:
        src: a LeRobot checkpoint directory (or hub id) of ``--policy.type=msta``.
        dst: new or empty directory.
    """
    directory = locate_checkpoint(str(src), "--policy.path")
    if not is_lerobot_checkpoint(directory):
        raise FileNotFoundError(f"{directory} is not a LeRobot checkpoint (no "
                                f"{PREPROCESSOR_FILE})")
    native = load_policy(directory)
    return native.save_pretrained(_new_dir(dst))


# ----- command line ----------------------------------------------------------------------
@dataclass
class ConvertConfig:
    """Args:
        policy: the checkpoint to convert (``--policy.path``): an msta checkpoint directory
            or hub id becomes a LeRobot checkpoint; a LeRobot msta checkpoint (lerobot-train's
            ``pretrained_model/``) becomes an msta one.
        output_dir: the new checkpoint's directory (new, or empty).
    """

    policy: PolicyPath = field(default_factory=PolicyPath)
    output_dir: str = ""

    def __post_init__(self) -> None:
        if not self.policy.path:
            raise ValueError("--policy.path is required")
        if not self.output_dir:
            raise ValueError("--output_dir is required")


def convert(cfg: ConvertConfig) -> Path:
    """Convert ``cfg.policy.path`` into ``cfg.output_dir`` in the other format."""
    if checkpoint_format(cfg.policy.path) == "msta":
        return msta_to_lerobot(cfg.policy.path, cfg.output_dir)
    return lerobot_to_msta(cfg.policy.path, cfg.output_dir)


def main(argv: Sequence[str] | None = None) -> None:
    prog = "python -m lerobot_policy_msta.convert"
    cfg = parse_config(ConvertConfig, argv, prog)
    try:
        kind = checkpoint_format(cfg.policy.path)
        out = convert(cfg)
    except (ValueError, TypeError, KeyError, FileNotFoundError, FileExistsError) as e:
        raise SystemExit(f"{prog}: error: {e}") from None
    other = "LeRobot" if kind == "msta" else "msta"
    print(f"converted the {kind} checkpoint {cfg.policy.path} -> {other} checkpoint {out}",
          file=sys.stdout)


if __name__ == "__main__":
    main()
