"""``meta/msta.json``: msta's own metadata of a dataset (schema version, recorded sensors,
provenance columns) and the settings each recording session used.

``robot`` is the name of the robot the dataset's episodes simulated
(``RobotDescription.name``, also ``info.json``'s ``robot_type``); a dataset written before it
was recorded has none and counts as the A1 (:data:`~msta.data.robot.LEGACY_ROBOT`).
:func:`dataset_robot` reads it; :func:`check_robot` refuses another robot in one line.

``recordings`` is a list of blocks, one per change of settings, each ``{"from_episode": k,
<settings>}``: an episode ``e`` that msta-collect recorded was recorded with the last block
whose ``from_episode`` is at most ``e`` (stage 2's appended episodes, ``provenance/source``
``student``, are described by their provenance columns alone). ``msta-collect`` writes the
settings a session records with (teacher and its revision, episode length, terrains and
levels, action noise); ``--resume`` compares them with the dataset's and refuses a
difference unless mixing is asked for, when a new block starts at the first new episode. A dataset recorded before the blocks existed has none: only its
episodes' provenance (the teacher) can be compared.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from msta.data import features as F
from msta.data import layout as L
from msta.data.errors import DatasetFormatError
from msta.data.lerobot_edits import derive_msta_meta, is_rewritten
from msta.data.robot import LEGACY_ROBOT

RECORDINGS = "recordings"
#: ``meta/msta.json``'s key of the simulated robot's name.
ROBOT = "robot"


def read_msta_meta(root: Path, info: dict[str, Any]) -> dict[str, Any]:
    """``meta/msta.json``, checked against the schema version and ``info.json``'s features."""
    msta_path = root / L.MSTA_META_PATH
    try:
        msta_meta = json.loads(msta_path.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise DatasetFormatError(f"{msta_path}: cannot read ({e})") from e
    if not isinstance(msta_meta, dict) or not isinstance(msta_meta.get("sensors"), list):
        raise DatasetFormatError(f"{msta_path}: not an msta metadata object")
    version = msta_meta.get("msta_schema_version")
    if version not in F.SCHEMA_VERSIONS:
        raise DatasetFormatError(
            f"{msta_path}: msta_schema_version {version!r}, expected one of "
            f"{list(F.SCHEMA_VERSIONS)}")
    expected = F.build_features(msta_meta["sensors"], derived=version >= 2)
    if info["features"] != expected:
        bad = sorted(k for k in set(expected) | set(info["features"])
                     if expected.get(k) != info["features"].get(k))
        raise DatasetFormatError(f"{root / L.INFO_PATH}: features differ from the msta "
                                 f"schema in columns {bad}")
    blocks = msta_meta.get(RECORDINGS, [])
    if not isinstance(blocks, list) or not all(
            isinstance(b, dict) and isinstance(b.get("from_episode"), int) for b in blocks):
        raise DatasetFormatError(f"{msta_path}: '{RECORDINGS}' must be a list of objects with "
                                 "an integer 'from_episode'")
    robot = msta_meta.get(ROBOT, LEGACY_ROBOT)
    if not isinstance(robot, str) or not robot.strip() or not robot.isprintable():
        raise DatasetFormatError(f"{msta_path}: '{ROBOT}' must be a robot's name, got "
                                 f"{str(robot)[:80]!r}")
    return msta_meta


def meta_robot(msta_meta: dict[str, Any]) -> str:
    """The robot a dataset's ``meta/msta.json`` content records (the A1 when it records none)."""
    return str(msta_meta.get(ROBOT, LEGACY_ROBOT))


def dataset_robot(root: str | Path) -> str:
    """The name of the robot whose episodes the dataset at ``root`` holds: ``meta/msta.json``'s
    ``robot``; the A1 for a dataset written before robots were recorded; for a dataset
    LeRobot's tools rewrote (no msta.json), ``info.json``'s ``robot_type``
    (:func:`~msta.data.lerobot_edits.derive_msta_meta`).

    Raises:
        DatasetFormatError: the metadata cannot be read or is not msta's (file named).
    """
    root = Path(root)
    info = F.load_info(root)
    meta = derive_msta_meta(root, info) if is_rewritten(root) else read_msta_meta(root, info)
    return meta_robot(meta)


def check_robot(recorded: str, robot: str, what: str, option: str) -> None:
    """One-line ``ValueError`` unless the dataset's robot ``recorded`` is ``robot``.

    Args:
        recorded: the dataset's robot (:func:`dataset_robot`).
        robot: the robot that would be simulated or appended.
        what: the dataset, as the message names it (its root).
        option: the option that chose ``robot`` (``--env.robot``).
    """
    if recorded != robot:
        raise ValueError(f"{what} holds episodes of robot {recorded!r}, not {robot!r} "
                         f"({option}): give {option} the robot {recorded!r}, or choose a "
                         f"dataset of {robot!r}")


def recorded_settings(msta_meta: dict[str, Any], episodes: int) -> dict[str, Any] | None:
    """The settings of the last block that covers one of the first ``episodes`` episodes
    (without ``from_episode``), or None when the dataset records none."""
    blocks = [b for b in msta_meta.get(RECORDINGS, []) if b["from_episode"] < episodes]
    return _settings(blocks[-1]) if blocks else None


def _settings(block: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in block.items() if k != "from_episode"}


def differences(recorded: dict[str, Any], wanted: dict[str, Any]) -> list[str]:
    """``"<setting> <recorded> -> <wanted>"`` for each setting that differs (JSON values)."""
    out = []
    for key in sorted(set(recorded) | set(wanted)):
        a, b = recorded.get(key), json.loads(json.dumps(wanted.get(key)))
        if a != b:
            out.append(f"{key} {json.dumps(a)} -> {json.dumps(b)}")
    return out


def add_recording(msta_meta: dict[str, Any], start: int, settings: dict[str, Any]) -> bool:
    """Record that episodes from ``start`` on are recorded with ``settings``; blocks of a
    killed session beyond the committed episodes go. Returns whether ``msta_meta`` changed."""
    settings = json.loads(json.dumps(settings))
    old = list(msta_meta.get(RECORDINGS, []))
    blocks = [b for b in old if b["from_episode"] < start]
    if not (blocks and _settings(blocks[-1]) == settings):
        blocks.append({"from_episode": int(start), **settings})
    msta_meta[RECORDINGS] = blocks
    return blocks != old
