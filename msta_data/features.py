"""The msta dataset schema: registry -> LeRobot v3.0 features, and per-episode provenance.

Columns of ``data/chunk-*/file-*.parquet`` (one row per control step, 50 Hz):

* one float32 vector column per registry sensor (``SensorSpec.column``): student inputs
  ``observation.<name>``, privileged signals ``privileged.<name>``, channel names from the
  registry;
* ``observation.state`` (the student sensors concatenated) and
  ``observation.environment_state`` (the velocity command), computed by the writer from the
  sensor columns so that stock LeRobot policies (ACT, diffusion) train on the dataset
  unchanged (:mod:`msta.data.derived`; schema 2 on);
* ``action`` (12): the teacher's label for this step; ``executed_action`` (12): the
  action actually applied (equal to ``action`` for teacher rollouts, the student's action
  in stage 2);
* ``next.reward`` (total reward), ``next.lin_vel_tracking``, ``next.ang_vel_tracking``
  (the paper's per-step metrics), all float32 scalars, and ``next.done`` (bool);
* lerobot's standard ``timestamp``, ``frame_index``, ``episode_index``, ``index``,
  ``task_index``, filled by the writer.

Provenance: each episode's row in ``meta/episodes/*/*.parquet`` carries the columns
``provenance/terrain``, ``provenance/terrain_level``, ``provenance/source``,
``provenance/round``, ``provenance/policy``, ``provenance/policy_revision`` and
``provenance/seed`` (the authoritative record; lerobot's loader ignores unknown episode
columns and ``LeRobotDataset(..., episode_filter=lambda ep: ep["provenance/terrain"] ==
"stairs_up")`` works). The task string, the only per-frame text lerobot knows, is
``task_string(provenance)`` (``"a1 locomotion on <terrain>"``) so ``task_index`` groups
episodes by terrain type.

``meta/msta.json`` records the msta schema version, the robot and the sensor list
(:mod:`msta.data.msta_json`); ``info.json`` is
left exactly as lerobot writes it (lerobot warns about unknown keys there). Schema 1 (before
the derived columns) is still read and appended to in its own layout, so every file of a
dataset has the same columns.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from msta.data import derived as D
from msta.data import layout as L
from msta.data import sensors as registry
from msta.data.errors import DatasetFormatError, EpisodeValidationError

CODEBASE_VERSION = "v3.0"
#: Schema of new datasets: 2 adds the derived columns (msta.data.derived) to schema 1.
MSTA_SCHEMA_VERSION = 2
#: Schemas the writer appends to (each in its own layout) and the readers read.
SCHEMA_VERSIONS: tuple[int, ...] = (1, 2)
DEFAULT_FPS = 50

#: lerobot's automatically filled columns (same dicts as ``lerobot.utils.constants``).
LEROBOT_DEFAULT_FEATURES: dict[str, dict[str, Any]] = {
    "timestamp": {"dtype": "float32", "shape": (1,), "names": None},
    "frame_index": {"dtype": "int64", "shape": (1,), "names": None},
    "episode_index": {"dtype": "int64", "shape": (1,), "names": None},
    "index": {"dtype": "int64", "shape": (1,), "names": None},
    "task_index": {"dtype": "int64", "shape": (1,), "names": None},
}

#: Columns every msta dataset has besides the sensors, supplied by the collector.
NON_SENSOR_FEATURES: dict[str, dict[str, Any]] = {
    "action": {"dtype": "float32", "shape": (registry.ACTION_DIM,),
               "names": list(registry.JOINT_NAMES)},
    "executed_action": {"dtype": "float32", "shape": (registry.ACTION_DIM,),
                        "names": list(registry.JOINT_NAMES)},
    "next.reward": {"dtype": "float32", "shape": (1,), "names": None},
    "next.lin_vel_tracking": {"dtype": "float32", "shape": (1,), "names": None},
    "next.ang_vel_tracking": {"dtype": "float32", "shape": (1,), "names": None},
    "next.done": {"dtype": "bool", "shape": (1,), "names": None},
}

Source = Literal["teacher", "student"]
SOURCES: tuple[str, ...] = ("teacher", "student")


@dataclass(frozen=True)
class Provenance:
    """Where an episode came from; stored as ``provenance/<field>`` episode columns.

    Args:
        terrain: terrain type, e.g. ``"stairs_up"``.
        terrain_level: curriculum difficulty row (0 = easiest).
        source: ``"teacher"`` (stage 1 rollouts) or ``"student"`` (stage 2 corrections).
        round: stage-2 round (0 for teacher data).
        policy: name of the policy that acted, e.g. ``"gait"`` or ``"msta"``.
        policy_revision: revision / checkpoint id of that policy ("" if none).
        seed: the episode's random seed.
    """

    terrain: str
    terrain_level: int
    source: str
    round: int
    policy: str
    policy_revision: str
    seed: int

    def __post_init__(self) -> None:
        if self.source not in SOURCES:
            raise EpisodeValidationError(
                f"provenance 'source' must be one of {SOURCES}, got {self.source!r}")
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if f.type == "int":
                if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
                    raise EpisodeValidationError(
                        f"provenance {f.name!r} must be an int, got {value!r}")
                object.__setattr__(self, f.name, int(value))
            elif not isinstance(value, str):
                raise EpisodeValidationError(
                    f"provenance {f.name!r} must be a str, got {value!r}")

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Provenance:
        """Build from a plain dict; unknown or missing keys are errors."""
        if isinstance(d, Provenance):
            return d
        names = [f.name for f in dataclasses.fields(cls)]
        unknown = sorted(set(d) - set(names))
        missing = [n for n in names if n not in d]
        if unknown or missing:
            raise EpisodeValidationError(
                f"bad provenance keys: missing {missing}, unknown {unknown}; expected {names}")
        return cls(**d)

    def columns(self) -> dict[str, Any]:
        return {f"provenance/{k}": v for k, v in dataclasses.asdict(self).items()}


PROVENANCE_COLUMNS: dict[str, pa.DataType] = {
    f"provenance/{f.name}": (pa.int64() if f.type == "int" else pa.string())
    for f in dataclasses.fields(Provenance)
}


#: An episode's task text is this prefix and its terrain type.
TASK_PREFIX = "a1 locomotion on "


def task_string(provenance: Provenance) -> str:
    """The lerobot task text of an episode (groups episodes by terrain type)."""
    return f"{TASK_PREFIX}{provenance.terrain}"


def resolve_sensors(sensors: Sequence[str] | None) -> tuple[str, ...]:
    """Registry names to record, in registry order; ``None`` means every sensor but the
    extensions (``registry.DEFAULT_RECORDED``)."""
    if sensors is None:
        return tuple(n for n, s in registry.SENSORS.items() if not s.extension)
    if isinstance(sensors, str):
        raise TypeError(f"sensors must be a sequence of names, got the string {sensors!r}")
    for name in sensors:
        registry.get(name)
    if len(set(sensors)) != len(sensors):
        raise ValueError(f"duplicate sensor names in {list(sensors)}")
    return tuple(n for n in registry.SENSORS if n in set(sensors))


def build_features(sensors: Sequence[str] | None = None,
                   derived: bool = False) -> dict[str, dict[str, Any]]:
    """The lerobot ``features`` dict (as in ``meta/info.json``) for the given sensors.

    Args:
        sensors: registry names; ``None`` = the whole registry but the extension sensors.
        derived: include ``observation.state`` / ``observation.environment_state``
            (:mod:`msta.data.derived`), as a schema-2 dataset (every new one) does;
            ``False`` gives a schema-1 dataset's features.

    Returns:
        column -> {"dtype", "shape", "names"}: sensors, the derived columns, then the
        non-sensor columns, then lerobot's default columns (the Parquet column order).
    """
    feats: dict[str, dict[str, Any]] = {}
    for name in resolve_sensors(sensors):
        spec = registry.get(name)
        feats[spec.column] = {"dtype": "float32", "shape": (spec.dim,), "names": list(spec.names)}
    if derived:
        feats.update(D.features(feats))
    for col, ft in {**NON_SENSOR_FEATURES, **LEROBOT_DEFAULT_FEATURES}.items():
        feats[col] = {"dtype": ft["dtype"], "shape": tuple(ft["shape"]),
                      "names": None if ft["names"] is None else list(ft["names"])}
    return feats


def input_columns(features: dict[str, dict[str, Any]]) -> list[str]:
    """Columns the collector supplies per episode (all but lerobot's defaults and the
    derived columns, which the writer fills)."""
    return [c for c in features if c not in LEROBOT_DEFAULT_FEATURES and c not in D.COLUMNS]


def sensor_column_to_name(features: dict[str, dict[str, Any]]) -> dict[str, str]:
    """Map dataset column -> registry name for the sensor columns present."""
    out = {}
    for spec in registry.SENSORS.values():
        if spec.column in features:
            out[spec.column] = spec.name
    return out


def arrow_type(ft: dict[str, Any]) -> pa.DataType:
    """The Arrow type lerobot's loader (``datasets``) expects for one feature."""
    scalar = pa.bool_() if ft["dtype"] == "bool" else pa.from_numpy_dtype(ft["dtype"])
    shape = tuple(ft["shape"])
    if shape == (1,):
        return scalar
    if len(shape) != 1:
        raise ValueError(f"only 1-D features are supported, got shape {shape}")
    return pa.list_(pa.field("item", scalar), shape[0])


