"""Fast, appendable, crash-safe episode writer producing a LeRobot v3.0 dataset.

Parquet is written with pyarrow directly (no per-frame Python work). The layout and
column types are exactly those lerobot 0.6.1's ``LeRobotDataset`` loads (the tests load
our output with it).

Durability protocol (one writer at a time, enforced by ``flock`` on ``root/.msta.lock``):

1. Episodes are validated when added and buffered in memory.
2. A *flush* (every ``flush_every_frames`` buffered frames, and on ``close``) writes the
   buffered episodes as new data files ``data/chunk-C/file-F.parquet`` (at most
   ``max_frames_per_file`` rows each, whole episodes only) plus one matching
   ``meta/episodes/chunk-C/file-F.parquet`` per data file. Existing files are never
   modified, so earlier episodes stay byte-identical on append.
3. Then ``meta/tasks.parquet`` and ``meta/stats.json`` are rewritten, the checksum
   manifest ``meta/msta_checksums.json`` records the new generation as *pending*
   (size and sha256 of every file, :mod:`msta.data.integrity`), ``meta/info.json``
   (``total_episodes``/``total_frames``) is rewritten — the commit point — and the manifest
   records the generation as *committed*.

Parquet files are written with page checksums (CRC32, verified by msta's reader).

Every file is written to ``<name>.tmp``, fsync-ed and ``os.replace``-d into place, so a
process killed at any instant leaves only complete files. A kill loses at most the
buffered (unflushed) episodes; a kill during step 2-3 can leave the new files of one
flush uncommitted (lerobot still loads the dataset: its frame count comes from
``info.json``). :meth:`DatasetWriter.open` first verifies every committed file against the
manifest (and refuses, naming the file, when one is missing, truncated or changed, or when
``info.json`` matches no recorded commit, or when its counts disagree with the episode files:
:func:`~msta.data.integrity.check_counts`), then moves every file of the chunk directories the
commit does not list to ``.msta-quarantine/`` (it deletes nothing but its own partial ``.tmp``
writes: :mod:`msta.data.quarantine`), and recomputes ``stats.json`` from the committed
per-episode stats when it is not the committed one. A dataset LeRobot's tools rewrote (no
``meta/msta.json``, no manifest) gets msta's metadata re-derived: :mod:`msta.data.lerobot_edits`.

The writer also fills ``observation.state`` and ``observation.environment_state`` from the
sensor columns, with their statistics (:mod:`msta.data.derived`). A dataset written before
them (msta schema 1) is appended to in its own layout, without them, so all its files keep
the same columns; re-record it to give it the derived columns.

After each commit the dataset card ``README.md`` is rebuilt from the committed files
(:func:`msta.data.hub_cards.write_dataset_card`: sizes, provenance counts, features); a
README.md of the user's own is left alone.
"""

from __future__ import annotations

import io
import json
import logging
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Self

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from msta.data import derived as D
from msta.data import features as F
from msta.data import integrity as I
from msta.data import layout as L
from msta.data import lerobot_edits as E
from msta.data import quarantine as Q
from msta.data import stats as S
from msta.data.errors import DatasetFormatError, DatasetIntegrityError, DatasetLockedError
from msta.data.features import validate_episode
from msta.data.hub_cards import write_dataset_card
from msta.data.inside import refuse_links
from msta.data.layout import LOCK_NAME
from msta.data.locking import lock_directory
from msta.data.msta_json import read_msta_meta
from msta.data.robot import LEGACY_ROBOT

__all__ = ["LOCK_NAME", "DatasetWriter", "validate_episode"]

DEFAULT_FLUSH_EVERY_FRAMES = 50_000
logger = logging.getLogger(__name__)


@dataclass
class _Episode:
    index: int
    length: int
    task_index: int
    task: str
    columns: dict[str, np.ndarray]
    stats: S.Stats
    provenance: F.Provenance


