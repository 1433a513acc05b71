"""Local path or hub id? The one rule every command applies to ``--dataset`` / ``--policy``.

1. An existing path is local, whatever it looks like.
2. A spec written as a path (absolute, ``./``, ``../``, ``~``, more than two components, or
   a first component that exists here) is local: when it is missing the error says so and
   gives the absolute path; no hub is asked.
3. Otherwise a ``[datasets/]user/name[@revision]`` is fetched (once per commit, hash
   verified, :func:`msta.data.hub_pull.materialize`) from ``HF_ENDPOINT`` — only when that is
   set. msta never contacts a hub it was not pointed at, so with ``HF_ENDPOINT`` unset a
   mistyped relative path (``outpts/a1``) is reported as a missing local path, not looked
   up on huggingface.co.
4. A hub failure is reported with both readings (no local path, and what the hub said).

:func:`locate` applies the rules; :func:`locate_dataset` (a verified LeRobot dataset root)
and :func:`locate_checkpoint` (a checkpoint directory) add what ``--dataset`` and
``--policy.path`` need; :func:`reads_as_hub_id` says which reading a spec gets.
"""

from __future__ import annotations

import os
from pathlib import Path

from msta.data import layout as L
from msta.data.hub_ids import is_hub_id
from msta.data.hub_pull import materialize
from msta.data.integrity import VerifyMode, verify_dataset


def looks_like_path(spec: str) -> bool:
    """True when ``spec`` can only mean a local path (rule 2)."""
    text = spec.strip()
    path = Path(text).expanduser()
    if path.is_absolute() or text.startswith((".", "~")):
        return True
    parts = Path(text.split("@", 1)[0]).parts
    if parts and parts[0] == "datasets":
        parts = parts[1:]
    return len(parts) != 2 or Path(parts[0]).exists()


def reads_as_hub_id(spec: str) -> bool:
    """True when :func:`locate` reads ``spec`` as a hub id (rule 3), not as a local path."""
    return (not Path(spec).expanduser().exists() and not looks_like_path(spec)
            and is_hub_id(spec))


def locate(spec: str, repo_type: str, flag: str, revision: str | None = None) -> Path:
    """A local directory for a path or hub id, by the rules of the module docstring.

    Args:
        spec: the command-line value.
        repo_type: ``"dataset"`` or ``"model"`` (which hub repo kind).
        flag: the option's name for messages, e.g. ``"--dataset"``.
        revision: hub revision (branch, tag or commit) for a hub id that names none.

    Raises:
        FileNotFoundError: one line: the local path that does not exist, and what the hub
            said when it was asked.
    """
    path = Path(spec).expanduser()
    if path.exists():
        return path
    if revision and "@" not in spec:
        spec = f"{spec}@{revision}"
    noun = "dataset" if repo_type == "dataset" else "checkpoint"
    where = f"{flag} {spec!r}: no such {noun} directory ({path.absolute()})"
    if looks_like_path(spec) or not is_hub_id(spec):
        raise FileNotFoundError(where)
    endpoint = os.environ.get("HF_ENDPOINT")
    if not endpoint:
        raise FileNotFoundError(f"{where}; to read it as a hub {repo_type} id set HF_ENDPOINT "
                                "(msta asks no hub it was not pointed at)")
    try:
        return materialize(spec, repo_type=repo_type)
    except Exception as e:  # any hub failure: say what was tried
        first = str(e).strip().splitlines()[0] if str(e).strip() else ""
        raise FileNotFoundError(f"{where}, and the hub at {endpoint} has no {repo_type} "
                                f"{spec!r} ({type(e).__name__}: {first})") from e


def locate_dataset(spec: str, flag: str = "--dataset", verify: VerifyMode | None = "full",
                   ) -> Path:
    """A local LeRobot dataset root for a path or hub id (:func:`locate`), verified.

    Args:
        spec: a dataset root, or ``[datasets/]user/name[@revision]``.
        flag: the option's name for messages.
        verify: check the committed files against the checksum manifest ("full" hashes
            every file, "sizes" only sizes; None: no check).

    Raises:
        ValueError: ``spec`` is empty.
        FileNotFoundError: no such directory (absolute path named) or not a dataset.
        DatasetIntegrityError: a committed file is missing or changed (file named).
    """
    if not spec:
        raise ValueError(f"{flag} is required (a dataset root or a hub id)")
    path = locate(spec, "dataset", flag)
    if not L.is_dataset_root(path):
        raise FileNotFoundError(f"{flag} {spec!r}: {L.info_path(path)} missing "
                                "(not a LeRobot v3.0 dataset)")
    if verify is not None:
        verify_dataset(path, verify)
    return path


def locate_checkpoint(spec: str, flag: str = "--policy.path", revision: str | None = None,
                      ) -> Path:
    """A local checkpoint directory for a path or hub id (:func:`locate`).

    Args:
        spec: a checkpoint directory, or ``user/name[@revision]``.
        flag: the option's name for messages.
        revision: hub revision for an id that names none.

    Raises:
        ValueError: ``spec`` is empty.
        FileNotFoundError: no such directory (absolute path named), or a file.
    """
    if not spec:
        raise ValueError(f"{flag} is required (a checkpoint directory or a hub id)")
    path = locate(spec, "model", flag, revision)
    if not path.is_dir():
        raise FileNotFoundError(f"{flag} {spec!r}: {path} is not a checkpoint directory")
    return path
