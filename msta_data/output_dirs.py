"""A command deletes only what it wrote: output folders a command may clear carry its mark.

A command that starts its ``--output_dir`` afresh (the demo, the device check, the
benchmarks' work folders) first claims the folder with :func:`claim_output_dir`: a folder
that does not exist is created, an empty one is taken, and either gets the marker file
:data:`MARKER` naming the command. A folder holding anything else without that marker (a
user's files, ``--output_dir=.``, another tool's outputs) is refused with one line that
names it, and nothing is deleted. :func:`clear_output_dir` empties only a folder claimed so.
A folder written before the marker existed is recognised by its entries: every one a name
the command writes (``legacy``).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

#: The file that marks a folder as an msta command's output (JSON: the command's name).
MARKER = ".msta-output"


class OutputDirError(ValueError):
    """An output folder the command may not use (a file, or a folder it did not write)."""


def _owner(path: Path) -> str | None:
    marker = path / MARKER
    if not marker.is_file() or marker.is_symlink():
        return None
    try:
        data = json.loads(marker.read_text())
    except (OSError, ValueError, UnicodeDecodeError):
        return None
    return data.get("command") if isinstance(data, dict) else None


def claim_output_dir(path: str | Path, command: str, option: str = "--output_dir",
                     legacy: frozenset[str] = frozenset()) -> Path:
    """``path`` as ``command``'s output folder: created (with parents) when missing, taken
    when empty or already marked by an msta command; marked with :data:`MARKER`.

    Args:
        path: the folder.
        command: the command's name, written into the marker and named in errors.
        option: the option the folder came from, for the message.
        legacy: the names the command writes at the folder's top: an unmarked folder
            holding only these is one of its runs from before the marker.

    Raises:
        OutputDirError: ``path`` is a file (or a link), or a folder that holds files
            without msta's marker.
    """
    path = Path(path)
    if path.is_symlink() or (path.exists() and not path.is_dir()):
        raise OutputDirError(f"{option}={path} is not a folder; give a folder path")
    foreign = [c.name for c in path.iterdir() if c.name not in legacy] if path.is_dir() else []
    if path.is_dir() and _owner(path) is None and foreign:
        raise OutputDirError(f"{option}={path} holds files that {command} did not write (no "
                             f"{MARKER}); choose another {option} or empty it")
    path.mkdir(parents=True, exist_ok=True)
    (path / MARKER).write_text(json.dumps({"command": command}) + "\n")
    return path


def clear_output_dir(path: str | Path, command: str, option: str = "--output_dir",
                     legacy: frozenset[str] = frozenset()) -> Path:
    """Empty ``command``'s output folder for a fresh run (after :func:`claim_output_dir`'s
    checks: a folder msta did not write is refused, not emptied); returns it, marked."""
    path = claim_output_dir(path, command, option, legacy)
    for child in path.iterdir():
        if child.name == MARKER:
            continue
        if child.is_dir() and not child.is_symlink():
            shutil.rmtree(child)
        else:
            child.unlink()
    return path
