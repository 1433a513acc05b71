"""Commits of one repo on disk, stored so that their size grows linearly with the changes.

Each ``commits/<sha>.json`` holds the commit's metadata and its *diff* against its first
parent (``changes``: path -> entry for added or modified files, ``removed``: deleted paths).
A full file table is written to ``trees/<sha>.json`` only for root commits and when the diff
entries accumulated since the last snapshot reach half the table's size (and at least 64):
every snapshot is paid for by at least half as many diff entries, so storage stays linear in
the number of changes, and reading a revision reads one snapshot plus fewer diff entries than
max(64, half the table).

Commits written by earlier versions (``files``: the full table in the commit JSON) are read
as snapshots, so old roots keep working unchanged. Commits are immutable, so parsed commits
and rebuilt tables are cached (bounded LRU).
"""

from __future__ import annotations

import hashlib
import json
import secrets
import threading
from collections import OrderedDict
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from msta.data.hub_server.fsio import read_json, write_json

MIN_CHAIN = 64


@dataclass(frozen=True)
class FileEntry:
    """One file of a commit's tree."""

    sha256: str
    size: int
    oid: str  # git blob id: of the content (regular) or of the LFS pointer (lfs)
    lfs: bool

    def to_json(self) -> dict:
        return {"sha256": self.sha256, "size": self.size, "oid": self.oid, "lfs": self.lfs}

    @staticmethod
    def from_json(d: dict) -> FileEntry:
        return FileEntry(sha256=d["sha256"], size=d["size"], oid=d["oid"], lfs=d["lfs"])


@dataclass(frozen=True)
class CommitInfo:
    """A commit's metadata (no file table)."""

    id: str
    parents: list[str]
    title: str
    message: str
    author: str
    date: str


@dataclass(frozen=True)
class Commit(CommitInfo):
    """A commit with its complete file table."""

    files: dict[str, FileEntry]


class _Folder:
    """A folder of :func:`path_clash`'s index: its files (name -> path) and sub-folders."""

    __slots__ = ("files", "folders")

    def __init__(self) -> None:
        self.files: dict[str, str] = {}
        self.folders: dict[str, _Folder] = {}

    def any_file(self) -> str:
        node = self
        while not node.files:
            node = next(iter(node.folders.values()))
        return next(iter(node.files.values()))


def path_clash(kept: Iterable[str], added: Iterable[str]) -> tuple[str, str] | None:
    """``(added path, other path)`` when an added file would sit where a folder is, or under a
    file (``a`` beside ``a/x``), among ``added`` or against ``kept``; None when all fit.

    One pass over the paths' parts (no prefix strings), so the cost is linear in the length
    of all paths, however deep they nest. Clashes among ``kept`` alone (older roots) are let be.
    """
    root = _Folder()
    for path in kept:
        node = root
        *parents, name = path.split("/")
        for part in parents:
            node = node.folders.get(part) or node.folders.setdefault(part, _Folder())
        node.files[name] = path
    for path in added:
        node = root
        *parents, name = path.split("/")
        for part in parents:
            if part in node.files:
                return path, node.files[part]
            node = node.folders.get(part) or node.folders.setdefault(part, _Folder())
        if name in node.folders:
            return path, node.folders[name].any_file()
        node.files[name] = path
    return None


class _Lru:
    """A small thread-safe LRU map."""

    def __init__(self, size: int):
        self._size = size
        self._data: OrderedDict[Any, Any] = OrderedDict()
        self._lock = threading.Lock()

    def get(self, key: Any) -> Any:
        with self._lock:
            if key in self._data:
                self._data.move_to_end(key)
                return self._data[key]
        return None

    def put(self, key: Any, value: Any) -> None:
        with self._lock:
            self._data[key] = value
            self._data.move_to_end(key)
            while len(self._data) > self._size:
                self._data.popitem(last=False)


