"""Tree listings of one commit's file table: the entries ``/tree/`` and ``/paths-info/`` return.

A directory's ``oid`` is the git tree id of its contents, as git computes it (files as blobs
of mode 100644, an LFS file as its pointer, sub-directories by their own tree id). The file
table is read once into a nested index and each tree id is computed once from its children,
so a listing costs time linear in the file table and the answer, whatever the number and
depth of the directories.
"""

from __future__ import annotations

import hashlib

from msta.data.hub_server.commits import FileEntry
from msta.data.hub_server.storage import StoreError, lfs_pointer


class _Dir:
    """One directory of the index: its files and sub-directories by name."""

    __slots__ = ("dirs", "files", "oid")

    def __init__(self) -> None:
        self.files: dict[str, FileEntry] = {}
        self.dirs: dict[str, _Dir] = {}
        self.oid = ""


def _index(files: dict[str, FileEntry]) -> _Dir:
    root = _Dir()
    for path, entry in files.items():
        node = root
        *parents, name = path.split("/")
        for part in parents:
            child = node.dirs.get(part)
            node = child if child is not None else node.dirs.setdefault(part, _Dir())
        node.files[name] = entry
    return root


def _utf8(name: str) -> bytes:
    """``name`` as UTF-8; a lone surrogate an older server let in is kept as its bytes, so
    such a root's listings still work (new paths are checked: boundary.repo_path)."""
    return name.encode("utf-8", "surrogatepass")


def _set_oids(top: _Dir) -> None:
    """Git tree id of ``top`` and every directory below it (post-order, no recursion: paths
    may nest 2,000 levels)."""
    stack: list[tuple[_Dir, bool]] = [(top, False)]
    while stack:
        node, children_done = stack.pop()
        if node.oid:
            continue
        if not children_done:
            stack.append((node, True))
            stack.extend((d, False) for d in node.dirs.values() if not d.oid)
            continue
        items = [(_utf8(n) + b"/", b"40000 " + _utf8(n), d.oid) for n, d in node.dirs.items()]
        items += [(_utf8(n), b"100644 " + _utf8(n), e.oid) for n, e in node.files.items()]
        body = b"".join(head + b"\0" + bytes.fromhex(oid) for _, head, oid in sorted(items))
        node.oid = hashlib.sha1(b"tree %d\0" % len(body) + body).hexdigest()


def _find(root: _Dir, path: str) -> _Dir | None:
    node: _Dir | None = root
    for part in path.split("/") if path else []:
        node = node.dirs.get(part)
        if node is None:
            return None
    return node


def file_json(path: str, entry: FileEntry) -> dict:
    """The hub's JSON for a file entry."""
    out = {"type": "file", "oid": entry.oid, "size": entry.size, "path": path}
    if entry.lfs:
        out["lfs"] = {"oid": entry.sha256, "size": entry.size,
                      "pointerSize": len(lfs_pointer(entry.sha256, entry.size))}
    return out


def _dir_json(path: str, node: _Dir) -> dict:
    _set_oids(node)
    return {"type": "directory", "oid": node.oid, "size": 0, "path": path}


def tree_entries(files: dict[str, FileEntry], path: str, recursive: bool) -> list[dict]:
    """Tree listing of ``path`` ('' = root) sorted by path; StoreError when it is no directory."""
    path = path.strip("/")
    top = _find(_index(files), path)
    if top is None:
        raise StoreError("entry_not_found", f"path '{path}' not found in this revision")
    _set_oids(top)
    out: list[dict] = []
    todo = [(path, top)]
    while todo:
        where, node = todo.pop()
        prefix = where + "/" if where else ""
        out.extend(file_json(prefix + n, e) for n, e in node.files.items())
        for name, child in node.dirs.items():
            out.append(_dir_json(prefix + name, child))
            if recursive:
                todo.append((prefix + name, child))
    return sorted(out, key=lambda e: e["path"])


def paths_info(files: dict[str, FileEntry], paths: list[str]) -> list[dict]:
    """Entries of the requested paths that exist (files and directories), in request order."""
    root = _index(files)
    out = []
    for path in dict.fromkeys(p.strip("/") for p in paths):
        if path in files:
            out.append(file_json(path, files[path]))
        elif path and (node := _find(root, path)) is not None:
            out.append(_dir_json(path, node))
    return out
