"""The on-disk names of an msta dataset (LeRobot v3.0 plus msta's own files), defined once.

Every path is relative to the dataset root and uses ``/`` (it is also the path inside a hub
repo). The writer, the reader, the integrity checks, the hub client and the commands that
look at a dataset root all take the names from here, and where Hugging Face's and LeRobot's
caches are (:func:`hf_home`, :func:`lerobot_home`).
"""

from __future__ import annotations

import os
from pathlib import Path

#: Directory of the metadata files.
META_DIR = "meta"
#: LeRobot's dataset description; writing it is the commit point of the msta writer.
INFO_PATH = f"{META_DIR}/info.json"
#: Per-channel statistics (LeRobot's format).
STATS_PATH = f"{META_DIR}/stats.json"
#: The task strings and their indices.
TASKS_PATH = f"{META_DIR}/tasks.parquet"
#: msta's schema version and sensor list.
MSTA_META_PATH = f"{META_DIR}/msta.json"
#: msta's checksum manifest: size and sha256 of every committed file (msta.data.integrity).
MANIFEST_PATH = f"{META_DIR}/msta_checksums.json"
#: Directory of the frame Parquet files.
DATA_DIR = "data"
#: Directory of the per-episode Parquet files.
EPISODES_DIR = f"{META_DIR}/episodes"
#: Template of a frame file (LeRobot's ``data_path``).
DATA_PATH = f"{DATA_DIR}/chunk-{{chunk_index:03d}}/file-{{file_index:03d}}.parquet"
#: Template of an episode-table file.
EPISODES_PATH = f"{EPISODES_DIR}/chunk-{{chunk_index:03d}}/file-{{file_index:03d}}.parquet"
#: Glob of the numbered files inside DATA_DIR or EPISODES_DIR.
NUMBERED_GLOB = "chunk-*/file-*.parquet"
#: Directories whose numbered Parquet files make up the committed episodes.
NUMBERED_DIRS = (DATA_DIR, EPISODES_DIR)
#: Where a writer moves files it finds in the chunk directories that no commit lists
#: (``<QUARANTINE_DIR>/<UTC time>/<relative path>``; msta.data.quarantine): never read, never
#: pushed.
QUARANTINE_DIR = ".msta-quarantine"
#: The exclusive lock of a directory (a dataset root, a training run; msta.data.locking).
LOCK_NAME = ".msta.lock"
#: A dataset card or model card on the hub.
CARD_NAME = "README.md"
#: The hub dataset viewer's glob of the frame files (a dataset card's ``configs``).
DATA_FILES_GLOB = f"{DATA_DIR}/*/*.parquet"
#: Files of a directory that are machine-local and never pushed: the lock, MuJoCo's log.
LOCAL_ONLY_FILES = frozenset({LOCK_NAME, "MUJOCO_LOG.TXT"})


def info_path(root: str | Path) -> Path:
    """``<root>/meta/info.json``."""
    return Path(root) / INFO_PATH


def is_dataset_root(root: str | Path) -> bool:
    """True when ``root`` holds ``meta/info.json`` (a dataset, finished or being appended)."""
    return info_path(root).is_file()


def hf_home() -> Path:
    """huggingface_hub's ``HF_HOME``, read now by its rule: ``HF_HOME``, else
    ``$XDG_CACHE_HOME/huggingface``, else ``~/.cache/huggingface`` (``~`` and ``$VARS``
    expanded)."""
    default = os.path.join(os.environ.get("XDG_CACHE_HOME")
                           or os.path.join(os.path.expanduser("~"), ".cache"), "huggingface")
    return Path(os.path.expandvars(os.path.expanduser(os.environ.get("HF_HOME") or default)))


def lerobot_home() -> Path:
    """LeRobot's ``HF_LEROBOT_HOME``, read now by its rule: ``HF_LEROBOT_HOME``, else
    ``<HF_HOME>/lerobot`` (``~`` and ``$VARS`` expanded): where a dataset named by repo id
    alone lives."""
    own = os.environ.get("HF_LEROBOT_HOME")
    return Path(os.path.expandvars(os.path.expanduser(own))) if own else hf_home() / "lerobot"
