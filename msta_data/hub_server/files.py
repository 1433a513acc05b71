"""File endpoints of the hub server: downloads (``/resolve/``), Git LFS uploads, validate-yaml.

LFS uploads follow the Git LFS batch API with the "basic" transfer: the batch answer carries an
upload URL holding a one-time ticket (the client sends no token with the PUT, as with a
presigned URL), and a verify URL the client calls with its token afterwards.
"""

from __future__ import annotations

import re
import secrets
import threading
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

from msta_data.hub_server.api import read_repo, write_repo
from msta_data.hub_server.cards import validate_card
from msta_data.hub_server.protocol import HttpError, Request, Response, Route, route

if TYPE_CHECKING:
    from msta_data.hub_server.server import HubApp

_SHA256_RE = re.compile(r"^[0-9a-f]{64}$")
_RANGE_RE = re.compile(r"^bytes=(\d*)-(\d*)$")
TICKET_TTL_S = 3600.0
LFS_CONTENT_TYPE = "application/vnd.git-lfs+json"


# ------------------------------------------------------------------ downloads
def _byte_range(header: str | None, size: int) -> tuple[int, int] | None:
    """(offset, length) of a single ``Range: bytes=a-b`` request; None for the whole file."""
    if not header:
        return None
    m = _RANGE_RE.match(header.strip())
    if m is None or (not m.group(1) and not m.group(2)):
        return None  # unsupported forms (multiple ranges): answer with the whole file
    if m.group(1):
        start = int(m.group(1))
        end = min(int(m.group(2)), size - 1) if m.group(2) else size - 1
    else:
        start, end = max(size - int(m.group(2)), 0), size - 1
    if start >= size or end < start:
        raise HttpError(416, f"range {header} not satisfiable for {size} bytes",
                        headers={"Content-Range": f"bytes */{size}"})
    return start, end - start + 1


def resolve_file(app: HubApp, req: Request) -> Response:
    """GET/HEAD /[datasets/]ns/name/resolve/rev/path: the file with the hub's metadata headers."""
    meta = read_repo(app, req, "dataset" if req.groups.get("type") else "model")
    sha = app.storage.resolve(meta, req.groups["rev"])
    entry = app.storage.get_commit(meta, sha).files.get(req.groups["path"])
    if entry is None:
        raise HttpError(404, f"Entry not found: {req.groups['path']}", "EntryNotFound",
                        headers={"X-Repo-Commit": sha})
    etag = f'"{entry.sha256}"' if entry.lfs else f'"{entry.oid}"'
    headers = {"X-Repo-Commit": sha, "ETag": etag, "Accept-Ranges": "bytes"}
    if entry.lfs:
        headers.update({"X-Linked-Etag": etag, "X-Linked-Size": str(entry.size)})
    path = str(app.storage.blob_path(entry.sha256))
    byte_range = _byte_range(req.headers.get("Range"), entry.size) if entry.size else None
    if byte_range is None:
        return Response(200, headers=headers, stream=(path, 0, entry.size),
                        content_type="application/octet-stream")
    offset, length = byte_range
    headers["Content-Range"] = f"bytes {offset}-{offset + length - 1}/{entry.size}"
    return Response(206, headers=headers, stream=(path, offset, length), content_type="application/octet-stream")


# ------------------------------------------------------------------ LFS
@dataclass(frozen=True)
class Ticket:
    oid: str
    size: int
    expires: float


class TicketBook:
    """One-time upload tickets handed out by the LFS batch endpoint (kept in memory)."""

    def __init__(self) -> None:
        self._tickets: dict[str, Ticket] = {}
        self._lock = threading.Lock()

    def issue(self, oid: str, size: int) -> str:
        key = secrets.token_urlsafe(32)
        with self._lock:
            now = time.monotonic()
            self._tickets = {k: t for k, t in self._tickets.items() if t.expires > now}
            self._tickets[key] = Ticket(oid, size, now + TICKET_TTL_S)
        return key

    def get(self, key: str) -> Ticket:
        with self._lock:
            ticket = self._tickets.get(key)
        if ticket is None or ticket.expires < time.monotonic():
            raise HttpError(403, "upload ticket is unknown or expired; ask the batch endpoint again")
        return ticket

    def close(self, key: str) -> None:
        with self._lock:
            self._tickets.pop(key, None)


