"""Content hashes of a dataset's committed files, and the checks that use them.

Parquet pages carry no checksum unless the writer asks for one, and a changed byte inside a
data page decodes to a plausible number (an audit read ``joint_pos`` values of
5.9e36 that every loader accepted). So at every commit the writer records, in
``meta/msta_checksums.json`` (msta's own file: LeRobot's loader never reads it), the size
and sha256 of every file the commit consists of:

* ``data/chunk-*/file-*.parquet`` and ``meta/episodes/chunk-*/file-*.parquet`` (written
  once, never modified);
* ``meta/info.json`` (the commit point: it says which generation is on disk),
  ``meta/stats.json``, ``meta/tasks.parquet`` and ``meta/msta.json``.

A commit writes the manifest twice: first with the new generation as ``pending`` (next to
the last ``committed`` one), then ``meta/info.json``, then the manifest with the new
generation ``committed``. A writer killed anywhere in between leaves an ``info.json`` whose
sha256 is that of one of the two recorded generations; anything else (a lowered episode
count, an edited file) matches neither and is refused, so a stale ``info.json`` can no
longer make the writer delete committed files as leftovers.

Checks (:func:`verify_dataset`): ``full`` hashes every recorded file (~1.2 ms per MB on
this project's CPU, docs/data.md); ``sizes`` checks existence and sizes of the Parquet
files and hashes only the small meta files. Hashes are cached per process by
``(path, size, mtime, inode)`` so a training run that opens a dataset twice hashes it once.
Datasets written before the manifest existed ("legacy") carry none: readers warn, writers
record one after a full structural check (:func:`check_structure`).
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import stat
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from msta.data import features as F
from msta.data import layout as L
from msta.data.errors import DatasetFormatError, DatasetIntegrityError
from msta.data.inside import PathOutsideRootError, inside

logger = logging.getLogger(__name__)

MANIFEST_FORMAT = 1
_EPISODE_ROW_COLUMNS = ("episode_index", "length", "dataset_from_index", "dataset_to_index")
VerifyMode = Literal["full", "sizes"]
_CHUNK = 1 << 20
_cache: dict[str, tuple[tuple[int, int, int, int], FileRecord]] = {}
_warned: set[str] = set()


@dataclass(frozen=True)
class FileRecord:
    """Size (bytes) and sha256 (hex) of one file."""

    size: int
    sha256: str

    def to_json(self) -> dict[str, Any]:
        return {"size": self.size, "sha256": self.sha256}


def digest_bytes(data: bytes) -> FileRecord:
    """The :class:`FileRecord` of an in-memory file content."""
    return FileRecord(len(data), hashlib.sha256(data).hexdigest())


def digest_file(path: Path, use_cache: bool = True) -> FileRecord:
    """sha256 of a file, read in 1 MiB chunks (cached by size, mtime, ctime and inode).

    Raises:
        DatasetIntegrityError: ``path`` is not a regular file (a device such as /dev/zero
            would be read forever, a FIFO would block): refused before reading.
    """
    # O_NONBLOCK: opening a FIFO must not wait for a writer; it is refused just below.
    with os.fdopen(os.open(path, os.O_RDONLY | os.O_NONBLOCK), "rb") as f:
        st = os.fstat(f.fileno())
        if not stat.S_ISREG(st.st_mode):
            raise DatasetIntegrityError(f"{path}: not a regular file (a device, FIFO, socket "
                                        "or directory); refused, nothing was read")
        key = (st.st_size, st.st_mtime_ns, st.st_ctime_ns, st.st_ino)
        hit = _cache.get(str(path)) if use_cache else None
        if hit is not None and hit[0] == key:
            return hit[1]
        h = hashlib.sha256()
        while chunk := f.read(_CHUNK):
            h.update(chunk)
    rec = FileRecord(st.st_size, h.hexdigest())
    if use_cache:
        _cache[str(path)] = (key, rec)
    return rec


@dataclass(frozen=True)
class Generation:
    """One commit: the episode and frame totals and every file it consists of."""

    total_episodes: int
    total_frames: int
    files: dict[str, FileRecord] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {"total_episodes": self.total_episodes, "total_frames": self.total_frames,
                "files": {rel: r.to_json() for rel, r in sorted(self.files.items())}}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> Generation:
        files = {str(rel): FileRecord(int(r["size"]), str(r["sha256"]))
                 for rel, r in data["files"].items()}
        return cls(int(data["total_episodes"]), int(data["total_frames"]), files)

    def numbered(self) -> list[str]:
        """The recorded data and episode-metadata Parquet files."""
        return sorted(r for r in self.files if r.startswith(tuple(d + "/" for d in L.NUMBERED_DIRS)))


@dataclass
class Manifest:
    """``meta/msta_checksums.json``: the last committed generation and, between the two
    manifest writes of a commit, the pending one."""

    committed: Generation | None
    pending: Generation | None = None

    def to_json(self) -> dict[str, Any]:
        return {"format": MANIFEST_FORMAT, "algorithm": "sha256",
                "committed": self.committed.to_json() if self.committed else None,
                "pending": self.pending.to_json() if self.pending else None}

    def dumps(self) -> bytes:
        return json.dumps(self.to_json(), indent=1).encode()

    @classmethod
    def load(cls, root: str | Path) -> Manifest | None:
        """Read the manifest; ``None`` for a dataset written before manifests existed."""
        path = Path(root) / L.MANIFEST_PATH
        try:
            data = json.loads(path.read_bytes())
        except FileNotFoundError:
            return None
        except (OSError, ValueError) as e:
            raise DatasetIntegrityError(f"{path}: cannot read the checksum manifest ({e})") \
                from None
        try:
            if data.get("format") != MANIFEST_FORMAT:
                raise ValueError(f"format {data.get('format')!r}, expected {MANIFEST_FORMAT}")
            gens = [Generation.from_json(data[k]) if data.get(k) else None
                    for k in ("committed", "pending")]
        except (AttributeError, KeyError, TypeError, ValueError) as e:
            raise DatasetIntegrityError(f"{path}: malformed checksum manifest ({e})") from None
        if gens[0] is None and gens[1] is None:
            raise DatasetIntegrityError(f"{path}: records no generation")
        for gen in gens:
            for rel in gen.files if gen else ():
                check_entry(path, rel)
        return cls(*gens)

    def generations(self) -> list[Generation]:
        return [g for g in (self.committed, self.pending) if g is not None]


def check_entry(manifest: Path, rel: str) -> None:
    """A manifest entry must name a file inside the dataset: a relative ``/``-separated path
    with no empty, ``.`` or ``..`` part, no backslash or control character (a manifest
    pushed by someone else could name ``/dev/zero`` or ``../../secret``).

    Raises:
        DatasetIntegrityError: naming the manifest and the entry.
    """
    parts = rel.split("/")
    if (not rel or rel.startswith("/") or "\\" in rel or any(ord(c) < 32 for c in rel)
            or any(p in ("", ".", "..") for p in parts) or ":" in parts[0]):
        raise DatasetIntegrityError(
            f"{manifest}: entry {rel!r} is not a relative path inside the dataset (absolute, "
            "'..', empty part, backslash or control character); refused, nothing was read")


def _inside(root: Path, rel: str) -> Path:
    """``root / rel`` after checking that symbolic links do not lead outside ``root``."""
    try:
        return inside(root, rel, what="dataset")
    except PathOutsideRootError as e:
        raise DatasetIntegrityError(str(e)) from None


def current_generation(root: str | Path, manifest: Manifest) -> Generation:
    """The recorded generation ``meta/info.json`` belongs to.

    Raises:
        DatasetIntegrityError: ``info.json`` matches neither recorded generation (a stale
            or edited file), naming both.
    """
    path = Path(root) / L.INFO_PATH
    try:
        rec = digest_bytes(path.read_bytes())
    except FileNotFoundError:
        raise DatasetIntegrityError(f"{path}: no such file") from None
    for gen in manifest.generations():
        if gen.files.get(L.INFO_PATH) == rec:
            return gen
    try:
        said = json.loads(path.read_bytes()).get("total_episodes")
    except (ValueError, AttributeError):
        said = "?"
    want = manifest.committed or manifest.pending
    assert want is not None
    raise DatasetIntegrityError(
        f"{path}: does not match the last commit recorded in {L.MANIFEST_PATH} (it says "
        f"{said} episodes, the commit has {want.total_episodes}): stale or edited; restore it "
        "(nothing was changed)")


def _check_file(root: Path, rel: str, gen: Generation, others: list[Generation],
                mode: VerifyMode) -> None:
    path = _inside(root, rel)
    want = gen.files[rel]
    try:
        st = path.stat()
    except FileNotFoundError:
        raise DatasetIntegrityError(
            f"{path}: missing (recorded at commit in {L.MANIFEST_PATH}, {want.size} bytes)") \
            from None
    if not stat.S_ISREG(st.st_mode):
        raise DatasetIntegrityError(f"{path}: not a regular file (a device, FIFO, socket or "
                                    "directory); refused, nothing was read")
    size = st.st_size
    accepted = [want] + [g.files[rel] for g in others if rel in g.files]
    if all(size != a.size for a in accepted):
        raise DatasetIntegrityError(
            f"{path}: {size} bytes, {want.size} recorded at commit in {L.MANIFEST_PATH} "
            "(truncated or modified)")
    if mode == "sizes" and rel.startswith(tuple(d + "/" for d in L.NUMBERED_DIRS)):
        return
    got = digest_file(path)
    if got not in accepted:
        raise DatasetIntegrityError(
            f"{path}: sha256 {got.sha256[:16]}... differs from {want.sha256[:16]}... recorded "
            f"at commit in {L.MANIFEST_PATH} (corrupted or modified)")


def check_generation(root: str | Path, manifest: Manifest, gen: Generation,
                     mode: VerifyMode = "full", skip: tuple[str, ...] = ()) -> None:
    """Every file of ``gen`` exists with its recorded size (and sha256 in ``full`` mode).

    A rewritten meta file (stats, tasks) may also match the other recorded generation:
    that is what a writer killed inside a commit leaves.

    Args:
        root: dataset root.
        manifest: the manifest ``gen`` comes from.
        gen: the generation on disk (:func:`current_generation`).
        mode: ``full`` or ``sizes`` (module docstring).
        skip: relative paths not checked (the writer regenerates ``meta/stats.json``).
    """
    if mode not in ("full", "sizes"):
        raise ValueError(f"verify mode must be 'full' or 'sizes', got {mode!r}")
    others = [g for g in manifest.generations() if g is not gen]
    for rel in sorted(gen.files):
        if rel not in skip:
            _check_file(Path(root), rel, gen, others, mode)


def check_counts(root: str | Path, gen: Generation | None) -> None:
    """``meta/info.json``'s episode and frame counts against the episode files present.

    A count that is wrong but agrees with the manifest (both edited, or a dataset without
    one) would train on a subset, and a writer would write over the files beyond it. So:
    the counts must be the ones the commit recorded; an episode file the commit lists (any,
    without a manifest) may not hold only episodes beyond the count; no file may hold
    episodes on both sides of the count or an empty episode
    (:func:`msta.data.features.check_episode_rows`); and the other files must hold exactly
    episodes ``0 .. total_episodes - 1``, ending at frame ``total_frames``. Files the commit
    does not list are a killed writer's: readers ignore them.

    Raises:
        DatasetFormatError: one line naming the file (DatasetIntegrityError for counts that
            differ from the commit's).
    """

    root = Path(root)
    info = F.load_info(root)
    total, frames = info["total_episodes"], info["total_frames"]
    if gen is not None and (gen.total_episodes, gen.total_frames) != (total, frames):
        raise DatasetIntegrityError(
            f"{root / L.INFO_PATH}: {total} episodes and {frames} frames, the last commit in "
            f"{L.MANIFEST_PATH} recorded {gen.total_episodes} and {gen.total_frames}: edited; "
            "restore it (nothing was changed)")
    listed = None if gen is None else set(gen.files)
    committed, end = [], 0
    for path in F.episode_files(root):  # the index columns only: one pass, small reads
        rows = F.read_parquet(path, list(_EPISODE_ROW_COLUMNS))
        F.check_episode_rows(path, rows, total)
        ep = rows.column("episode_index").to_numpy()
        if len(ep) and ep.min() >= total:
            if listed is None or path.relative_to(root).as_posix() in listed:
                raise DatasetFormatError(
                    f"{path}: beyond the {total} episodes of {L.INFO_PATH} (it holds episodes "
                    f"{ep.min()}-{ep.max()}): a lowered count, or meta/ restored from an older "
                    "copy? Nothing was changed: restore meta/, or move the file away if it is "
                    "not part of the dataset")
            continue  # a killed writer's leftover (a writer moves it aside)
        committed.append(ep)
        if len(ep):
            end = max(end, int(rows.column("dataset_to_index").to_numpy().max()))
    got = np.sort(np.concatenate(committed)) if committed else np.zeros(0, np.int64)
    if len(got) != total or not np.array_equal(got, np.arange(len(got))):
        raise DatasetFormatError(
            f"{root / L.INFO_PATH}: total_episodes {total}, but {L.EPISODES_DIR} holds "
            f"{len(got)} of them (or duplicates, or gaps)")
    if end != frames:
        raise DatasetFormatError(f"{root / L.INFO_PATH}: total_frames {frames}, but the last "
                                 f"episode in {L.EPISODES_DIR} ends at frame {end}")


def leftover_files(root: str | Path, committed: set[str]) -> list[str]:
    """Files in the chunk directories of data/ and meta/episodes/, and ``.tmp`` files in
    meta/, that no commit lists."""
    root = Path(root)
    out = []
    for sub in (*L.NUMBERED_DIRS, L.META_DIR):
        pattern = "*.tmp" if sub == L.META_DIR else "chunk-*/*"
        for path in (root / sub).glob(pattern):
            rel = path.relative_to(root).as_posix()
            if path.is_file() and rel not in committed:
                out.append(rel)
    return sorted(set(out))


def verify_dataset(root: str | Path, mode: VerifyMode = "full",
                   for_publish: bool = False) -> Generation | None:
    """Check a dataset against its manifest before training on, extending or publishing it.

    Args:
        root: dataset root.
        mode: ``full`` (hash every file) or ``sizes``.
        for_publish: also refuse files no commit lists (a killed writer's leftovers would be
            uploaded and lerobot's loader reads every Parquet file it finds).

    Returns:
        the generation on disk, or ``None`` for a legacy dataset (no manifest).

    Raises:
        DatasetFormatError / DatasetIntegrityError: one line naming the first bad file
            (:func:`check_generation`, :func:`check_counts`).
    """
    manifest = Manifest.load(root)
    if manifest is None:
        check_counts(root, None)
        if str(root) in _warned:
            return None
        _warned.add(str(root))
        logger.warning("%s: no %s (written before msta recorded checksums, or rewritten by "
                       "LeRobot's tools): only structural checks apply; extending it with "
                       "msta-collect --resume records them", root, L.MANIFEST_PATH)
        return None
    gen = current_generation(root, manifest)
    check_generation(root, manifest, gen, mode)
    check_counts(root, gen)
    if for_publish:
        extra = leftover_files(root, set(gen.files))
        if extra:
            raise DatasetIntegrityError(
                f"{Path(root) / extra[0]}: not part of the last commit (left by a killed "
                f"writer?; {len(extra)} such file(s)); DatasetWriter.open / msta-collect "
                f"--resume moves them to {L.QUARANTINE_DIR}/")
    return gen


def check_structure(root: str | Path) -> None:
    """Read every committed data file whole (Parquet page checksums verified where written):
    every ``info.json`` feature present without nulls, no NaN/Inf in float columns, and as
    many rows as its episodes' lengths. The check for datasets without a manifest (written
    before msta recorded checksums, or by lerobot itself).

    Raises:
        DatasetFormatError: naming the file and column.
    """

    info = F.load_info(root)
    table = F.read_episode_table(root, info).to_pandas()
    cs = int(info["chunks_size"])
    files = table.groupby(["data/chunk_index", "data/file_index"], sort=True)["length"].sum()
    for (chunk, file), rows in files.items():
        path = Path(root) / F.numbered_path(L.DATA_PATH, F.file_number(chunk, file, cs), cs)
        data = F.read_parquet(path, list(info["features"]))
        if data.num_rows != rows:
            raise DatasetFormatError(f"{path}: {data.num_rows} rows, meta/episodes says {rows} "
                                     "(truncated or rewritten?)")
        for col, ft in info["features"].items():
            arr = data.column(col).combine_chunks()
            if tuple(ft["shape"]) != (1,):  # LeRobot's merge writes variable-length lists
                arr = fixed_size(arr, ft["shape"][0], f"{path}: column {col!r}")
            flat = arr.flatten() if pa.types.is_fixed_size_list(arr.type) else arr
            if arr.null_count or flat.null_count:
                raise DatasetFormatError(f"{path}: column {col!r} contains nulls")
            if pa.types.is_floating(flat.type) and not np.isfinite(flat.to_numpy()).all():
                raise DatasetFormatError(f"{path}: column {col!r} has NaN/Inf values")


def verify_for_publish(root: str | Path) -> None:
    """What ``msta-hub push-dataset`` checks before uploading anything: every committed
    file hashed, no leftover of an unfinished commit; without a manifest, every column of
    every committed episode read (:func:`check_structure`).

    Raises:
        DatasetFormatError / DatasetIntegrityError: naming the first bad file.
    """
    if verify_dataset(root, "full", for_publish=True) is None:
        check_structure(root)


def fixed_size(arr: pa.Array, size: int, where: str) -> pa.Array:
    """A ``list<value>`` column (LeRobot's merge writes these) as ``fixed_size_list<value>[size]``
    after checking that no row is null and every row holds ``size`` values; any other array
    is returned unchanged.

    Args:
        arr: one column (chunks combined).
        size: the feature's length.
        where: ``"<file>: column 'x'"`` for the error.

    Raises:
        DatasetFormatError: a null row or a row of another length (row named).
    """
    if not (pa.types.is_list(arr.type) or pa.types.is_large_list(arr.type)):
        return arr
    lengths = pc.list_value_length(arr).fill_null(-1).to_numpy(zero_copy_only=False)
    bad = np.flatnonzero(lengths != size)
    if len(bad):
        row = int(bad[0])
        got = "null" if lengths[row] < 0 else f"{lengths[row]} values"
        raise DatasetFormatError(f"{where}: row {row} holds {got}, expected {size} values")
    return pa.FixedSizeListArray.from_arrays(arr.flatten(), size)
