"""Paths inside a root, with no symbolic link leading out: the one check every reader,
writer, quarantine and push uses.

A dataset, a checkpoint or a folder to push is a root. Anything found under it (a chunk
folder, the quarantine, a file to upload) may be a symbolic link that someone else made, and
following it would read, move, rewrite or publish files outside the root (a link to a token
file would upload the token). :func:`inside` resolves a path and refuses one whose real
location is outside the root's real location; :func:`files_under` lists the regular files
under a root without following any link, and names the links it met so a caller can refuse
or skip them in one line.
"""

from __future__ import annotations

import os
from pathlib import Path


class PathOutsideRootError(ValueError):
    """A path under a root leads outside it through a symbolic link (both named)."""


def inside(root: str | Path, path: str | Path, *, what: str = "root") -> Path:
    """``path`` (absolute, or relative to ``root``) after checking that its real location,
    every symbolic link along it followed, is ``root``'s real location or below it.

    A path that does not exist yet is checked through its nearest existing parent, so a
    writer may ask before it creates a file.

    Args:
        root: the folder the path must stay in.
        path: the path to check.
        what: the root's kind in the message ("dataset", "checkpoint", "folder to push").

    Returns:
        ``root / path`` (not resolved: callers keep the names they know).

    Raises:
        PathOutsideRootError: naming the path, where it leads and the root.
    """
    root = Path(root)
    full = root / path
    base = Path(os.path.realpath(root))
    real = Path(os.path.realpath(full))
    if real != base and base not in real.parents:
        raise PathOutsideRootError(
            f"{full}: a symbolic link leading outside the {what} {root} (to {real}); refused, "
            "nothing was read, written or moved")
    return full


def _walk(root: Path) -> tuple[dict[str, Path], list[str]]:
    """One pass over ``root``, no link followed: its regular files by relative POSIX path,
    and the relative paths of its symbolic links, both sorted."""
    files_found: dict[str, Path] = {}
    links: list[str] = []
    for folder, dirs, files in os.walk(root, followlinks=False):
        for name in dirs + files:
            path = Path(folder) / name
            rel = path.relative_to(root).as_posix()
            if path.is_symlink():
                links.append(rel)
            elif name in files and path.is_file():
                files_found[rel] = path
    return dict(sorted(files_found.items())), sorted(links)


def links_under(root: str | Path) -> list[str]:
    """Relative paths of the symbolic links under ``root`` (none followed), sorted."""
    return _walk(Path(root))[1]


def _refuse(root: str | Path, found: list[str], what: str, error: type[Exception]) -> None:
    if found:
        shown = ", ".join(found[:4]) + (f" and {len(found) - 4} more" if len(found) > 4 else "")
        raise error(
            f"{root}: the {what} holds symbolic links ({shown}); msta does not follow links "
            "out of a root, replace them with the files themselves")


def refuse_links(root: str | Path, *, what: str = "root",
                 error: type[Exception] = PathOutsideRootError) -> None:
    """Raise ``error`` when a symbolic link is anywhere under ``root`` (the links named): what
    a writer checks before it moves or rewrites files in a root."""
    _refuse(root, links_under(root), what, error)


def files_under(root: str | Path, *, what: str = "root",
                links: str = "refuse") -> dict[str, Path]:
    """The regular files under ``root`` by relative POSIX path, no symbolic link followed
    (one pass over the tree).

    Args:
        root: the folder to list.
        what: the root's kind in the message.
        links: "refuse" raises on the first link found (named with the others), "skip"
            leaves links out (a caller that says so itself).

    Raises:
        PathOutsideRootError: ``links="refuse"`` and a symbolic link is under ``root``
            (``root`` itself may be a link: only links below it count).
    """
    if links not in ("refuse", "skip"):
        raise ValueError(f"links={links!r}: expected 'refuse' or 'skip'")
    found, linked = _walk(Path(root))
    if links == "refuse":
        _refuse(root, linked, what, PathOutsideRootError)
    return found
