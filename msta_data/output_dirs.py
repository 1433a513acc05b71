"""A command deletes only what it wrote: output folders a command may clear carry its mark.

A command that starts its ``--output_dir`` afresh (the demo, the device check, the
benchmarks' work folders) first claims the folder with :func:`claim_output_dir`: a folder
that does not exist is created, an empty one is taken, and either gets the marker file
:data:`MARKER` naming the command. A folder holding anything else without that marker (a
user's files, ``--output_dir=.``, another tool's outputs) is refused with one line that
names it, and nothing is deleted. :func:`clear_output_dir` empties only a folder claimed so.
A folder marked by another msta command is refused too (``msta-demo`` does not clear
msta-eval's outputs). A folder written before the marker existed is recognised by its
entries: every one a name the command writes (``legacy``), one of them a name only it
writes (``sign``), so a folder of other tools' outputs with common names is not taken.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from msta.data.cli import usage_error

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
                     legacy: frozenset[str] = frozenset(),
                     sign: frozenset[str] = frozenset()) -> Path:
    """``path`` as ``command``'s output folder: created (with parents) when missing, taken
    when empty or already marked by an msta command; marked with :data:`MARKER`.

    Args:
        path: the folder.
        command: the command's name, written into the marker and named in errors.
        option: the option the folder came from, for the message.
        legacy: the names the command writes at the folder's top: an unmarked folder
            holding only these, ``sign`` among them, is one of its runs from before the
            marker.
        sign: names of ``legacy`` no other command writes.

    Raises:
        OutputDirError: ``path`` is a file (or a link), or a folder that holds files
            without msta's marker, or marked by another msta command.
    """
    path = Path(path)
    if path.is_symlink() or (path.exists() and not path.is_dir()):
        raise OutputDirError(f"{option}={path} is not a folder; give a folder path")
    if path.is_dir():
        owner, names = _owner(path), {c.name for c in path.iterdir()}
        if owner is not None and owner != command:
            raise OutputDirError(f"{option}={path} holds {owner}'s outputs; choose another "
                                 f"{option} for {command}")
        old_run = names <= legacy and bool(names & sign)
        if owner is None and names and not old_run:
            raise OutputDirError(f"{option}={path} holds files that {command} did not write "
                                 f"(no {MARKER}); choose another {option} or empty it")
    path.mkdir(parents=True, exist_ok=True)
    (path / MARKER).write_text(json.dumps({"command": command}) + "\n")
    return path


def clear_output_dir(path: str | Path, command: str, option: str = "--output_dir",
                     legacy: frozenset[str] = frozenset(),
                     sign: frozenset[str] = frozenset()) -> Path:
    """Empty ``command``'s output folder for a fresh run (after :func:`claim_output_dir`'s
    checks: a folder the command did not write is refused, not emptied); returns it,
    marked."""
    path = claim_output_dir(path, command, option, legacy, sign)
    for child in path.iterdir():
        if child.name == MARKER:
            continue
        if child.is_dir() and not child.is_symlink():
            shutil.rmtree(child)
        else:
            child.unlink()
    return path


def command_output_dir(path: str | Path, command: str, prog: str, clear: bool = False,
                       legacy: frozenset[str] = frozenset(),
                       sign: frozenset[str] = frozenset()) -> Path:
    """:func:`claim_output_dir` (or :func:`clear_output_dir` with ``clear``) for a command
    line: a refusal exits 2 with one line, ``<prog>: error: ...``."""
    try:
        return (clear_output_dir if clear else claim_output_dir)(path, command, legacy=legacy,
                                                                 sign=sign)
    except OutputDirError as e:
        raise usage_error(f"{prog}: error: {e}") from None