def data_schema(features: dict[str, dict[str, Any]]) -> pa.Schema:
    """Arrow schema of the data files, with the ``huggingface`` features metadata that
    lerobot's writer stores (built with ``datasets``, as lerobot does; lerobot itself is
    not imported because it takes ~15 s)."""
    import datasets  # lazy: datasets pulls in pandas and more (~1 s); only this path needs it

    def hf(ft: dict[str, Any]) -> Any:
        value = datasets.Value(ft["dtype"])
        shape = tuple(ft["shape"])
        return value if shape == (1,) else datasets.Sequence(value, length=shape[0])

    schema = datasets.Features({c: hf(ft) for c, ft in features.items()}).arrow_schema
    ours = pa.schema([pa.field(c, arrow_type(ft)) for c, ft in features.items()])
    if not ours.equals(schema, check_metadata=False):
        raise AssertionError(f"arrow schema mismatch with datasets':\n{ours}\nvs\n{schema}")
    return schema


# ---------------------------------------------------------------------------------------
# On-disk layout (LeRobot v3.0) shared by the writer and the reader.
# ---------------------------------------------------------------------------------------

# File names and path templates: msta.data.layout.
#: Episode-table columns every msta dataset has (besides ``stats/...``), lerobot's first.
EPISODE_INDEX_COLUMNS: dict[str, pa.DataType] = {
    "episode_index": pa.int64(),
    "tasks": pa.list_(pa.string()),
    "length": pa.int64(),
    "data/chunk_index": pa.int64(),
    "data/file_index": pa.int64(),
    "dataset_from_index": pa.int64(),
    "dataset_to_index": pa.int64(),
}
EPISODE_META_COLUMNS: dict[str, pa.DataType] = {
    "meta/episodes/chunk_index": pa.int64(),
    "meta/episodes/file_index": pa.int64(),
}


