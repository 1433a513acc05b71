"""File endpoints of the hub server: downloads (``/resolve/``), Git LFS uploads, validate-yaml.

LFS uploads follow the Git LFS batch API with the "basic" transfer: the batch answer carries an
upload URL holding a one-time ticket (the client sends no token with the PUT, as with a
presigned URL), and a verify URL the client calls with its token afterwards. A ticket is bound
to the repo it was issued for; the uploaded bytes are always hashed, and only then may that
repo's commits reference the object. The batch answer says "already stored" only for objects
of the same repo, so it reveals nothing about other repos. Tickets never reach a log (the
handler logs ``/lfs/upload/<ticket>``).
"""

from __future__ import annotations

import re
from typing import TYPE_CHECKING

from msta.data.hub_server import boundary
from msta.data.hub_server.api import read_repo, write_repo
from msta.data.hub_server.boundary import InputError, field
from msta.data.hub_server.cards import validate_card
from msta.data.hub_server.protocol import HttpError, Request, Response, Route, route
from msta.data.hub_server.storage import RepoMeta, StoreError
from msta.data.hub_server.tickets import TICKET_TTL_S, Ticket

if TYPE_CHECKING:
    from msta.data.hub_server.app import HubApp

_RANGE_RE = re.compile(r"^bytes=(\d{0,18})-(\d{0,18})$")
MAX_BATCH_OBJECTS = 1000  # huggingface_hub sends 256 a batch, git-lfs 100 (lfs.transfer.batchSize)
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
    path = boundary.repo_path(req.groups["path"], missing_is_404=True)
    entry = app.storage.get_commit(meta, sha).files.get(path)
    if entry is None:
        raise HttpError(404, f"Entry not found: {req.groups['path']}", "EntryNotFound",
                        headers={"X-Repo-Commit": sha})
    etag = f'"{entry.sha256}"' if entry.lfs else f'"{entry.oid}"'
    headers = {"X-Repo-Commit": sha, "ETag": etag, "Accept-Ranges": "bytes"}
    if entry.lfs:
        headers.update({"X-Linked-Etag": etag, "X-Linked-Size": str(entry.size)})
    path = str(app.storage.blob_path(meta, entry.sha256))
    byte_range = _byte_range(req.headers.get("Range"), entry.size) if entry.size else None
    if byte_range is None:
        return Response(200, headers=headers, stream=(path, 0, entry.size),
                        content_type="application/octet-stream")
    offset, length = byte_range
    headers["Content-Range"] = f"bytes {offset}-{offset + length - 1}/{entry.size}"
    return Response(206, headers=headers, stream=(path, offset, length), content_type="application/octet-stream")


def lfs_batch(app: HubApp, req: Request) -> Response:
    """POST /[datasets/]ns/name.git/info/lfs/objects/batch (upload operation, basic transfer)."""
    repo_type = "dataset" if req.groups.get("type") else "model"
    meta = write_repo(app, req, repo_type)
    data = req.json_object()
    if field(data, "operation", str, "") != "upload":
        raise HttpError(400, "only the LFS 'upload' operation is supported; download with /resolve/")
    if "basic" not in field(data, "transfers", list, ["basic"]):
        raise HttpError(400, "only the 'basic' LFS transfer is supported")
    requested = field(data, "objects", list, [])
    if len(requested) > MAX_BATCH_OBJECTS:
        raise HttpError(413, f"an LFS batch request may list at most {MAX_BATCH_OBJECTS} objects, "
                             f"got {len(requested)}; send several")
    known = app.storage.repo_blobs(meta)
    objects: list[dict] = []
    wanted: list[dict] = []  # the answer's objects that need an upload
    for obj in requested:
        try:
            obj = boundary.json_object(obj, "each LFS object")
            oid = boundary.sha256_oid(obj.get("oid"))
            size = boundary.byte_size(obj.get("size"))
        except InputError as err:
            objects.append({"oid": boundary._shown(obj.get("oid") if isinstance(obj, dict) else obj),
                            "size": 0, "error": {"code": 422, "message": err.message}})
            continue
        objects.append({"oid": oid, "size": size})  # already in this repo: no actions
        if not app.storage.repo_has_blob(meta, oid, size, known=known):
            wanted.append(objects[-1])
    keys = app.tickets.issue([(o["oid"], o["size"]) for o in wanted], meta.repo_type, meta.repo_id,
                             req.user or "")
    for obj, key in zip(wanted, keys, strict=True):
        obj.update(authenticated=True, actions={
            "upload": {"href": f"{req.base_url}/lfs/upload/{key}", "header": {}, "expires_in": int(TICKET_TTL_S)},
            "verify": {"href": f"{req.base_url}/lfs/verify/{key}", "header": {}}})
    return Response(body={"transfer": "basic", "objects": objects, "hash_algo": "sha256"},
                    content_type=LFS_CONTENT_TYPE)