def lfs_batch(app: HubApp, req: Request) -> Response:
    """POST /[datasets/]ns/name.git/info/lfs/objects/batch (upload operation, basic transfer)."""
    repo_type = "dataset" if req.groups.get("type") else "model"
    data = req.json()
    if data.get("operation") != "upload":
        read_repo(app, req, repo_type)
        raise HttpError(400, "only the LFS 'upload' operation is supported; download with /resolve/")
    write_repo(app, req, repo_type)
    if "basic" not in (data.get("transfers") or ["basic"]):
        raise HttpError(400, "only the 'basic' LFS transfer is supported")
    objects = []
    for obj in data.get("objects") or []:
        oid, size = obj.get("oid"), obj.get("size")
        if not isinstance(oid, str) or not _SHA256_RE.match(oid) or not isinstance(size, int) or size < 0:
            objects.append({"oid": str(oid), "size": size if isinstance(size, int) else 0,
                            "error": {"code": 422, "message": "oid must be a sha256 and size an integer"}})
            continue
        if app.storage.has_blob(oid, size):
            objects.append({"oid": oid, "size": size})  # already here: no actions
            continue
        key = app.tickets.issue(oid, size)
        objects.append({"oid": oid, "size": size, "authenticated": True, "actions": {
            "upload": {"href": f"{req.base_url}/lfs/upload/{key}", "header": {}, "expires_in": int(TICKET_TTL_S)},
            "verify": {"href": f"{req.base_url}/lfs/verify/{key}", "header": {}}}})
    return Response(body={"transfer": "basic", "objects": objects, "hash_algo": "sha256"},
                    content_type=LFS_CONTENT_TYPE)


def lfs_upload(app: HubApp, req: Request) -> Response:
    """PUT /lfs/upload/<ticket>: the object's bytes; stored only if size and sha256 match."""
    key = req.groups["ticket"]
    ticket = app.tickets.get(key)
    declared = req.headers.get("Content-Length")
    if declared is not None and int(declared) != ticket.size:
        raise HttpError(400, f"upload is {declared} bytes but the batch request announced {ticket.size}")
    if not app.storage.has_blob(ticket.oid, ticket.size):
        app.storage.put_blob_stream(req.body, ticket.size, ticket.oid)
    if req.body.read(1):
        raise HttpError(400, f"upload is longer than the announced {ticket.size} bytes")
    return Response(body={})


def lfs_verify(app: HubApp, req: Request) -> Response:
    """POST /lfs/verify/<ticket>: confirms the object is stored."""
    key = req.groups["ticket"]
    ticket = app.tickets.get(key)
    data = req.json()
    if data.get("oid") != ticket.oid or not app.storage.has_blob(ticket.oid, ticket.size):
        raise HttpError(404, f"LFS object {ticket.oid} is not stored")
    app.tickets.close(key)
    return Response(body={"message": "ok"})


# ------------------------------------------------------------------ validate-yaml
def validate_yaml(app: HubApp, req: Request) -> Response:
    """POST /api/validate-yaml {content, repoType}: 400 with ``errors`` when the metadata is bad."""
    data = req.json()
    errors = validate_card(str(data.get("content") or ""), str(data.get("repoType") or "model"))
    if errors:
        raise HttpError(400, "Invalid metadata in README.md", extra={"errors": [{"message": e} for e in errors]})
    return Response(body={"warnings": []})


_NS = r"(?P<ns>[^/]+)/(?P<name>[^/]+?)"
ROUTES: list[Route] = [
    route("POST", r"/api/validate-yaml", validate_yaml),
    route("PUT", r"/lfs/upload/(?P<ticket>[A-Za-z0-9_-]+)", lfs_upload),
    route("POST", r"/lfs/verify/(?P<ticket>[A-Za-z0-9_-]+)", lfs_verify),
    route("POST", r"(?:/(?P<type>datasets))?/" + _NS + r"\.git/info/lfs/objects/batch", lfs_batch),
    route("GET", r"(?:/(?P<type>datasets))?/" + _NS + r"/resolve/(?P<rev>[^/]+)/(?P<path>.+)", resolve_file),
]


