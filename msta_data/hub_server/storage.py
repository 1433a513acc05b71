"""On-disk store of the hub server: content-addressed blobs, repos, commits and refs.

Layout under ``root``::

    FORMAT                         storage format marker
    blobs/ab/abcdef...             file contents, named by their sha256
    tmp/                           staging area (same filesystem, so renames are atomic)
    repos/<models|datasets>/<namespace>/<name>/
        repo.json                  id, type, private flag, creation date
        refs.json                  {"branches": {name: sha}, "tags": {name: sha}}
        commits/<sha>.json         one commit: parents, message, author, date, full file table

Every file is written to a temporary name and renamed into place, so a crash never leaves a
half-written blob, commit or ref. A commit records the complete file table of its tree, so
reading any revision needs one JSON file.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import os
import re
import secrets
import shutil
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

FORMAT = "msta-hub-storage 1"
REPO_TYPES = ("model", "dataset")
_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,95}$")
_RESERVED_NAMESPACES = {"api", "datasets", "spaces", "models", "lfs", "resolve"}
SHA_RE = re.compile(r"^[0-9a-f]{40}$")
_SHORT_SHA_RE = re.compile(r"^[0-9a-f]{7,39}$")
_REF_RE = re.compile(r"^(?!.*\.\.)(?!/)(?!.*//)[A-Za-z0-9._/-]{1,200}(?<!/)$")


class StoreError(Exception):
    """A request the store cannot satisfy; ``kind`` maps to an HTTP status and error code."""

    def __init__(self, kind: str, message: str):
        super().__init__(message)
        self.kind = kind
        self.message = message


def now_iso() -> str:
    now = time.time()
    return time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(now)) + f".{int(now * 1000) % 1000:03d}Z"


def git_blob_sha1(data: bytes) -> str:
    """Git object id of a blob (what `git hash-object` prints)."""
    return hashlib.sha1(b"blob %d\0" % len(data) + data).hexdigest()


def lfs_pointer(sha256: str, size: int) -> bytes:
    """The Git LFS pointer file git would store for an LFS object."""
    return f"version https://git-lfs.github.com/spec/v1\noid sha256:{sha256}\nsize {size}\n".encode()


def validate_repo_name(namespace: str, name: str) -> None:
    """Raise StoreError("bad_request") unless ``namespace/name`` is a valid repo id."""
    for part in (namespace, name):
        if not _NAME_RE.match(part) or part.endswith(".git") or ".." in part:
            raise StoreError("bad_request", f"invalid repo id '{namespace}/{name}'")
    if namespace in _RESERVED_NAMESPACES:
        raise StoreError("bad_request", f"namespace '{namespace}' is reserved")


def validate_ref_name(name: str) -> None:
    """Raise StoreError("bad_request") for names git would refuse or that look like a sha."""
    if not _REF_RE.match(name) or SHA_RE.match(name) or name.endswith(".lock"):
        raise StoreError("bad_request", f"invalid branch or tag name '{name}'")


def _atomic_write(path: Path, data: bytes) -> None:
    tmp = path.with_name(f".{path.name}.{secrets.token_hex(6)}.tmp")
    with open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def _write_json(path: Path, obj: Any) -> None:
    _atomic_write(path, json.dumps(obj, indent=1, sort_keys=True).encode())


def _read_json(path: Path) -> Any:
    with open(path, "rb") as f:
        return json.load(f)


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
class Commit:
    """A commit: the complete file table plus metadata."""

    id: str
    parents: list[str]
    title: str
    message: str
    author: str
    date: str
    files: dict[str, FileEntry]


@dataclass(frozen=True)
class RepoMeta:
    repo_type: str
    namespace: str
    name: str
    private: bool
    created_at: str

    @property
    def repo_id(self) -> str:
        return f"{self.namespace}/{self.name}"


class Storage:
    """Thread-safe persistent store. One server process per root (enforced with a file lock).

    Args:
        root: directory holding all server data; created when missing.
    """

    def __init__(self, root: str | os.PathLike):
        self.root = Path(root).resolve()
        self.root.mkdir(parents=True, exist_ok=True)
        marker = self.root / "FORMAT"
        if marker.exists():
            found = marker.read_text().strip()
            if found != FORMAT:
                raise ValueError(f"{self.root}: unknown storage format '{found}' (expected '{FORMAT}')")
        elif any(p.name not in {".lock"} for p in self.root.iterdir()):
            raise ValueError(f"{self.root} is not empty and is not a msta-hub root (no FORMAT file)")
        for sub in ("blobs", "tmp", "repos"):
            (self.root / sub).mkdir(exist_ok=True)
        if not marker.exists():
            _atomic_write(marker, (FORMAT + "\n").encode())
        self._lock_file = open(self.root / ".lock", "a+")  # noqa: SIM115 (held for the lifetime)
        try:
            fcntl.flock(self._lock_file, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            self._lock_file.close()
            raise ValueError(f"{self.root} is in use by another msta-hub server") from None
        self._locks: dict[tuple[str, str], threading.Lock] = {}
        self._locks_guard = threading.Lock()

    def close(self) -> None:
        """Release the root's file lock."""
        with contextlib.suppress(OSError, ValueError):
            fcntl.flock(self._lock_file, fcntl.LOCK_UN)
            self._lock_file.close()

    # ---------------------------------------------------------------- blobs
    def blob_path(self, sha256: str) -> Path:
        return self.root / "blobs" / sha256[:2] / sha256

    def has_blob(self, sha256: str, size: int | None = None) -> bool:
        path = self.blob_path(sha256)
        return path.is_file() and (size is None or path.stat().st_size == size)

    def put_blob_bytes(self, data: bytes) -> tuple[str, int]:
        """Store ``data``; returns (sha256, size)."""
        sha = hashlib.sha256(data).hexdigest()
        if not self.has_blob(sha, len(data)):
            path = self.blob_path(sha)
            path.parent.mkdir(exist_ok=True)
            _atomic_write(path, data)
        return sha, len(data)

    def put_blob_stream(self, stream: IO[bytes], size: int, expected_sha256: str) -> None:
        """Copy exactly ``size`` bytes from ``stream`` and store them if their sha256 matches."""
        tmp = self.root / "tmp" / f"upload-{secrets.token_hex(8)}"
        digest = hashlib.sha256()
        remaining = size
        try:
            with open(tmp, "wb") as f:
                while remaining > 0:
                    chunk = stream.read(min(remaining, 1 << 20))
                    if not chunk:
                        raise StoreError("bad_request", f"upload ended after {size - remaining} of {size} bytes")
                    digest.update(chunk)
                    f.write(chunk)
                    remaining -= len(chunk)
                f.flush()
                os.fsync(f.fileno())
            if digest.hexdigest() != expected_sha256:
                raise StoreError("bad_request", f"uploaded content does not match sha256 {expected_sha256}")
            path = self.blob_path(expected_sha256)
            path.parent.mkdir(exist_ok=True)
            os.replace(tmp, path)
        finally:
            tmp.unlink(missing_ok=True)

    def blob_sha1(self, sha256: str) -> str:
        return git_blob_sha1(self.blob_path(sha256).read_bytes())

    # ---------------------------------------------------------------- repos
    def _repo_dir(self, repo_type: str, namespace: str, name: str) -> Path:
        return self.root / "repos" / f"{repo_type}s" / namespace / name

    @contextlib.contextmanager
    def repo_lock(self, repo_type: str, repo_id: str) -> Iterator[None]:
        with self._locks_guard:
            lock = self._locks.setdefault((repo_type, repo_id), threading.Lock())
        with lock:
            yield

    def get_repo(self, repo_type: str, repo_id: str) -> RepoMeta | None:
        """The repo's metadata, or None when it does not exist."""
        if repo_type not in REPO_TYPES or repo_id.count("/") != 1:
            return None
        namespace, name = repo_id.split("/")
        path = self._repo_dir(repo_type, namespace, name) / "repo.json"
        if not _NAME_RE.match(namespace) or not _NAME_RE.match(name) or not path.is_file():
            return None
        d = _read_json(path)
        return RepoMeta(repo_type, namespace, name, bool(d["private"]), d["createdAt"])

    def create_repo(self, repo_type: str, namespace: str, name: str, private: bool, author: str) -> RepoMeta:
        """Create a repo with an empty initial commit on ``main``; StoreError("conflict") if it exists."""
        validate_repo_name(namespace, name)
        repo_id = f"{namespace}/{name}"
        with self.repo_lock(repo_type, repo_id):
            if self.get_repo(repo_type, repo_id) is not None:
                raise StoreError("conflict", f"You already created this {repo_type} repo: {repo_id}")
            final = self._repo_dir(repo_type, namespace, name)
            staging = self.root / "tmp" / f"repo-{secrets.token_hex(8)}"
            (staging / "commits").mkdir(parents=True)
            created = now_iso()
            commit = self._make_commit([], {}, "initial commit", "", author, created)
            self._write_commit(staging, commit)
            _write_json(staging / "refs.json", {"branches": {"main": commit.id}, "tags": {}})
            _write_json(staging / "repo.json", {"id": repo_id, "type": repo_type, "private": private,
                                                "createdAt": created})
            final.parent.mkdir(parents=True, exist_ok=True)
            os.rename(staging, final)
        return RepoMeta(repo_type, namespace, name, private, created)

    def delete_repo(self, repo_type: str, repo_id: str) -> None:
        with self.repo_lock(repo_type, repo_id):
            meta = self.get_repo(repo_type, repo_id)
            if meta is None:
                raise StoreError("repo_not_found", f"Repository {repo_id} not found")
            trash = self.root / "tmp" / f"deleted-{secrets.token_hex(8)}"
            os.rename(self._repo_dir(repo_type, meta.namespace, meta.name), trash)
        shutil.rmtree(trash, ignore_errors=True)

    def set_private(self, meta: RepoMeta, private: bool) -> None:
        with self.repo_lock(meta.repo_type, meta.repo_id):
            path = self._repo_dir(meta.repo_type, meta.namespace, meta.name) / "repo.json"
            d = _read_json(path)
            d["private"] = private
            _write_json(path, d)

    # ---------------------------------------------------------------- refs and commits
    def refs(self, meta: RepoMeta) -> dict[str, dict[str, str]]:
        return _read_json(self._repo_dir(meta.repo_type, meta.namespace, meta.name) / "refs.json")

    def _write_refs(self, meta: RepoMeta, refs: dict) -> None:
        _write_json(self._repo_dir(meta.repo_type, meta.namespace, meta.name) / "refs.json", refs)

    def _commit_dir(self, meta: RepoMeta) -> Path:
        return self._repo_dir(meta.repo_type, meta.namespace, meta.name) / "commits"

    def get_commit(self, meta: RepoMeta, sha: str) -> Commit:
        d = _read_json(self._commit_dir(meta) / f"{sha}.json")
        files = {p: FileEntry.from_json(e) for p, e in d["files"].items()}
        return Commit(d["id"], d["parents"], d["title"], d["message"], d["author"], d["date"], files)

    def resolve(self, meta: RepoMeta, revision: str) -> str:
        """Commit sha of a branch, tag, full sha or unique short sha; StoreError otherwise."""
        refs = self.refs(meta)
        rev = revision.removeprefix("refs/heads/") if revision.startswith("refs/heads/") else revision
        if rev in refs["branches"]:
            return refs["branches"][rev]
        rev = revision.removeprefix("refs/tags/")
        if rev in refs["tags"]:
            return refs["tags"][rev]
        commit_dir = self._commit_dir(meta)
        if SHA_RE.match(revision) and (commit_dir / f"{revision}.json").is_file():
            return revision
        if _SHORT_SHA_RE.match(revision):
            matches = [p.stem for p in commit_dir.glob(f"{revision}*.json")]
            if len(matches) == 1:
                return matches[0]
            if len(matches) > 1:
                raise StoreError("bad_request", f"short sha '{revision}' is ambiguous in {meta.repo_id}")
        raise StoreError("revision_not_found", f"Invalid rev id: {revision}")

    @staticmethod
    def _make_commit(parents: list[str], files: dict[str, FileEntry], title: str, message: str,
                     author: str, date: str) -> Commit:
        body = {"parents": parents, "title": title, "message": message, "author": author, "date": date,
                "files": {p: e.to_json() for p, e in sorted(files.items())}, "nonce": secrets.token_hex(8)}
        sha = hashlib.sha1(json.dumps(body, sort_keys=True).encode()).hexdigest()
        return Commit(sha, parents, title, message, author, date, files)

    @staticmethod
    def _write_commit(repo_dir: Path, commit: Commit) -> None:
        _write_json(repo_dir / "commits" / f"{commit.id}.json", {
            "id": commit.id, "parents": commit.parents, "title": commit.title, "message": commit.message,
            "author": commit.author, "date": commit.date,
            "files": {p: e.to_json() for p, e in sorted(commit.files.items())}})

    def commit(self, meta: RepoMeta, branch: str, files: dict[str, FileEntry], deleted: list[str],
               deleted_folders: list[str], title: str, message: str, author: str,
               parent_commit: str | None = None) -> Commit:
        """Apply additions and deletions to the head of ``branch`` and advance it atomically."""
        with self.repo_lock(meta.repo_type, meta.repo_id):
            refs = self.refs(meta)
            if branch not in refs["branches"]:
                raise StoreError("revision_not_found", f"Invalid rev id: {branch} (commits need a branch)")
            head = refs["branches"][branch]
            if parent_commit is not None and parent_commit != head:
                raise StoreError("precondition", f"parentCommit {parent_commit} is not the head of {branch}")
            tree = dict(self.get_commit(meta, head).files)
            for path in deleted:
                if tree.pop(path, None) is None:
                    raise StoreError("bad_request", f"cannot delete '{path}': no such file")
            for folder in deleted_folders:
                prefix = folder.rstrip("/") + "/"
                for path in [p for p in tree if p.startswith(prefix)]:
                    del tree[path]
            tree.update(files)
            commit = self._make_commit([head], tree, title, message, author, now_iso())
            self._write_commit(self._repo_dir(meta.repo_type, meta.namespace, meta.name), commit)
            refs["branches"][branch] = commit.id
            self._write_refs(meta, refs)
            return commit

    def empty_commit(self, meta: RepoMeta, author: str) -> str:
        """Write a parentless commit without files (for ``create_branch(emptyBranch=True)``)."""
        with self.repo_lock(meta.repo_type, meta.repo_id):
            commit = self._make_commit([], {}, "empty branch", "", author, now_iso())
            self._write_commit(self._repo_dir(meta.repo_type, meta.namespace, meta.name), commit)
        return commit.id

    def history(self, meta: RepoMeta, sha: str) -> list[Commit]:
        """Commits reachable from ``sha`` along first parents, newest first."""
        out = []
        while True:
            commit = self.get_commit(meta, sha)
            out.append(commit)
            if not commit.parents:
                return out
            sha = commit.parents[0]

    def create_ref(self, meta: RepoMeta, kind: str, name: str, sha: str) -> None:
        """Create a branch or tag (``kind``: branches|tags); StoreError("conflict") if it exists."""
        validate_ref_name(name)
        with self.repo_lock(meta.repo_type, meta.repo_id):
            refs = self.refs(meta)
            if name in refs[kind]:
                raise StoreError("conflict", f"{kind[:-1].capitalize()} '{name}' already exists")
            refs[kind][name] = sha
            self._write_refs(meta, refs)

    def delete_ref(self, meta: RepoMeta, kind: str, name: str) -> None:
        """Delete a branch or tag; StoreError("revision_not_found") if it does not exist."""
        with self.repo_lock(meta.repo_type, meta.repo_id):
            refs = self.refs(meta)
            if name not in refs[kind]:
                raise StoreError("revision_not_found", f"{kind[:-1]} '{name}' not found")
            del refs[kind][name]
            self._write_refs(meta, refs)