def _ticket_repo(app: HubApp, ticket: Ticket) -> RepoMeta:
    meta = app.storage.get_repo(ticket.repo_type, ticket.repo_id)
    if meta is None:
        raise HttpError(404, "the repo of this upload ticket no longer exists")
    return meta


def lfs_upload(app: HubApp, req: Request) -> Response:
    """PUT /lfs/upload/<ticket>: the object's bytes; kept only if size and sha256 match.

    The ticket is used up by a successful upload; a second ``PUT`` with it is refused (403).
    """
    with app.tickets.claim(req.groups["ticket"]) as ticket:
        meta = _ticket_repo(app, ticket)
        declared = req.headers.get("Content-Length")
        if declared is not None and int(declared) != ticket.size:
            raise HttpError(400, f"upload is {declared} bytes but the batch request announced {ticket.size}")
        try:
            app.storage.put_blob_stream(meta, req.body, ticket.size, ticket.oid)
        except StoreError as err:  # the repo was deleted (and maybe created again) meanwhile
            if err.kind not in ("repo_not_found", "conflict"):
                raise
            raise HttpError(404, "the repo of this upload ticket no longer exists") from None
    return Response(body={})


def lfs_verify(app: HubApp, req: Request) -> Response:
    """POST /lfs/verify/<ticket>: confirms the object is stored for the ticket's repo."""
    key = req.groups["ticket"]
    ticket = app.tickets.get(key)
    meta = _ticket_repo(app, ticket)
    data = req.json_object()
    if data.get("oid") != ticket.oid or not app.storage.repo_has_blob(meta, ticket.oid, ticket.size):
        raise HttpError(404, f"LFS object {ticket.oid} is not stored")
    app.tickets.close(key)
    return Response(body={"message": "ok"})


# ------------------------------------------------------------------ validate-yaml
def validate_yaml(app: HubApp, req: Request) -> Response:
    """POST /api/validate-yaml {content, repoType}: 400 with ``errors`` when the metadata is bad."""
    data = req.json_object()
    errors = validate_card(field(data, "content", str, ""), field(data, "repoType", str, "model"),
                           app.limits.max_card_bytes, anonymous=req.user is None)
    if errors:
        raise HttpError(400, "Invalid metadata in README.md", extra={"errors": [{"message": e} for e in errors]})
    return Response(body={"warnings": []})


_NS = r"(?P<ns>[^/]+)/(?P<name>[^/]+?)"
ROUTES: list[Route] = [
    route("POST", r"/api/validate-yaml", validate_yaml),
    route("PUT", r"/lfs/upload/(?P<ticket>[A-Za-z0-9_-]+)", lfs_upload, body="upload"),
    route("POST", r"/lfs/verify/(?P<ticket>[A-Za-z0-9_-]+)", lfs_verify),
    route("POST", r"(?:/(?P<type>datasets))?/" + _NS + r"\.git/info/lfs/objects/batch", lfs_batch),
    route("GET", r"(?:/(?P<type>datasets))?/" + _NS + r"/resolve/(?P<rev>[^/]+)/(?P<path>.+)", resolve_file),
]


