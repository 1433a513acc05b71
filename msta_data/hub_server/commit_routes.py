"""Commit endpoints of the hub server: preupload, commit (NDJSON) and the commit list.

A commit's ``lfsFile`` operation names its content by sha256. It is accepted only when that
object was uploaded to, or committed in, the same repo (``Storage.repo_blobs``): a hash never
gives access to another repo's file, and a bad oid never names a path (boundary.sha256_oid).
"""

from __future__ import annotations

import base64
import binascii
from typing import TYPE_CHECKING, Any

from msta.data.hub_server import boundary
from msta.data.hub_server.api import REPO, REV, read_repo, repo_url, write_repo
from msta.data.hub_server.boundary import InputError, field
from msta.data.hub_server.commits import FileEntry
from msta.data.hub_server.protocol import HttpError, Request, Response, Route, route
from msta.data.hub_server.storage import RepoMeta, git_blob_sha1, lfs_pointer

if TYPE_CHECKING:
    from msta.data.hub_server.app import HubApp


def preupload(app: HubApp, req: Request) -> Response:
    """POST .../preupload/{rev}: upload mode (regular or lfs) and known oid of each file."""
    meta = write_repo(app, req)
    if req.flag("create_pr"):
        raise HttpError(400, "pull requests are not supported by this server")
    data = req.json_object()
    head = app.storage.resolve(meta, req.groups["rev"])
    tree = app.storage.get_commit(meta, head).files
    out = []
    for f in field(data, "files", list, []):
        f = boundary.json_object(f, "each entry of 'files'")
        path = boundary.repo_path(field(f, "path", str))
        size = boundary.byte_size(field(f, "size", int), "'size'")
        lfs = app.lfs_threshold is not None and size >= app.lfs_threshold and size > 0
        item = {"path": path, "uploadMode": "lfs" if lfs else "regular", "shouldIgnore": False}
        entry = tree.get(path)
        if entry is not None and entry.lfs == lfs:
            item["oid"] = entry.sha256 if lfs else entry.oid
        out.append(item)
    return Response(body={"files": out, "commitOid": head})


class _Ops:
    """The operations of one commit as its NDJSON lines are read."""

    def __init__(self, app: HubApp, meta: RepoMeta):
        self.app, self.meta = app, meta
        self.header: dict[str, Any] | None = None
        self.files: dict[str, FileEntry] = {}
        self.deleted: list[str] = []
        self.deleted_folders: list[str] = []
        self._repo_blobs: set[str] | None = None

    def add(self, item: Any) -> None:
        item = boundary.json_object(item, "each commit line")
        key = field(item, "key", str)
        value = boundary.json_object(item.get("value") or {}, f"the value of a '{key}' line")
        if key == "header":
            self.header = value
        elif key == "file":
            self._file(boundary.repo_path(field(value, "path", str)), value)
        elif key == "lfsFile":
            self._lfs_file(boundary.repo_path(field(value, "path", str)), value)
        elif key == "deletedFile":
            self.deleted.append(boundary.repo_path(field(value, "path", str)))
        elif key == "deletedFolder":
            self.deleted_folders.append(boundary.repo_path(field(value, "path", str).rstrip("/")))
        else:
            raise HttpError(400, f"unknown commit operation '{boundary._shown(key)}'")

    def _file(self, path: str, value: dict) -> None:
        content = field(value, "content", str, "")
        encoding = field(value, "encoding", str, "base64")
        try:
            data = base64.b64decode(content, validate=True) if encoding == "base64" else content.encode()
        except (binascii.Error, ValueError):
            raise HttpError(400, f"content of '{path}' is not valid base64") from None
        sha, size = self.app.storage.put_blob_bytes(self.meta, data)
        self.files[path] = FileEntry(sha, size, git_blob_sha1(data), False)

    def _lfs_file(self, path: str, value: dict) -> None:
        if field(value, "algo", str, "sha256") != "sha256":
            raise HttpError(400, f"LFS object for '{path}': only sha256 is supported")
        oid = boundary.sha256_oid(field(value, "oid", str))
        size = field(value, "size", int, None)
        if size is not None:
            boundary.byte_size(size, "'size'")
        if self._repo_blobs is None:
            self._repo_blobs = self.app.storage.repo_blobs(self.meta)
        if not self.app.storage.repo_has_blob(self.meta, oid, size, known=self._repo_blobs):
            raise HttpError(400, f"LFS object {oid} for '{path}' was not uploaded to this repo")
        size = self.app.storage.blob_path(self.meta, oid).stat().st_size
        self.files[path] = FileEntry(oid, size, git_blob_sha1(lfs_pointer(oid, size)), True)


def _still_there(app: HubApp, meta: RepoMeta) -> None:
    """404 when the repo was deleted while the commit body arrived, 409 when it was also
    created anew under the same name (the commit was meant for the old one)."""
    now = app.storage.get_repo(meta.repo_type, meta.repo_id)
    if now is None:
        raise HttpError(404, f"Repository Not Found: {meta.repo_id} (deleted during the commit)", "RepoNotFound")
    if now.created_at != meta.created_at:
        raise HttpError(409, f"{meta.repo_id} was deleted and created again during the commit")


def commit(app: HubApp, req: Request) -> Response:
    """POST .../commit/{branch}: NDJSON header + operations; advances the branch atomically."""
    meta = write_repo(app, req)
    if req.flag("create_pr"):
        raise HttpError(400, "pull requests are not supported by this server")
    ops = _Ops(app, meta)
    for line in req.body:
        if line.strip():
            try:
                ops.add(boundary.parse_json(line))
            except InputError as err:
                raise HttpError(400, f"commit body: {err.message}") from None
    header = ops.header
    if header is None or not field(header, "summary", str, ""):
        raise HttpError(400, "commit needs a header line with a non-empty 'summary'")
    parent = field(header, "parentCommit", str, None)
    if parent is not None:
        boundary.commit_sha(parent, "parentCommit")
    branch = req.groups["rev"].removeprefix("refs/heads/")
    with app.storage.repo_lock(meta.repo_type, meta.repo_id):  # no delete between check and write
        _still_there(app, meta)
        if branch not in app.storage.refs(meta)["branches"]:
            app.storage.resolve(meta, branch)  # RevisionNotFound for unknown names
            raise HttpError(400, f"Invalid rev id: {branch} is not a branch; commits go to branches")
        new = app.storage.commit(meta, branch, ops.files, ops.deleted, ops.deleted_folders, header["summary"],
                                 field(header, "description", str, ""), req.user or "", parent)
    return Response(body={"commitUrl": f"{repo_url(req.base_url, meta)}/commit/{new.id}",
                          "commitOid": new.id, "success": True, "pullRequestUrl": None})


def list_commits(app: HubApp, req: Request) -> Response:
    """GET .../commits/{rev}: first-parent history, newest first."""
    meta = read_repo(app, req)
    sha = app.storage.resolve(meta, req.groups["rev"])
    return Response(body=[{"id": c.id, "title": c.title, "message": c.message, "date": c.date,
                           "authors": [{"user": c.author, "avatar": None}]}
                          for c in app.storage.history(meta, sha)])


ROUTES: list[Route] = [
    route("POST", REPO + r"/preupload/" + REV, preupload),
    route("POST", REPO + r"/commit/" + REV, commit, body="commit"),
    route("GET", REPO + r"/commits/" + REV, list_commits),
]
