"""On-disk store of the hub server: repos, their commits, refs and file contents.

Layout under ``root``::

    FORMAT                         storage format marker
    tmp/                           staging area (same filesystem, so renames are atomic)
    blobs/ab/abcdef...             contents written by formats 1 and 2 (read, never written)
    repos/<models|datasets>/<namespace>/<name>/
        repo.json                  id, type, private flag, creation date
        refs.json                  {"branches": {name: sha}, "tags": {name: sha}}
        commits/<sha>.json         one commit: parents, message, author, date, diff to its parent
        trees/<sha>.json           full file table of some commits (see commits.py)
        blobs/ab/abcdef...         this repo's file contents, named by their sha256
        blobs.txt                  sha256 of every blob this repo's commits and uploads brought in

Each repo keeps its own contents: bytes are stored once per repo, never looked up in another
repo, so a write costs the same whether or not some other repo (a private one, say) holds the
same bytes, and deleting a repo deletes its contents. A commit may reference an LFS object by
hash only if ``blobs.txt`` of its own repo lists it (an upload to this repo, or a file committed
to it), so knowing a hash never opens another repo's file. Every file is written to a
temporary name and renamed into place, so a crash never leaves a half-written blob, commit or
ref. Roots written by formats 1 and 2 (contents shared in ``blobs/``; format 1: a full file
table in every commit and no ``blobs.txt``) are read as they are: a repo's granted blob that
is not in its own store is read from ``blobs/``; ``blobs.txt`` is rebuilt from a repo's commits
the first time it is needed.

Repo ids are case-insensitive, as on the Hugging Face hub: ``alice/Pub`` and ``alice/pub`` name
one repo (stored under the case it was created with); a second repo differing only in case
cannot be created.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import os
import secrets
import shutil
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO

from msta.data.hub_server import boundary
from msta.data.hub_server.commits import Commit, CommitInfo, CommitStore, FileEntry, path_clash
from msta.data.hub_server.fsio import append_line, atomic_write, read_json, write_json

__all__ = ["Commit", "CommitInfo", "FileEntry", "RepoMeta", "Storage", "StoreError", "git_blob_sha1",
           "lfs_pointer"]

FORMAT = "msta-hub-storage 3"
_READABLE_FORMATS = ("msta-hub-storage 1", "msta-hub-storage 2", FORMAT)
REPO_TYPES = ("model", "dataset")


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
            if found not in _READABLE_FORMATS:
                raise ValueError(f"{self.root}: unknown storage format '{found}' (expected '{FORMAT}')")
        elif any(p.name not in {".lock"} for p in self.root.iterdir()):
            raise ValueError(f"{self.root} is not empty and is not a msta-hub root (no FORMAT file)")
        self._lock_file = open(self.root / ".lock", "a+")  # noqa: SIM115 (held for the lifetime)
        try:
            fcntl.flock(self._lock_file, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            self._lock_file.close()
            raise ValueError(f"{self.root} is in use by another msta-hub server") from None
        for sub in ("tmp", "repos"):
            (self.root / sub).mkdir(exist_ok=True)
        if not marker.exists() or marker.read_text().strip() != FORMAT:
            atomic_write(marker, (FORMAT + "\n").encode())  # older roots are read as they are
        self._locks: dict[tuple[str, str], threading.RLock] = {}
        self._locks_guard = threading.Lock()
        self.commits = CommitStore()
        self._ids: dict[tuple[str, str], set[str]] = {}  # (type, lower-case id) -> ids on disk
        for repo_type in REPO_TYPES:
            for path in (self.root / "repos" / f"{repo_type}s").glob("*/*/repo.json"):
                self._index(repo_type, f"{path.parent.parent.name}/{path.parent.name}", True)

    def close(self) -> None:
        """Release the root's file lock."""
        with contextlib.suppress(OSError, ValueError):
            fcntl.flock(self._lock_file, fcntl.LOCK_UN)
            self._lock_file.close()

    # ---------------------------------------------------------------- blobs
    def blob_path(self, meta: RepoMeta, sha256: str) -> Path:
        """Where the blob ``sha256`` of ``meta``'s repo lives: its own store, or for a blob an
        older root kept in the shared ``blobs/``, there. The id is checked, so the path stays
        under the root. Callers pass ids of the repo's own files or check ``repo_has_blob``."""
        sha256 = boundary.sha256_oid(sha256)
        own = self.repo_dir(meta) / "blobs" / sha256[:2] / sha256
        if own.is_file():
            return own
        shared = self.root / "blobs" / sha256[:2] / sha256
        return shared if shared.is_file() else own

    def put_blob_bytes(self, meta: RepoMeta, data: bytes) -> tuple[str, int]:
        """Store ``data`` in ``meta``'s repo; returns (sha256, size). Always written in full."""
        tmp = self.root / "tmp" / f"blob-{secrets.token_hex(8)}"
        try:
            atomic_write(tmp, data)
            sha = hashlib.sha256(data).hexdigest()
            self._place(meta, tmp, sha, grant=False)
        finally:
            tmp.unlink(missing_ok=True)
        return sha, len(data)

    def put_blob_stream(self, meta: RepoMeta, stream: IO[bytes], size: int, expected_sha256: str) -> None:
        """Copy exactly ``size`` bytes from ``stream`` (400 when it holds more or fewer) into
        ``meta``'s repo if their sha256 matches, and let the repo's commits reference them
        (``blobs.txt``). The bytes are always read, hashed and written in full."""
        expected_sha256 = boundary.sha256_oid(expected_sha256)
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
                if stream.read(1):
                    raise StoreError("bad_request", f"upload is longer than the announced {size} bytes")
                f.flush()
                os.fsync(f.fileno())
            if digest.hexdigest() != expected_sha256:
                raise StoreError("bad_request", f"uploaded content does not match sha256 {expected_sha256}")
            self._place(meta, tmp, expected_sha256, grant=True)
        finally:
            tmp.unlink(missing_ok=True)

    def _place(self, meta: RepoMeta, tmp: Path, sha256: str, grant: bool) -> None:
        """Rename the written file ``tmp`` into the repo's store, also over a copy already
        there (the same work either way); 404 when the repo was deleted meanwhile, 409 when it
        was also created anew."""
        with self.repo_lock(meta.repo_type, meta.repo_id):
            now = self.get_repo(meta.repo_type, meta.repo_id)
            if now is None or now.repo_id != meta.repo_id:
                raise StoreError("repo_not_found", f"Repository Not Found: {meta.repo_id} (deleted meanwhile)")
            if now.created_at != meta.created_at:
                raise StoreError("conflict", f"{meta.repo_id} was deleted and created again meanwhile")
            path = self.repo_dir(meta) / "blobs" / sha256[:2] / sha256
            path.parent.mkdir(parents=True, exist_ok=True)
            os.replace(tmp, path)
            if grant:
                self.grant_blob(meta, sha256)

    # ---------------------------------------------------------------- blobs of one repo
    def _grants_path(self, meta: RepoMeta) -> Path:
        return self._repo_dir(meta.repo_type, meta.namespace, meta.name) / "blobs.txt"

    def repo_blobs(self, meta: RepoMeta) -> set[str]:
        """sha256 of every blob this repo may reference (rebuilt from commits for old roots)."""
        path = self._grants_path(meta)
        if not path.is_file():
            with self.repo_lock(meta.repo_type, meta.repo_id):
                if not path.is_file():
                    atomic_write(path, "".join(f"{s}\n" for s in sorted(self._blobs_in_commits(meta))).encode())
        return {ln for ln in path.read_text().split() if boundary.SHA256_RE.match(ln)}

    def _blobs_in_commits(self, meta: RepoMeta) -> set[str]:
        repo_dir = self._repo_dir(meta.repo_type, meta.namespace, meta.name)
        found: set[str] = set()
        for p in (repo_dir / "commits").glob("*.json"):
            found.update(e.sha256 for e in self.commits.tree(repo_dir, p.stem).values())
        return {s for s in found if boundary.SHA256_RE.match(s)}

    def grant_blob(self, meta: RepoMeta, sha256: str) -> None:
        """Record that ``meta``'s repo may reference blob ``sha256`` (after an upload to it)."""
        sha256 = boundary.sha256_oid(sha256)
        if sha256 not in self.repo_blobs(meta):
            append_line(self._grants_path(meta), sha256)

    def repo_has_blob(self, meta: RepoMeta, sha256: str, size: int | None = None,
                      known: set[str] | None = None) -> bool:
        """Whether the blob is stored *and* reachable from this repo (never says more).

        Args:
            known: ``repo_blobs(meta)`` when the caller has it already.
        """
        if sha256 not in (self.repo_blobs(meta) if known is None else known):
            return False
        path = self.blob_path(meta, sha256)
        return path.is_file() and (size is None or path.stat().st_size == size)

    # ---------------------------------------------------------------- repos
    def _repo_dir(self, repo_type: str, namespace: str, name: str) -> Path:
        boundary.repo_name(namespace, name)
        if repo_type not in REPO_TYPES:
            raise StoreError("bad_request", f"unknown repo type '{repo_type}'")
        return self.root / "repos" / f"{repo_type}s" / namespace / name

    def repo_dir(self, meta: RepoMeta) -> Path:
        return self._repo_dir(meta.repo_type, meta.namespace, meta.name)

    @contextlib.contextmanager
    def repo_lock(self, repo_type: str, repo_id: str) -> Iterator[None]:
        """The lock of one repo id (case-insensitive: ``a/B`` and ``a/b`` share it)."""
        with self._locks_guard:
            lock = self._locks.setdefault((repo_type, repo_id.lower()), threading.RLock())
        with lock:
            yield

    def _index(self, repo_type: str, repo_id: str, present: bool) -> None:
        """Record that the repo ``repo_id`` (as spelled on disk) exists or no longer does."""
        with self._locks_guard:
            ids = self._ids.setdefault((repo_type, repo_id.lower()), set())
            (ids.add if present else ids.discard)(repo_id)

    def get_repo(self, repo_type: str, repo_id: str) -> RepoMeta | None:
        """The repo's metadata, or None when it does not exist (or cannot be named).

        ``repo_id`` is matched without regard to case: an id spelled as on disk first, else the
        one repo whose id differs only in case (None when an older root holds several)."""
        if repo_type not in REPO_TYPES or repo_id.count("/") != 1:
            return None
        namespace, name = repo_id.split("/")
        if not boundary.is_repo_name(namespace, name):
            return None
        path = self._repo_dir(repo_type, namespace, name) / "repo.json"
        if not path.is_file():
            with self._locks_guard:
                ids = sorted(self._ids.get((repo_type, repo_id.lower()), ()))
            if len(ids) != 1 or ids[0] == repo_id:
                return None
            namespace, name = ids[0].split("/")
            path = self._repo_dir(repo_type, namespace, name) / "repo.json"
            if not path.is_file():
                return None
        d = read_json(path)
        return RepoMeta(repo_type, namespace, name, bool(d["private"]), d["createdAt"])

    def create_repo(self, repo_type: str, namespace: str, name: str, private: bool, author: str) -> RepoMeta:
        """Create a repo with an empty initial commit on ``main``; StoreError("conflict") naming
        the existing repo if one has this id, in any case."""
        boundary.repo_name(namespace, name)
        repo_id = f"{namespace}/{name}"
        with self.repo_lock(repo_type, repo_id):
            existing = self.get_repo(repo_type, repo_id)
            if existing is not None:
                raise StoreError("conflict", f"You already created this {repo_type} repo: {existing.repo_id}")
            final = self._repo_dir(repo_type, namespace, name)
            staging = self.root / "tmp" / f"repo-{secrets.token_hex(8)}"
            created = now_iso()
            try:
                (staging / "commits").mkdir(parents=True)
                commit = self.commits.write(staging, [], {}, "initial commit", "", author, created)
                write_json(staging / "refs.json", {"branches": {"main": commit.id}, "tags": {}})
                write_json(staging / "repo.json", {"id": repo_id, "type": repo_type, "private": private,
                                                   "createdAt": created})
                atomic_write(staging / "blobs.txt", b"")
                final.parent.mkdir(parents=True, exist_ok=True)
                os.rename(staging, final)
            except BaseException:  # a full disk, say: leave no half-made repo in tmp/
                shutil.rmtree(staging, ignore_errors=True)
                raise
            self._index(repo_type, repo_id, True)
        return RepoMeta(repo_type, namespace, name, private, created)

    def delete_repo(self, repo_type: str, repo_id: str) -> None:
        """Delete the repo with its contents (its own blob store)."""
        with self.repo_lock(repo_type, repo_id):
            meta = self.get_repo(repo_type, repo_id)
            if meta is None:
                raise StoreError("repo_not_found", f"Repository {repo_id} not found")
            trash = self.root / "tmp" / f"deleted-{secrets.token_hex(8)}"
            os.rename(self.repo_dir(meta), trash)
            self._index(repo_type, meta.repo_id, False)
        shutil.rmtree(trash, ignore_errors=True)

    def set_private(self, meta: RepoMeta, private: bool) -> None:
        with self.repo_lock(meta.repo_type, meta.repo_id):
            path = self.repo_dir(meta) / "repo.json"
            d = read_json(path)
            d["private"] = private
            write_json(path, d)

    # ---------------------------------------------------------------- refs and commits
    def refs(self, meta: RepoMeta) -> dict[str, dict[str, str]]:
        return read_json(self.repo_dir(meta) / "refs.json")

    def _write_refs(self, meta: RepoMeta, refs: dict) -> None:
        write_json(self.repo_dir(meta) / "refs.json", refs)

    def get_commit(self, meta: RepoMeta, sha: str) -> Commit:
        """The commit with its complete file table."""
        return self.commits.commit(self.repo_dir(meta), boundary.commit_sha(sha))

    def resolve(self, meta: RepoMeta, revision: str) -> str:
        """Commit sha of a revision; StoreError("revision_not_found") when it names nothing.

        ``refs/heads/x`` and ``refs/tags/x`` name only that ref. A full sha names its commit
        before any ref. 7 to 39 hex characters name the one commit starting with them, and
        are refused (400) when a branch or tag has that name too: such refs cannot be created
        (boundary.ref_name) but may exist in older roots, and must never take over a pin.
        Any other name is a branch, then a tag.
        """
        revision = boundary.revision(revision)
        refs = self.refs(meta)
        for prefix, kind in (("refs/heads/", "branches"), ("refs/tags/", "tags")):
            if revision.startswith(prefix):
                if revision.removeprefix(prefix) in refs[kind]:
                    return refs[kind][revision.removeprefix(prefix)]
                raise StoreError("revision_not_found", f"Invalid rev id: {revision}")
        ref = refs["branches"].get(revision, refs["tags"].get(revision))
        repo_dir = self.repo_dir(meta)
        if boundary.SHA1_RE.match(revision) and self.commits.exists(repo_dir, revision):
            return revision
        if boundary.SHORT_SHA_RE.match(revision):
            matches = [p.stem for p in (repo_dir / "commits").glob(f"{revision}*.json")]
            if len(matches) > 1 or (matches and ref is not None):
                raise StoreError("bad_request", f"short sha '{revision}' is ambiguous in {meta.repo_id} "
                                 "(it starts several commits, or a commit and a branch or tag's name): "
                                 "pass the full sha, or refs/heads/NAME or refs/tags/NAME for a ref")
            if matches:
                return matches[0]
        if ref is not None:
            return ref
        raise StoreError("revision_not_found", f"Invalid rev id: {revision}")

    def commit(self, meta: RepoMeta, branch: str, files: dict[str, FileEntry], deleted: list[str],
               deleted_folders: list[str], title: str, message: str, author: str,
               parent_commit: str | None = None) -> Commit:
        """Apply additions and deletions to the head of ``branch`` and advance it atomically.

        Every blob of ``files`` is granted to the repo before the commit is written.
        """
        with self.repo_lock(meta.repo_type, meta.repo_id):
            refs = self.refs(meta)
            if branch not in refs["branches"]:
                raise StoreError("revision_not_found", f"Invalid rev id: {branch} (commits need a branch)")
            head = refs["branches"][branch]
            if parent_commit is not None and parent_commit != head:
                raise StoreError("precondition", f"parentCommit {parent_commit} is not the head of {branch}")
            repo_dir = self.repo_dir(meta)
            tree = self.commits.tree(repo_dir, head)
            for path in deleted:
                if tree.pop(path, None) is None:
                    raise StoreError("bad_request", f"cannot delete '{path}': no such file")
            for folder in deleted_folders:
                prefix = folder.rstrip("/") + "/"
                for path in [p for p in tree if p.startswith(prefix)]:
                    del tree[path]
            self._check_clash(tree, files, branch)
            tree.update(files)
            known = self.repo_blobs(meta)
            for sha in sorted({e.sha256 for e in files.values()} - known):
                append_line(self._grants_path(meta), sha)
            commit = self.commits.write(repo_dir, [head], tree, title, message, author, now_iso())
            refs["branches"][branch] = commit.id
            self._write_refs(meta, refs)
            return commit

    @staticmethod
    def _check_clash(tree: dict[str, FileEntry], files: dict[str, FileEntry], branch: str) -> None:
        """400 when two added paths are a file and a folder at one path (``a``, ``a/x``), 409
        when an added path is one with a file or folder already on the branch."""
        clash = path_clash([p for p in tree if p not in files], files)
        if clash is None:
            return
        path, other = (boundary._shown(p) for p in clash)
        if clash[1] in files:
            raise StoreError("bad_request", f"cannot commit both '{path}' and '{other}': "
                                            "a path cannot be a file and a folder")
        raise StoreError("conflict", f"cannot add '{path}': '{other}' is on branch {branch}, "
                                     "and a path cannot be a file and a folder")

    def empty_commit(self, meta: RepoMeta, author: str) -> str:
        """Write a parentless commit without files (for ``create_branch(emptyBranch=True)``)."""
        with self.repo_lock(meta.repo_type, meta.repo_id):
            commit = self.commits.write(self.repo_dir(meta), [], {}, "empty branch", "", author, now_iso())
        return commit.id

    def history(self, meta: RepoMeta, sha: str) -> list[CommitInfo]:
        """Commits reachable from ``sha`` along first parents, newest first (no file tables)."""
        repo_dir, out = self.repo_dir(meta), []
        while True:
            info = self.commits.info(repo_dir, sha)
            out.append(info)
            if not info.parents:
                return out
            sha = info.parents[0]

    def last_commits(self, meta: RepoMeta, sha: str, paths: list[str]) -> dict[str, CommitInfo]:
        """For each path, the newest commit (along first parents from ``sha``) that changed it."""
        repo_dir, out = self.repo_dir(meta), {}
        wanted = set(paths)
        for info in self.history(meta, sha):
            if not wanted:
                break
            hit = wanted & self.commits.changed_paths(repo_dir, info.id)
            out.update((p, info) for p in hit)
            wanted -= hit
        return out

    def create_ref(self, meta: RepoMeta, kind: str, name: str, sha: str) -> None:
        """Create a branch or tag (``kind``: branches|tags); StoreError("conflict") if it exists."""
        boundary.ref_name(name)
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
