"""Files in a dataset's chunk directories that no commit lists: moved aside, never deleted.

A writer that reopens a dataset (``msta-collect --resume``, stage 2's append) may find files
there that the last commit in ``meta/msta_checksums.json`` does not list: what a killed
writer left (its partial ``.tmp`` files, the complete files of an unfinished commit), but
just as well committed episodes that a ``meta/`` restored from an older copy no longer
counts, or a user's own files (a ``.backup`` copy, notes). Nothing on disk tells these apart
for certain, so the writer deletes only its own partial writes (``<name>.tmp`` of a name it
writes, :func:`is_partial_write`) and moves everything else, keeping the relative path, into
``<root>/.msta-quarantine/<UTC time>/``, saying so in one warning line (stderr when no
logging is configured). Readers never look there and ``msta-hub push-dataset`` does not
upload it; delete the folder once its content is checked.
"""

from __future__ import annotations

import logging
import os
import re
import time
from collections.abc import Sequence
from pathlib import Path

import pyarrow as pa

from msta.data import features as F
from msta.data import integrity as I
from msta.data import layout as L
from msta.data.errors import DatasetIntegrityError

logger = logging.getLogger(__name__)

#: Partial writes of the writer's atomic write (``<name>.tmp``, then renamed to ``<name>``).
_CHUNK_TMP = re.compile(r"chunk-\d+/file-\d+\.parquet\.tmp")
_META_TMP = frozenset(f"{rel}.tmp" for rel in (
    L.INFO_PATH, L.STATS_PATH, L.TASKS_PATH, L.MSTA_META_PATH, L.MANIFEST_PATH,
    f"{L.META_DIR}/{L.CARD_NAME}"))
_SHOWN = 4  # file names listed in the warning line


def is_partial_write(rel: str) -> bool:
    """True for a ``.tmp`` file the writer itself creates (a write a kill interrupted)."""
    for sub in L.NUMBERED_DIRS:
        if rel.startswith(sub + "/") and _CHUNK_TMP.fullmatch(rel[len(sub) + 1:]):
            return True
    return rel in _META_TMP


def _new_folder(root: Path) -> Path:
    """A fresh ``.msta-quarantine/<UTC time>[-n]`` folder."""
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
    for n in range(1000):
        folder = root / L.QUARANTINE_DIR / (stamp if n == 0 else f"{stamp}-{n}")
        try:
            folder.mkdir(parents=True)
            return folder
        except FileExistsError:
            continue
    raise FileExistsError(f"{root / L.QUARANTINE_DIR}: cannot create a folder for {stamp}")


def set_aside(root: str | Path, rels: Sequence[str], why: str) -> Path | None:
    """Delete the writer's partial writes among ``rels`` and move the other files into a new
    quarantine folder (relative paths kept), with one warning line.

    Args:
        root: dataset root.
        rels: files relative to ``root`` that no commit lists.
        why: what the last commit says (for the message), e.g. "meta/info.json: 4 episodes".

    Returns:
        the quarantine folder, or None when nothing had to be moved.
    """
    root = Path(root)
    for rel in rels:
        if is_partial_write(rel):
            (root / rel).unlink(missing_ok=True)
    moved = sorted(rel for rel in rels if not is_partial_write(rel))
    if not moved:
        return None
    folder = _new_folder(root)
    for rel in moved:
        (folder / rel).parent.mkdir(parents=True, exist_ok=True)
        os.replace(root / rel, folder / rel)
    shown = ", ".join(moved[:_SHOWN]) + (f" and {len(moved) - _SHOWN} more"
                                         if len(moved) > _SHOWN else "")
    logger.warning(
        "%s: moved %d file(s) that the last commit does not list (%s) to %s: %s. They are the "
        "files of an unfinished commit (a killed writer), episodes committed under a newer "
        "meta/ (restored from an older copy?) or files of your own; nothing was deleted",
        root, len(moved), why, folder, shown)
    return folder


def committed_files(table: pa.Table, chunks_size: int) -> tuple[set[str], int]:
    """The data and episode files that the committed episodes' rows name (``data/*`` and
    ``meta/episodes/*`` columns of the episode table), and the number after the highest: the
    next file a writer may create without touching one of them (msta writes data file N
    with episode file N; LeRobot's tools number the two series apart)."""
    out: set[str] = set()
    top = -1
    for template, prefix in ((L.DATA_PATH, "data"), (L.EPISODES_PATH, L.EPISODES_DIR)):
        if f"{prefix}/chunk_index" not in table.column_names:
            continue
        nums = {F.file_number(c, f, chunks_size) for c, f in zip(
            table.column(f"{prefix}/chunk_index").to_pylist(),
            table.column(f"{prefix}/file_index").to_pylist(), strict=True)}
        out |= {F.numbered_path(template, n, chunks_size) for n in nums}
        top = max([top, *nums])
    return out, top + 1


def set_aside_leftovers(root: Path, gen: I.Generation | None, committed: set[str],
                        total: int) -> Path | None:
    """What a writer does on opening a dataset: :func:`set_aside` every file of the chunk
    directories (and ``meta/*.tmp``) that the commit does not list.

    Args:
        root: dataset root.
        gen: the generation on disk (None: a dataset without a manifest).
        committed: the numbered files of the committed episodes (from the episode table).
        total: the committed episode count (for messages).

    Raises:
        DatasetIntegrityError: touching nothing, for a numbered file of the committed
            episodes that no record lists, or, without a manifest, a numbered file beyond
            them (nothing tells a killed writer's leftover from a stale ``info.json``).
    """
    leftovers = I.leftover_files(root, set(gen.files) if gen else committed)
    for rel in leftovers:
        numbered = rel.endswith(".parquet") and any(rel.startswith(d + "/")
                                                    for d in L.NUMBERED_DIRS)
        if rel in committed or (gen is None and numbered):
            raise DatasetIntegrityError(
                f"{root / rel}: beyond the {total} episodes of {L.INFO_PATH}, and no record "
                f"({L.MANIFEST_PATH}) tells a killed writer's leftover from a stale info.json; "
                "nothing was changed: check info.json, or move the file away if it is a "
                "leftover")
    return set_aside(root, leftovers, f"{L.INFO_PATH}: {total} episodes")