def _fsync_replace(tmp: Path, path: Path) -> None:
    fd = os.open(tmp, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
    os.replace(tmp, path)


def _atomic_write(path: Path, write: Callable[[Path], None]) -> I.FileRecord:
    """Write ``path`` via ``write(tmp)``, fsync, then rename over ``path``; returns the
    size and sha256 of what was written."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    write(tmp)
    record = I.digest_file(tmp, use_cache=False)
    _fsync_replace(tmp, path)
    return record


def _atomic_json(path: Path, obj: Any) -> I.FileRecord:
    data = json.dumps(obj, indent=4, ensure_ascii=False).encode()
    return _atomic_write(path, lambda p: p.write_bytes(data))


def _take_lock(root: Path) -> int:
    return lock_directory(root, "another writer", DatasetLockedError)


class DatasetWriter:
    """Write episodes into a LeRobot v3.0 dataset; use as a context manager.

    Create with :meth:`create` (new dataset) or :meth:`open` (append). Only one writer
    may hold a dataset; a second gets :class:`DatasetLockedError`.
    """

    def __init__(self, root: Path, lock_fd: int, info: dict[str, Any], msta_meta: dict[str, Any],
                 flush_every_frames: int, max_frames_per_file: int | None) -> None:
        self.root = root
        self._lock_fd: int | None = lock_fd
        self.info = info
        self.msta_meta = msta_meta
        self.features: dict[str, dict[str, Any]] = info["features"]
        self._schema = F.data_schema(self.features)
        if flush_every_frames < 1:
            raise ValueError(f"flush_every_frames must be >= 1, got {flush_every_frames}")
        self.flush_every_frames = flush_every_frames
        self.max_frames_per_file = max_frames_per_file or self._default_max_frames()
        self._buffer: list[_Episode] = []
        self._buffered_frames = 0
        self._tasks: dict[str, int] = {}
        self._tasks_dirty = self._meta_dirty = False
        self._staged: dict[str, bytes] = {}  # replaced meta files, written by _commit
        self._stats: S.Stats = {}
        self._next_file = 0
        self._committed: I.Generation | None = None  # the generation on disk
        self._new_files: dict[str, I.FileRecord] = {}  # written since, not yet committed

    # ----- construction ----------------------------------------------------------------
    @classmethod
    def create(cls, root: str | Path, repo_id: str, fps: int = F.DEFAULT_FPS,
               robot: str = LEGACY_ROBOT, sensors: Sequence[str] | None = None,
               flush_every_frames: int = DEFAULT_FLUSH_EVERY_FRAMES,
               max_frames_per_file: int | None = None) -> DatasetWriter:
        """Start a new dataset at ``root`` (absent or an empty directory).

        Args:
            root: dataset directory.
            repo_id: hub id, e.g. ``"local/a1_teacher"`` (recorded in ``meta/msta.json``).
            fps: control rate; msta uses 50.
            robot: the simulated robot's name (``robot_type`` and msta.json's ``robot``).
            sensors: registry names to record; ``None`` = every registry sensor.
            flush_every_frames: buffered frames that trigger a flush (crash loses at most
                this many frames plus the episode in progress).
            max_frames_per_file: row cap per data file; default from lerobot's
                ``data_files_size_in_mb`` (100 MB) and the row size.
        """
        root = Path(root)
        root.mkdir(parents=True, exist_ok=True)
        lock_fd = _take_lock(root)
        try:
            leftovers = [p.name for p in root.iterdir() if p.name != LOCK_NAME]
            if leftovers:
                raise FileExistsError(
                    f"{root}: not empty ({sorted(leftovers)[:5]}); use DatasetWriter.open to append")
            feats = F.build_features(sensors, derived=True)
            info = {
                "codebase_version": F.CODEBASE_VERSION, "fps": int(fps), "features": feats,
                "total_episodes": 0, "total_frames": 0, "total_tasks": 0, "chunks_size": 1000,
                "data_files_size_in_mb": 100, "video_files_size_in_mb": 200,
                "data_path": L.DATA_PATH, "video_path": None, "robot_type": robot,
                "splits": {},
            }
            msta_meta = {"msta_schema_version": F.MSTA_SCHEMA_VERSION, "repo_id": repo_id,
                         "robot": robot, "sensors": list(F.resolve_sensors(sensors)),
                         "provenance_columns": list(F.PROVENANCE_COLUMNS)}
            self = cls(root, lock_fd, info, msta_meta, flush_every_frames, max_frames_per_file)
            self._new_files[L.MSTA_META_PATH] = _atomic_json(root / L.MSTA_META_PATH, msta_meta)
            self._commit()
            return self
        except BaseException:
            os.close(lock_fd)
            raise

    @classmethod
    def open(cls, root: str | Path, flush_every_frames: int = DEFAULT_FLUSH_EVERY_FRAMES,
             max_frames_per_file: int | None = None,
             verify: I.VerifyMode = "full") -> DatasetWriter:
        """Re-open a dataset written by msta to append episodes (stage 2, ``--resume``).

        Everything committed is verified first; files no commit lists are then moved aside
        (module docstring).

        Args:
            root: dataset root.
            flush_every_frames, max_frames_per_file: as :meth:`create`.
            verify: ``full`` hashes every committed file, ``sizes`` checks sizes only.

        Raises:
            DatasetIntegrityError: a committed file is missing, truncated or changed, or
                ``info.json`` matches no recorded commit (nothing is modified).
            DatasetFormatError: the schema or the metadata is wrong (file named).
            DatasetIntegrityError: a symbolic link is anywhere under ``root`` (a writer
                would move, rewrite or create files where it leads).
        """
        root = Path(root)
        if not (root / L.INFO_PATH).exists():
            raise DatasetFormatError(f"{root / L.INFO_PATH}: no such file; use create()")
        # a chunk folder, the quarantine, meta/ or the lock linked elsewhere: nothing touched
        refuse_links(root, what="dataset", error=DatasetIntegrityError)
        lock_fd = _take_lock(root)
        try:
            info = F.load_info(root)
            rewritten = E.is_rewritten(root)  # by LeRobot's tools: msta's metadata re-derived
            msta_meta = (E.derive_msta_meta(root, info) if rewritten
                         else read_msta_meta(root, info))
            manifest = I.Manifest.load(root)
            gen = None
            if manifest is None:  # no manifest (older or LeRobot-written): read every column
                I.check_structure(root)
            else:
                gen = I.current_generation(root, manifest)
                I.check_generation(root, manifest, gen, verify, skip=(L.STATS_PATH,))
            I.check_counts(root, gen)
            self = cls(root, lock_fd, info, msta_meta, flush_every_frames, max_frames_per_file)
            self._committed = gen
            if rewritten:
                self._adopt()
            self._recover(manifest)
            if rewritten:
                self._write_card()
            return self
        except BaseException:
            os.close(lock_fd)
            raise

    def _adopt(self) -> None:
        """Re-derive msta's metadata of a dataset LeRobot's tools rewrote
        (:mod:`msta.data.lerobot_edits`): ``meta/msta.json`` and the provenance columns."""
        self._new_files.update(E.adopt(self.root, self.msta_meta, _atomic_write))

    def _recover(self, manifest: I.Manifest | None) -> None:
        table = F.read_episode_table(self.root, self.info, with_stats=True)
        if len(table):
            last = table.slice(len(table) - 1).to_pylist()[0]
            if last["dataset_to_index"] != self.info["total_frames"]:
                raise DatasetFormatError(
                    f"{self.root / L.INFO_PATH}: total_frames {self.info['total_frames']} but "
                    f"the last episode ends at {last['dataset_to_index']}")
        committed, self._next_file = Q.committed_files(table, self.info["chunks_size"])
        Q.set_aside_leftovers(self.root, self._committed, committed, self.info["total_episodes"])
        if (self.root / L.TASKS_PATH).exists():
            tasks = pd.read_parquet(self.root / L.TASKS_PATH)
            self._tasks = {str(t): int(i) for t, i in zip(tasks.index, tasks["task_index"],
                                                          strict=True)}
        rows = table.select([c for c in table.column_names if c.startswith("stats/")]).to_pylist()
        self._stats = S.aggregate(S.from_episode_columns(r) for r in rows)
        stats_path = self.root / L.STATS_PATH
        gen = self._committed
        recorded = gen.files.get(L.STATS_PATH) if gen else None
        if self._stats and (recorded is None or not stats_path.exists()
                            or I.digest_file(stats_path) != recorded):
            self._new_files[L.STATS_PATH] = _atomic_json(stats_path, S.to_json(self._stats))
        if gen is None or manifest is None or manifest.pending is not None or self._new_files:
            self._record_generation(committed)

    def _record_generation(self, committed: set[str]) -> None:
        """Write the manifest for the generation on disk (after recovery or an upgrade)."""
        files = dict(self._committed.files) if self._committed else {
            rel: I.digest_file(self.root / rel) for rel in committed}
        for rel in (L.MSTA_META_PATH, L.TASKS_PATH, L.STATS_PATH, L.INFO_PATH):
            if (self.root / rel).exists():
                files[rel] = self._new_files.get(rel) or I.digest_file(self.root / rel)
        gen = I.Generation(self.info["total_episodes"], self.info["total_frames"], files)
        _atomic_write(self.root / L.MANIFEST_PATH,
                      lambda p: p.write_bytes(I.Manifest(gen).dumps()))
        self._committed, self._new_files = gen, {}

    def _default_max_frames(self) -> int:
        row = sum(np.dtype(ft["dtype"]).itemsize * ft["shape"][0] for ft in self.features.values())
        return max(1, int(self.info["data_files_size_in_mb"] * 1024 * 1024 // row))

    # ----- public API -------------------------------------------------------------------
    @property
    def num_episodes(self) -> int:
        """Episodes committed plus buffered."""
        return self.info["total_episodes"] + len(self._buffer)

    @property
    def num_frames(self) -> int:
        return self.info["total_frames"] + self._buffered_frames

    def add_episode(self, frames: dict[str, np.ndarray], provenance: dict[str, Any]) -> int:
        """Validate and buffer one episode; flushes when enough frames are buffered.

        Args:
            frames: column -> ``(L, dim)`` array for every column of
                ``features.input_columns`` (float32; ``next.done`` bool; scalars may be
                ``(L,)``). Timestamps, indices and the derived columns are filled by the writer.
            provenance: the :class:`~msta.data.features.Provenance` fields as a dict.

        Returns:
            the episode's index in the dataset.
        """
        self._check_open()
        prov = F.Provenance.from_dict(provenance)
        length, cols = validate_episode(frames, self.features)
        task = F.task_string(prov)
        if task not in self._tasks:
            self._tasks[task] = len(self._tasks)
            self._tasks_dirty = True
        ep = _Episode(index=self.num_episodes, length=length, task_index=self._tasks[task],
                      task=task, columns=cols, stats={}, provenance=prov)
        ep.columns.update(self._auto_columns(ep, self.num_frames))
        ep.stats = S.episode_stats(ep.columns)
        ep.stats.update(D.derive_stats(ep.stats, self.features))
        ep.columns.update(D.derive(ep.columns, self.features))
        ep.stats = {c: ep.stats[c] for c in self.features}  # schema order
        self._buffer.append(ep)
        self._buffered_frames += length
        if self._buffered_frames >= self.flush_every_frames:
            self.flush()
        return ep.index

    def flush(self) -> None:
        """Write buffered episodes as new files and commit them (see module docstring)."""
        self._check_open()
        if not self._buffer:
            return
        for group in self._groups():
            self._write_group(group)
        # msta.json (the recording settings) and tasks.parquet are replaced, not added:
        # written only once the pending manifest lists their new bytes (_commit), so a kill
        # leaves them matching one recorded generation or the other
        if self._meta_dirty:
            self._staged[L.MSTA_META_PATH] = json.dumps(
                self.msta_meta, indent=4, ensure_ascii=False).encode()
            self._meta_dirty = False
        if self._tasks_dirty:
            buf = io.BytesIO()
            pd.DataFrame({"task_index": list(self._tasks.values())},
                         index=pd.Index(list(self._tasks), name="task")
                         ).to_parquet(buf, write_page_checksum=True)
            self._staged[L.TASKS_PATH] = buf.getvalue()
            self._tasks_dirty = False
        self._stats = S.aggregate([self._stats, *(ep.stats for ep in self._buffer)])
        self._new_files[L.STATS_PATH] = _atomic_json(self.root / L.STATS_PATH,
                                                     S.to_json(self._stats))
        self.info["total_episodes"] += len(self._buffer)
        self.info["total_frames"] += self._buffered_frames
        self.info["total_tasks"] = len(self._tasks)
        self.info["splits"] = {"train": f"0:{self.info['total_episodes']}"}
        self._commit()
        self._buffer.clear()
        self._buffered_frames = 0
        self._write_card()

    def _write_card(self) -> None:
        try:  # the episodes are committed: a card that cannot be written only warns
            write_dataset_card(self.root)
        except (OSError, ValueError) as e:
            logger.warning("%s not rebuilt (%s: %s)", self.root / L.CARD_NAME, type(e).__name__, e)

    def meta_changed(self) -> None:
        """``msta_meta`` was edited (:func:`msta.data.msta_json.add_recording`): the next
        flush writes ``meta/msta.json`` with its episodes."""
        self._meta_dirty = True

    def close(self) -> None:
        """Flush and release the lock. Idempotent."""
        if self._lock_fd is None:
            return
        try:
            self.flush()
        finally:
            os.close(self._lock_fd)
            self._lock_fd = None

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        # Buffered episodes were validated when added, so they are committed even when the
        # block raised (e.g. a later episode was malformed).
        self.close()

    # ----- internals ----------------------------------------------------------------------
    def _check_open(self) -> None:
        if self._lock_fd is None:
            raise RuntimeError(f"{self.root}: writer is closed")

    def _auto_columns(self, ep: _Episode, first_index: int) -> dict[str, np.ndarray]:
        frame_index = np.arange(ep.length, dtype=np.int64)
        return {
            "timestamp": (frame_index / self.info["fps"]).astype(np.float32),
            "frame_index": frame_index,
            "episode_index": np.full(ep.length, ep.index, dtype=np.int64),
            "index": np.arange(first_index, first_index + ep.length, dtype=np.int64),
            "task_index": np.full(ep.length, ep.task_index, dtype=np.int64),
        }

    def _groups(self) -> list[list[_Episode]]:
        groups: list[list[_Episode]] = [[]]
        rows = 0
        for ep in self._buffer:
            if groups[-1] and rows + ep.length > self.max_frames_per_file:
                groups.append([])
                rows = 0
            groups[-1].append(ep)
            rows += ep.length
        return groups

    def _write_group(self, group: list[_Episode]) -> None:
        number, cs = self._next_file, self.info["chunks_size"]
        arrays = []
        for col, ft in self.features.items():
            values = np.concatenate([ep.columns[col] for ep in group])
            if tuple(ft["shape"]) == (1,):
                arrays.append(pa.array(values))
            else:
                arrays.append(pa.FixedSizeListArray.from_arrays(
                    pa.array(values.reshape(-1)), ft["shape"][0]))
        table = pa.Table.from_arrays(arrays, schema=self._schema)

        def write_data(path: Path) -> None:
            with pq.ParquetWriter(path, self._schema, compression="snappy",
                                  use_dictionary=["episode_index", "task_index"],
                                  write_statistics=list(F.LEROBOT_DEFAULT_FEATURES),
                                  write_page_checksum=True) as w:
                start = 0
                for ep in group:  # one row group per episode, as lerobot writes
                    w.write_table(table.slice(start, ep.length))
                    start += ep.length

        rel = F.numbered_path(L.DATA_PATH, number, cs)
        self._new_files[rel] = _atomic_write(self.root / rel, write_data)
        meta = self._episode_table(group, number)
        rel = F.numbered_path(L.EPISODES_PATH, number, cs)
        self._new_files[rel] = _atomic_write(self.root / rel, lambda p: pq.write_table(
            meta, p, compression="snappy", write_page_checksum=True))
        self._next_file += 1

    def _episode_table(self, group: list[_Episode], number: int) -> pa.Table:
        cs = self.info["chunks_size"]
        chunk, file = number // cs, number % cs
        rows = []
        for ep in group:
            start = int(ep.columns["index"][0])
            row = {"episode_index": ep.index, "tasks": [ep.task], "length": ep.length,
                   "data/chunk_index": chunk, "data/file_index": file,
                   "dataset_from_index": start, "dataset_to_index": start + ep.length}
            row.update(S.to_episode_columns(ep.stats))
            row.update({"meta/episodes/chunk_index": chunk, "meta/episodes/file_index": file})
            row.update(ep.provenance.columns())
            rows.append(row)
        fields = [pa.field(c, t) for c, t in F.EPISODE_INDEX_COLUMNS.items()]
        for col in self.features:
            for key in S.STAT_KEYS:
                fields.append(pa.field(f"stats/{col}/{key}", pa.list_(
                    pa.int64() if key == "count" else pa.float64())))
        fields += [pa.field(c, t) for c, t in {**F.EPISODE_META_COLUMNS,
                                                **F.PROVENANCE_COLUMNS}.items()]
        return pa.Table.from_pylist(rows, schema=pa.schema(fields))

    def _commit(self) -> None:
        """Record the new generation as pending, write ``info.json`` (the commit point),
        then record it as committed (see :mod:`msta.data.integrity`)."""
        info = dict(self.info)
        info["features"] = {c: {**ft, "shape": list(ft["shape"])}
                            for c, ft in self.features.items()}
        data = json.dumps(info, indent=4, ensure_ascii=False).encode()
        old = self._committed
        files = {**(old.files if old else {}), **self._new_files,
                 **{rel: I.digest_bytes(b) for rel, b in self._staged.items()},
                 L.INFO_PATH: I.digest_bytes(data)}
        gen = I.Generation(self.info["total_episodes"], self.info["total_frames"], files)
        manifest = self.root / L.MANIFEST_PATH
        _atomic_write(manifest, lambda p: p.write_bytes(I.Manifest(old, gen).dumps()))
        for rel, staged in self._staged.items():  # replaced files, now listed as pending
            _atomic_write(self.root / rel, lambda p, b=staged: p.write_bytes(b))
        self._staged = {}
        _atomic_write(self.root / L.INFO_PATH, lambda p: p.write_bytes(data))  # commit point
        self._committed, self._new_files = gen, {}
        _atomic_write(manifest, lambda p: p.write_bytes(I.Manifest(gen).dumps()))
