"""Datasets that LeRobot's own tools rewrote: what they write differently, and msta's metadata
re-derived from LeRobot's.

``lerobot-edit-dataset`` (``delete_episodes``, ``split``, ``merge``, ...) writes a new dataset
directory from LeRobot's files alone (an in-place edit first moves the original to
``<root>_old``): ``meta/info.json``, ``meta/stats.json``, ``meta/tasks.parquet``, the episode
table and the data files. msta's own files are not carried over: ``meta/msta.json`` (schema
version and sensors), the checksum manifest ``meta/msta_checksums.json`` and the card
``README.md``. ``delete_episodes`` and ``split`` also keep only LeRobot's episode columns, so
the ``provenance/*`` columns are gone; ``merge`` keeps them (empty for a source without them)
and writes its vectors as variable-length lists (``list<float>``) instead of fixed-size ones.

:meth:`msta.data.writer.DatasetWriter.open` (``msta-collect --resume``, stage 2's append) takes
a dataset with neither ``meta/msta.json`` nor a manifest as rewritten by LeRobot and, after
the structural checks every dataset without a manifest gets, re-derives:

* ``meta/msta.json`` (:func:`derive_msta_meta`): the sensors are the registry sensors whose
  columns ``info.json`` declares, schema 2 when it has the derived columns (1 without);
  ``info.json``'s features must be exactly that schema's, else it is not an msta dataset and
  nothing is changed. The repo id is ``local/<the root's name>``: LeRobot records none. The
  robot is ``info.json``'s ``robot_type`` (which LeRobot's tools keep and msta writes as the
  robot's name), the A1 when it holds no name.
* the ``provenance/*`` columns where an episode file lacks them or a merge left them empty
  (:func:`provenance_fixes`): the terrain from the episode's task text (``a1 locomotion on
  <terrain>``), every other field :data:`UNKNOWN` (``"unknown"``, or -1 for numbers): nothing on
  disk records them any more;
* then, as for any dataset without a manifest: ``meta/stats.json`` from the per-episode
  statistics, the manifest and the card.

Readers accept the variable-length vectors of a merge where every row holds the feature's
length (:func:`~msta.data.integrity.fixed_size`).
"""

from __future__ import annotations

import json
import logging
import math
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from msta.data import derived as D
from msta.data import features as F
from msta.data import layout as L
from msta.data import sensors as registry
from msta.data.errors import DatasetFormatError
from msta.data.integrity import FileRecord
from msta.data.robot import LEGACY_ROBOT

logger = logging.getLogger(__name__)

#: Provenance a LeRobot edit dropped: text fields say this, number fields -1.
UNKNOWN = "unknown"


def is_rewritten(root: str | Path) -> bool:
    """True for a dataset without ``meta/msta.json`` and without a checksum manifest: written
    (or rewritten) by LeRobot's tools rather than by msta."""
    root = Path(root)
    return not (root / L.MSTA_META_PATH).exists() and not (root / L.MANIFEST_PATH).exists()


def derive_msta_meta(root: str | Path, info: dict[str, Any]) -> dict[str, Any]:
    """``meta/msta.json``'s content for a LeRobot-rewritten dataset (module docstring).

    Raises:
        DatasetFormatError: ``info.json``'s features are not those of any msta schema for the
            sensors it declares (the columns that differ named).
    """
    root = Path(root)
    feats = info["features"]
    sensors = [s.name for s in registry.SENSORS.values() if s.column in feats]
    version = 2 if any(c in feats for c in D.COLUMNS) else 1
    expected = F.build_features(sensors, derived=version >= 2)
    if not sensors or feats != expected:
        bad = sorted(k for k in set(expected) | set(feats) if expected.get(k) != feats.get(k))
        raise DatasetFormatError(
            f"{root / L.INFO_PATH}: no {L.MSTA_META_PATH} and features that are not msta's "
            f"(schema {version} with sensors {sensors} differs in columns {bad}): not an msta "
            "dataset, nothing was changed")
    robot = info.get("robot_type")
    robot = robot if isinstance(robot, str) and robot.strip() and robot.isprintable() \
        else LEGACY_ROBOT
    return {"msta_schema_version": version, "repo_id": f"local/{root.resolve().name}",
            "robot": robot, "sensors": sensors,
            "provenance_columns": list(F.PROVENANCE_COLUMNS)}


_INT64 = (-(2**63), 2**63 - 1)