def numbered_path(template: str, number: int, chunks_size: int) -> str:
    """Relative path of the ``number``-th file (0-based) of a ``chunk-*/file-*`` series.

    The numbering matches lerobot's ``update_chunk_file_indices``: ``chunks_size`` files
    per chunk directory.
    """
    return template.format(chunk_index=number // chunks_size, file_index=number % chunks_size)


def file_number(chunk_index: int, file_index: int, chunks_size: int) -> int:
    return int(chunk_index) * chunks_size + int(file_index)


def load_info(root: str | Path, fps: int | None = None) -> dict[str, Any]:
    """Read and check ``meta/info.json``.

    Args:
        root: dataset root.
        fps: if given, the dataset's fps must equal it.

    Returns:
        the raw dict, with feature shapes as tuples.

    Raises:
        DatasetFormatError: missing or unreadable file, another ``codebase_version``,
            wrong fps, or malformed features (message names the file and key).
    """
    path = Path(root) / L.INFO_PATH
    try:
        info = json.loads(path.read_text())
    except FileNotFoundError:
        raise DatasetFormatError(f"{path}: no such file (not a LeRobot dataset root?)") from None
    except (OSError, json.JSONDecodeError) as e:
        raise DatasetFormatError(f"{path}: cannot read JSON ({e})") from e
    version = info.get("codebase_version")
    if version != CODEBASE_VERSION:
        raise DatasetFormatError(
            f"{path}: codebase_version is {version!r}, expected {CODEBASE_VERSION!r} "
            "(LeRobot v3.0 layout); convert the dataset with lerobot's converter")
    for key in ("fps", "features", "total_episodes", "total_frames", "chunks_size", "data_path"):
        if key not in info:
            raise DatasetFormatError(f"{path}: missing key {key!r}")
    _check_sizes(path, info)
    if fps is not None and info["fps"] != fps:
        raise DatasetFormatError(f"{path}: fps is {info['fps']}, expected {fps}")
    if info["data_path"] != L.DATA_PATH:
        raise DatasetFormatError(f"{path}: data_path {info['data_path']!r} != {L.DATA_PATH!r}")
    for col, ft in info["features"].items():
        if not isinstance(ft, dict) or "dtype" not in ft or "shape" not in ft:
            raise DatasetFormatError(f"{path}: feature {col!r} lacks dtype/shape: {ft!r}")
        ft["shape"] = tuple(ft["shape"])
    return info


def _check_sizes(path: Path, info: dict[str, Any]) -> None:
    """The counts and sizes of ``info.json`` are integers in range (``1e12``, ``0`` or
    ``-1`` would end in a numpy allocation or a division by zero far from the file)."""
    for key, low in (("fps", 1), ("total_episodes", 0), ("total_frames", 0),
                     ("chunks_size", 1)):
        value = info[key]
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise DatasetFormatError(f"{path}: {key} must be an integer >= {low}, got {value!r}")
    if info["total_episodes"] > info["total_frames"]:
        raise DatasetFormatError(
            f"{path}: total_episodes {info['total_episodes']} > total_frames "
            f"{info['total_frames']} (every episode has at least one frame)")
    size = info.get("data_files_size_in_mb", 1)
    if isinstance(size, bool) or not isinstance(size, (int, float)) or not 0 < size < 1e6:
        raise DatasetFormatError(
            f"{path}: data_files_size_in_mb must be a number in (0, 1e6), got {size!r}")


def check_column_feature(info: dict[str, Any], column: str, root: str | Path) -> None:
    """Raise unless ``info.json`` declares ``column`` as the registry / schema expects."""
    path = Path(root) / L.INFO_PATH
    expected = build_features(tuple(registry.SENSORS), derived=True).get(column)
    actual = info["features"].get(column)
    if actual is None:
        raise DatasetFormatError(
            f"{path}: column {column!r} missing; the dataset has {sorted(info['features'])}")
    if expected is not None and (actual["dtype"] != expected["dtype"]
                                 or tuple(actual["shape"]) != tuple(expected["shape"])):
        raise DatasetFormatError(
            f"{path}: column {column!r} is {actual['dtype']}{list(actual['shape'])}, expected "
            f"{expected['dtype']}{list(expected['shape'])}")


def read_parquet(path: Path, columns: list[str] | None = None) -> pa.Table:
    """``pyarrow.parquet.read_table`` with errors that name the file and column."""
    try:
        if columns is not None:
            names = pq.read_schema(path).names
            for col in columns:
                if col not in names:
                    raise DatasetFormatError(f"{path}: column {col!r} missing (has {names})")
        return pq.read_table(path, columns=columns, page_checksum_verification=True)
    except FileNotFoundError:
        raise DatasetFormatError(f"{path}: no such file") from None
    except (pa.ArrowException, OSError) as e:
        raise DatasetFormatError(f"{path}: cannot read Parquet (truncated or corrupt?): {e}") \
            from e


def episode_files(root: str | Path) -> list[Path]:
    return sorted((Path(root) / L.EPISODES_DIR).glob(L.NUMBERED_GLOB))


def read_episode_table(root: str | Path, info: dict[str, Any],
                       with_stats: bool = False) -> pa.Table:
    """The committed episodes' rows of ``meta/episodes`` (``episode_index`` order).

    Rows of episodes >= ``info["total_episodes"]`` (left by a writer killed between
    writing an episode file and committing ``info.json``) are dropped; such files hold no
    committed episode (a writer commits whole files).

    Raises:
        DatasetFormatError: unreadable file, missing column, an empty episode, a file holding
            episodes on both sides of the count, or committed episodes missing.
    """
    tables = []
    total = int(info["total_episodes"])
    for path in episode_files(root):
        names = read_parquet_schema(path).names
        cols = [c for c in names if with_stats or not c.startswith("stats/")]
        for col in EPISODE_INDEX_COLUMNS:
            if col not in names:
                raise DatasetFormatError(f"{path}: column {col!r} missing")
        tables.append(read_parquet(path, cols))
        check_episode_rows(path, tables[-1], total)
    if not tables:
        if total:
            raise DatasetFormatError(
                f"{Path(root) / L.EPISODES_DIR}: no episode files but info.json says {total}")
        return pa.table({c: pa.array([], t) for c, t in EPISODE_INDEX_COLUMNS.items()})
    try:
        table = pa.concat_tables(tables, promote_options="default")
    except pa.ArrowException as e:
        raise DatasetFormatError(f"{Path(root) / L.EPISODES_DIR}: inconsistent files: {e}") from e
    ep = table.column("episode_index").to_numpy()
    table = table.filter(pa.array(ep < total)).sort_by("episode_index")
    got = table.column("episode_index").to_numpy()
    if len(got) != total or (total and not np.array_equal(got, np.arange(total))):
        present = set(got.tolist())  # a count of 1e12 must not build a range of it
        missing = [i for i in range(min(total, len(got) + 10)) if i not in present][:10]
        raise DatasetFormatError(
            f"{Path(root) / L.INFO_PATH}: total_episodes {total}, but {L.EPISODES_DIR} holds "
            f"{len(got)} of them (missing e.g. {missing}, or duplicates)")
    return table


def check_episode_rows(path: Path, table: pa.Table, total: int) -> None:
    """One episode file's rows: at least one frame each, ``dataset_to_index - from ==
    length``, and not episodes on both sides of ``total`` (a writer commits whole files)."""
    length = table.column("length").to_numpy()
    span = (table.column("dataset_to_index").to_numpy()
            - table.column("dataset_from_index").to_numpy())
    ep = table.column("episode_index").to_numpy()
    bad = np.flatnonzero((length < 1) | (span != length))
    if len(bad):
        i = int(bad[0])
        raise DatasetFormatError(
            f"{path}: episode {ep[i]} has length {length[i]} and frames {span[i]} "
            "(dataset_to_index - dataset_from_index); every episode has at least one frame")
    if len(ep) and ep.min() < total <= ep.max():
        raise DatasetFormatError(
            f"{path}: holds episodes {ep.min()}-{ep.max()}, on both sides of meta/info.json's "
            f"total_episodes {total} (a writer commits whole files): a changed count?")


def read_parquet_schema(path: Path) -> pa.Schema:
    try:
        return pq.read_schema(path)
    except (pa.ArrowException, OSError) as e:
        raise DatasetFormatError(f"{path}: cannot read Parquet (truncated or corrupt?): {e}") \
            from e


def validate_episode(frames: dict[str, np.ndarray],
                     features: dict[str, dict[str, Any]]) -> tuple[int, dict[str, np.ndarray]]:
    """Check one episode against the schema and return ``(length, copied columns)``.

    Scalar columns may be ``(L,)`` or ``(L, 1)`` and come back as ``(L,)``.

    Raises:
        EpisodeValidationError: missing/unknown column, wrong type, dtype or shape,
            inconsistent lengths, or a NaN/Inf value (column, frame and channel named).
    """
    if not isinstance(frames, dict):
        raise EpisodeValidationError(f"frames must be a dict column -> array, got {type(frames)}")
    expected = input_columns(features)
    missing = [c for c in expected if c not in frames]
    extra = sorted(set(frames) - set(expected))
    if missing or extra:
        auto = [c for c in extra if c in LEROBOT_DEFAULT_FEATURES or c in D.COLUMNS]
        raise EpisodeValidationError(
            f"episode columns do not match the dataset: missing {missing}, unknown {extra}"
            + (f" ({auto} are filled by the writer)" if auto else ""))
    length: int | None = None
    out: dict[str, np.ndarray] = {}
    for col in expected:
        arr, ft = frames[col], features[col]
        if not isinstance(arr, np.ndarray):
            raise EpisodeValidationError(f"column {col!r}: expected np.ndarray, got {type(arr)}")
        want = np.dtype(ft["dtype"])
        if arr.dtype != want:
            raise EpisodeValidationError(f"column {col!r}: dtype {arr.dtype}, expected {want}")
        dim = ft["shape"][0]
        if tuple(ft["shape"]) == (1,) and arr.ndim == 2 and arr.shape[1] == 1:
            arr = arr[:, 0]
        ok = arr.ndim == 1 if tuple(ft["shape"]) == (1,) else (arr.ndim == 2
                                                                and arr.shape[1] == dim)
        if not ok:
            shape = "(L,)" if tuple(ft["shape"]) == (1,) else f"(L, {dim})"
            raise EpisodeValidationError(f"column {col!r}: shape {arr.shape}, expected {shape}")
        if length is None:
            length = arr.shape[0]
        if arr.shape[0] != length or length == 0:
            raise EpisodeValidationError(
                f"column {col!r}: {arr.shape[0]} frames, expected {length} (> 0) like "
                f"{expected[0]!r}")
        if arr.dtype.kind == "f" and not np.isfinite(arr).all():
            bad = np.argwhere(~np.isfinite(arr.reshape(length, -1)))[0]
            names = ft["names"] or [col]
            raise EpisodeValidationError(
                f"column {col!r}: non-finite value {arr.reshape(length, -1)[tuple(bad)]} at "
                f"frame {bad[0]}, channel {names[bad[1]]!r}")
        out[col] = arr.copy()
    assert length is not None
    return length, out