class CommitStore:
    """Reads and writes the commits of repos (one instance per server root, shared caches)."""

    def __init__(self) -> None:
        self._raw = _Lru(8192)  # (repo dir, sha) -> parsed commit JSON
        self._trees = _Lru(16)  # (repo dir, sha) -> {path: FileEntry}

    # ---------------------------------------------------------------- reading
    def _read(self, repo_dir: Path, sha: str) -> dict:
        key = (str(repo_dir), sha)
        d = self._raw.get(key)
        if d is None:
            d = read_json(repo_dir / "commits" / f"{sha}.json")
            if "files" in d:  # legacy full-table commit: keep only metadata in the cache
                self._trees.put(key, {p: FileEntry.from_json(e) for p, e in d["files"].items()})
                d = {k: v for k, v in d.items() if k != "files"} | {"legacy": True}
            self._raw.put(key, d)
        return d

    def exists(self, repo_dir: Path, sha: str) -> bool:
        return (repo_dir / "commits" / f"{sha}.json").is_file()

    def info(self, repo_dir: Path, sha: str) -> CommitInfo:
        d = self._read(repo_dir, sha)
        return CommitInfo(d["id"], list(d["parents"]), d["title"], d["message"], d["author"], d["date"])

    def tree(self, repo_dir: Path, sha: str) -> dict[str, FileEntry]:
        """The complete file table of commit ``sha`` (a fresh dict the caller may change)."""
        chain: list[dict] = []
        cur = sha
        while True:
            cached = self._trees.get((str(repo_dir), cur))
            if cached is not None:
                base = cached
                break
            d = self._read(repo_dir, cur)
            if d.get("legacy"):
                cached = self._trees.get((str(repo_dir), cur))
                if cached is None:  # evicted: read the legacy file again
                    raw = read_json(repo_dir / "commits" / f"{cur}.json")
                    cached = {p: FileEntry.from_json(e) for p, e in raw["files"].items()}
                base = cached
                break
            if d.get("snapshot"):
                snap = read_json(repo_dir / "trees" / f"{cur}.json")
                base = {p: FileEntry.from_json(e) for p, e in snap["files"].items()}
                break
            chain.append(d)
            cur = d["parents"][0]
        files = dict(base)
        for d in reversed(chain):
            for path in d["removed"]:
                files.pop(path, None)
            files.update({p: FileEntry.from_json(e) for p, e in d["changes"].items()})
        self._trees.put((str(repo_dir), sha), files)
        return dict(files)

    def commit(self, repo_dir: Path, sha: str) -> Commit:
        info = self.info(repo_dir, sha)
        return Commit(**info.__dict__, files=self.tree(repo_dir, sha))

    def changed_paths(self, repo_dir: Path, sha: str) -> set[str]:
        """Paths whose entry differs between commit ``sha`` and its first parent."""
        d = self._read(repo_dir, sha)
        if not d["parents"]:
            return set(self.tree(repo_dir, sha))
        if not d.get("legacy"):
            return set(d["changes"]) | set(d["removed"])
        mine, theirs = self.tree(repo_dir, sha), self.tree(repo_dir, d["parents"][0])
        return {p for p in mine.keys() | theirs.keys() if mine.get(p) != theirs.get(p)}

    # ---------------------------------------------------------------- writing
    def write(self, repo_dir: Path, parents: list[str], files: dict[str, FileEntry], title: str,
              message: str, author: str, date: str) -> Commit:
        """Write a new commit whose complete table is ``files``; returns it."""
        parent_files = self.tree(repo_dir, parents[0]) if parents else {}
        changes = {p: e for p, e in files.items() if parent_files.get(p) != e}
        removed = sorted(p for p in parent_files if p not in files)
        chain = max(1, len(changes) + len(removed))
        if parents:
            chain += int(self._read(repo_dir, parents[0]).get("chain", 0))
        snapshot = not parents or chain >= max(len(files) // 2, MIN_CHAIN)
        body = {"parents": parents, "title": title, "message": message, "author": author, "date": date,
                "changes": {p: e.to_json() for p, e in sorted(changes.items())}, "removed": removed,
                "nonce": secrets.token_hex(8)}
        sha = hashlib.sha1(json.dumps(body, sort_keys=True).encode()).hexdigest()
        del body["nonce"]
        body.update(id=sha, snapshot=snapshot, chain=0 if snapshot else chain)
        if snapshot:
            (repo_dir / "trees").mkdir(exist_ok=True)
            write_json(repo_dir / "trees" / f"{sha}.json",
                       {"files": {p: e.to_json() for p, e in sorted(files.items())}})
        write_json(repo_dir / "commits" / f"{sha}.json", body)
        self._trees.put((str(repo_dir), sha), dict(files))
        return Commit(sha, parents, title, message, author, date, dict(files))