def _as_int(value: Any, where: str) -> int:
    """An integer provenance value as LeRobot's tools may leave it (an int, an integral float
    from pandas, a string of digits), or a one-line refusal naming ``where``."""
    number = None
    if isinstance(value, float):
        number = int(value) if math.isfinite(value) and value.is_integer() else None
    elif isinstance(value, int) and not isinstance(value, bool):
        number = value
    elif isinstance(value, str) and re.fullmatch(r"\s*[+-]?[0-9]{1,19}\s*", value):
        number = int(value)
    if number is None or not _INT64[0] <= number <= _INT64[1]:
        raise DatasetFormatError(
            f"{where}: {str(value)[:40]!r} is not an integer msta can record (64-bit); fix or "
            "remove the value, nothing was changed")
    return number


def _terrain_of(task: Any) -> str:
    """The terrain a task text names (``a1 locomotion on <terrain>``), or ``unknown`` for
    any other text: a task edited to hold a newline and ``---`` is not recorded as a
    terrain (it broke the dataset card)."""
    name = str(task).removeprefix(F.TASK_PREFIX)
    ok = str(task).startswith(F.TASK_PREFIX) and re.fullmatch(r"[A-Za-z0-9_.-]{1,64}", name)
    return name if ok else UNKNOWN


def _provenance_column(table: pa.Table, col: str, kind: pa.DataType,
                       path: Path | None = None) -> pa.Array | None:
    """The filled column, or None when ``table`` already has it complete and typed.

    Raises:
        DatasetFormatError: an integer column holds a value that is not an integer (the
            file, column and row named).
    """
    have = table.column(col) if col in table.column_names else None
    if have is not None and have.null_count == 0 and have.type == kind:
        return None
    values = have.to_pylist() if have is not None else [None] * table.num_rows
    if col == "provenance/terrain":
        tasks = table.column("tasks").to_pylist()
        fill = [_terrain_of(t[0]) if t else UNKNOWN for t in tasks]
    else:
        fill = [-1 if kind == pa.int64() else UNKNOWN] * table.num_rows
    missing = [v is None or (isinstance(v, float) and math.isnan(v)) for v in values]  # NaN: pandas
    out = [f if m else v for v, f, m in zip(values, fill, missing, strict=True)]
    if kind == pa.int64():
        return pa.array([_as_int(v, f"{path}: column {col!r}, row {i}")
                         for i, v in enumerate(out)], kind)
    return pa.array([str(v) for v in out], kind)


def provenance_fixes(root: str | Path) -> dict[str, tuple[pa.Table, int]]:
    """Episode files whose ``provenance/*`` columns are missing or incomplete, filled as the
    module docstring says: relative path -> (the table to write, episodes filled)."""
    out = {}
    for path in F.episode_files(root):
        table = F.read_parquet(path)
        filled = 0
        for col, kind in F.PROVENANCE_COLUMNS.items():
            new = _provenance_column(table, col, kind, path)
            if new is None:
                continue
            have = table.column(col) if col in table.column_names else None
            filled = max(filled, table.num_rows if have is None else have.null_count)
            if have is None:
                table = table.append_column(pa.field(col, kind), new)
            else:
                i = table.column_names.index(col)
                table = table.set_column(i, pa.field(col, kind), new)
        if filled:
            out[path.relative_to(root).as_posix()] = (table, filled)
    return out


def adopt(root: str | Path, msta_meta: dict[str, Any],
          write: Callable[[Path, Callable[[Path], None]], FileRecord]) -> dict[str, FileRecord]:
    """Write ``meta/msta.json`` and the episode files :func:`provenance_fixes` fills, with the
    writer's atomic ``write(path, fill)``, and say so in one warning line.

    Returns:
        relative path -> what was written (the writer's next commit records it).
    """
    root = Path(root)
    fixes = provenance_fixes(root)  # first: a bad value refuses before anything is written
    text = json.dumps(msta_meta, indent=4, ensure_ascii=False).encode()
    done = {L.MSTA_META_PATH: write(root / L.MSTA_META_PATH, lambda p: p.write_bytes(text))}
    for rel, (table, _) in fixes.items():
        done[rel] = write(root / rel, lambda p, t=table: pq.write_table(
            t, p, compression="snappy", write_page_checksum=True))
    filled = sum(n for _, n in fixes.values())
    logger.warning(
        "%s: no %s and no %s (rewritten by LeRobot's tools?): re-derived from info.json (msta "
        "schema %d, %d sensors)%s", root, L.MSTA_META_PATH, L.MANIFEST_PATH,
        msta_meta["msta_schema_version"], len(msta_meta["sensors"]),
        f"; the provenance of {filled} episode(s) was lost: their terrain is taken from the task, "
        f"the rest is '{UNKNOWN}' or -1" if filled else "")
    return done
