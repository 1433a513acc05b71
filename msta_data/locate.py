"""Local path or hub id? The one rule every command applies to ``--dataset`` / ``--policy``.

1. An existing path is local, whatever it looks like.
2. A spec written as a path (absolute, ``./``, ``../``, ``~``, more than two components, or
   a first component that exists here) is local: when it is missing the error says so and
   gives the absolute path; no hub is asked.
3. Otherwise a ``[datasets/]user/name[@revision]`` is fetched (once per commit, hash
   verified, :func:`msta_data.hub_pull.materialize`) from ``HF_ENDPOINT`` — only when that is
   set. msta never contacts a hub it was not pointed at, so with ``HF_ENDPOINT`` unset a
   mistyped relative path (``outpts/a1``) is reported as a missing local path, not looked
   up on huggingface.co.
4. A hub failure is reported with both readings (no local path, and what the hub said).
"""

from __future__ import annotations

import os
from pathlib import Path

from msta_data.hub_ids import is_hub_id
from msta_data.hub_pull import materialize


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


def locate(spec: str, repo_type: str, flag: str) -> Path:
    """A local directory for a path or hub id, by the rules of the module docstring.

    Args:
        spec: the command-line value.
        repo_type: ``"dataset"`` or ``"model"`` (which hub repo kind).
        flag: the option's name for messages, e.g. ``"--dataset"``.

    Raises:
        FileNotFoundError: one line: the local path that does not exist, and what the hub
            said when it was asked.
    """
    path = Path(spec).expanduser()
    if path.exists():
        return path
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
