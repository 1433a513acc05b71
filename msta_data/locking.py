"""One process at a time per directory: an exclusive ``flock`` on ``<dir>/.msta.lock``.

The dataset writer holds it on a dataset root, ``msta-hub push-dataset`` on the dataset it
publishes, and every command that writes a run directory (msta-train, msta-correct,
msta-finetune, msta-finetune-ppo, msta-train-teacher, msta-eval, msta-compare, msta-repro)
on its ``--output_dir`` for the whole run (:func:`hold_directory`). The lock is released
when the file descriptor is closed or the process dies (SIGKILL included), so a killed
holder never leaves a stale lock; the file keeps the holder's pid for the error message.
"""

from __future__ import annotations

import fcntl
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from msta.data.errors import DirectoryLockedError
from msta.data.layout import LOCK_NAME


def lock_directory(directory: str | Path, holder: str = "another writer",
                   error: type[DirectoryLockedError] = DirectoryLockedError) -> int:
    """Take the exclusive lock of ``directory`` (which must exist) without waiting.

    Args:
        directory: the directory to lock.
        holder: who holds it, for the error message ("another writer", "another msta-train").
        error: the exception class raised when the lock is held.

    Returns:
        the lock's file descriptor; ``os.close`` it to release the lock.

    Raises:
        DirectoryLockedError (or ``error``): another process holds the lock (pid named).
    """
    path = Path(directory) / LOCK_NAME
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        pid = path.read_text().strip() or "?"
        raise error(f"{directory}: {holder} (pid {pid}) holds {path}; only one at a time") \
            from None
    os.ftruncate(fd, 0)
    os.write(fd, str(os.getpid()).encode())
    return fd


@contextmanager
def hold_directory(directory: str | Path, holder: str = "another run") -> Iterator[Path]:
    """Create ``directory`` and hold its lock (:func:`lock_directory`) for the block: a run
    directory has one writer, and another process gets :class:`DirectoryLockedError` at
    once, naming the holder's pid.

    Args:
        directory: the run directory.
        holder: who holds it, for the error message ("another msta-correct run").

    Yields:
        ``directory`` as a Path.
    """
    path = Path(directory)
    path.mkdir(parents=True, exist_ok=True)
    fd = lock_directory(path, holder)
    try:
        yield path
    finally:
        os.close(fd)
