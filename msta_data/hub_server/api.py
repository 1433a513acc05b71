"""JSON API endpoints of the hub server (``/api/...``): repos, refs, commits, trees, infos.

Each endpoint is a function ``(app, request) -> Response``; ``ROUTES`` maps method and path
pattern to it. Shapes of requests and answers follow what huggingface_hub's HfApi sends and
parses (see docs/hub.md for the list of covered calls).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from msta.data.hub_server import boundary, trees
from msta.data.hub_server.boundary import field
from msta.data.hub_server.cards import card_tags, front_matter
from msta.data.hub_server.commits import CommitInfo, FileEntry
from msta.data.hub_server.protocol import HttpError, Request, Response, Route, route
from msta.data.hub_server.storage import RepoMeta, lfs_pointer

if TYPE_CHECKING:
    from msta.data.hub_server.app import HubApp

REPO = r"/api/(?P<type>models|datasets)/(?P<ns>[^/]+)/(?P<name>[^/]+)"
REV = r"(?P<rev>[^/]+)"


# ------------------------------------------------------------------ access
def _not_found(req: Request, repo_id: str) -> HttpError:
    status = 401 if req.user is None else 404
    return HttpError(status, f"Repository Not Found: {repo_id}", "RepoNotFound")


def read_repo(app: HubApp, req: Request, repo_type: str | None = None) -> RepoMeta:
    """The repo named by the route if the caller may read it (else RepoNotFound, as the hub does)."""
    repo_type = repo_type or req.groups["type"].removesuffix("s")
    repo_id = f"{req.groups['ns']}/{req.groups['name']}"
    meta = app.storage.get_repo(repo_type, repo_id)
    if meta is None or not app.auth.can_read(req.user, meta.namespace, meta.private):
        raise _not_found(req, repo_id)
    return meta


def write_repo(app: HubApp, req: Request, repo_type: str | None = None) -> RepoMeta:
    """The repo named by the route if the caller may write it (401 anonymous, 403 no rights)."""
    meta = read_repo(app, req, repo_type)
    if req.user is None:
        raise HttpError(401, "Authentication required: pass a token (HF_TOKEN) to write")
    if not app.auth.can_write(req.user, meta.namespace):
        raise HttpError(403, f"You don't have write access to {meta.repo_id}")
    return meta


def repo_url(base: str, meta: RepoMeta) -> str:
    prefix = "datasets/" if meta.repo_type == "dataset" else ""
    return f"{base}/{prefix}{meta.repo_id}"


# ------------------------------------------------------------------ user and repos
def whoami(app: HubApp, req: Request) -> Response:
    if req.user is None:
        raise HttpError(401, "Authentication required: no token was sent")
    orgs = [{"type": "org", "name": o, "fullname": o} for o in app.auth.orgs_of(req.user)]
    return Response(body={"type": "user", "id": req.user, "name": req.user, "fullname": req.user,
                          "orgs": orgs, "auth": {"type": "access_token",
                                                 "accessToken": {"displayName": req.user, "role": "write"}}})


def _repo_type_of(data: dict) -> str:
    repo_type = field(data, "type", str, "model")
    if repo_type not in ("model", "dataset"):
        raise HttpError(400, f"repo type '{boundary._shown(repo_type)}' is not supported by this server "
                             "(model, dataset)")
    return repo_type


def _private_of(data: dict) -> bool | None:
    """The requested visibility (``visibility``: public|private, or ``private``: bool), or None."""
    visibility = field(data, "visibility", str, None)
    if visibility is not None:
        if visibility not in ("public", "private"):
            raise HttpError(400, "'visibility' must be 'public' or 'private'")
        return visibility == "private"
    return field(data, "private", bool, None)


def create_repo(app: HubApp, req: Request) -> Response:
    if req.user is None:
        raise HttpError(401, "Authentication required: pass a token (HF_TOKEN) to create a repo")
    data = req.json_object()
    repo_type = _repo_type_of(data)
    namespace = field(data, "organization", str, "") or req.user
    name = field(data, "name", str, "")
    private = bool(_private_of(data))
    boundary.repo_name(namespace, name)
    if not app.auth.can_write(req.user, namespace):
        raise HttpError(403, f"You don't have the rights to create a {repo_type} under the namespace '{namespace}'")
    existing = app.storage.get_repo(repo_type, f"{namespace}/{name}")
    base = req.base_url
    if existing is not None:
        raise HttpError(409, f"You already created this {repo_type} repo: {existing.repo_id}",
                        extra={"url": repo_url(base, existing)})
    meta = app.storage.create_repo(repo_type, namespace, name, private, author=req.user)
    return Response(body={"url": repo_url(base, meta), "name": meta.repo_id, "id": meta.repo_id})


def delete_repo(app: HubApp, req: Request) -> Response:
    if req.user is None:
        raise HttpError(401, "Authentication required: pass a token (HF_TOKEN) to delete a repo")
    data = req.json_object()
    repo_type = _repo_type_of(data)
    req.groups.update(ns=field(data, "organization", str, "") or req.user, name=field(data, "name", str, ""))
    meta = write_repo(app, req, repo_type)
    app.storage.delete_repo(meta.repo_type, meta.repo_id)
    return Response(body={})


def update_settings(app: HubApp, req: Request) -> Response:
    meta = write_repo(app, req)
    data = req.json_object()
    if data.get("gated") not in (None, False):
        raise HttpError(400, "gated repos are not supported by this server")
    private = _private_of(data)
    if private is not None:
        app.storage.set_private(meta, private)
    return Response(body={})


def repo_info(app: HubApp, req: Request) -> Response:
    meta = read_repo(app, req)
    sha = app.storage.resolve(meta, req.groups.get("rev", "main"))
    commit = app.storage.get_commit(meta, sha)
    siblings = []
    for path, entry in sorted(commit.files.items()):
        sib = {"rfilename": path, "size": entry.size, "blobId": entry.oid}
        if entry.lfs:
            sib["lfs"] = {"size": entry.size, "sha256": entry.sha256,
                          "pointerSize": len(lfs_pointer(entry.sha256, entry.size))}
        siblings.append(sib)
    card = _card(app, meta, commit.files.get("README.md"), anonymous=req.user is None)
    body = {"_id": meta.repo_id, "id": meta.repo_id, "author": meta.namespace, "sha": sha,
            "lastModified": commit.date, "createdAt": meta.created_at, "private": meta.private,
            "disabled": False, "gated": False, "downloads": 0, "likes": 0,
            "tags": card_tags(card), "siblings": siblings,
            "usedStorage": sum(e.size for e in commit.files.values())}
    if card is not None:
        body["cardData"] = card
    if meta.repo_type == "model":
        body["modelId"] = meta.repo_id
        if card and isinstance(card.get("library_name"), str):
            body["library_name"] = card["library_name"]
    return Response(body=body)


def _card(app: HubApp, meta: RepoMeta, entry: FileEntry | None, anonymous: bool) -> dict | None:
    """The README's front matter (read from its first bytes only), or None; ``anonymous``:
    read for a request without a token (cards.front_matter's parser slots)."""
    if entry is None:
        return None
    limit = app.limits.max_card_bytes
    with open(app.storage.blob_path(meta, entry.sha256), "rb") as f:
        head = f.read(limit + 64 * 1024)
    return front_matter(head.decode("utf-8", errors="replace"), max_bytes=limit, anonymous=anonymous)


# ------------------------------------------------------------------ refs
def list_refs(app: HubApp, req: Request) -> Response:
    meta = read_repo(app, req)
    refs = app.storage.refs(meta)

    def fmt(kind: str, prefix: str) -> list[dict]:
        return [{"name": n, "ref": f"refs/{prefix}/{n}", "targetCommit": s} for n, s in sorted(refs[kind].items())]

    return Response(body={"branches": fmt("branches", "heads"), "converts": [], "tags": fmt("tags", "tags"),
                          "pullRequests": []})


def create_tag(app: HubApp, req: Request) -> Response:
    meta = write_repo(app, req)
    data = req.json_object()
    tag = boundary.ref_name(field(data, "tag", str))
    sha = app.storage.resolve(meta, req.groups["rev"])
    app.storage.create_ref(meta, "tags", tag, sha)
    return Response(body={"name": tag, "ref": f"refs/tags/{tag}", "targetCommit": sha})


def delete_tag(app: HubApp, req: Request) -> Response:
    meta = write_repo(app, req)
    app.storage.delete_ref(meta, "tags", req.groups["rev"])
    return Response(body={})


def create_branch(app: HubApp, req: Request) -> Response:
    meta = write_repo(app, req)
    data = req.json_object()
    branch = boundary.ref_name(req.groups["rev"])
    if field(data, "emptyBranch", bool, False):
        sha = app.storage.empty_commit(meta, author=req.user or "")
    else:
        sha = app.storage.resolve(meta, field(data, "startingPoint", str, "") or "main")
    app.storage.create_ref(meta, "branches", branch, sha)
    return Response(body={})


def delete_branch(app: HubApp, req: Request) -> Response:
    meta = write_repo(app, req)
    if req.groups["rev"] == "main":
        raise HttpError(403, "Cannot delete the default branch 'main'")
    app.storage.delete_ref(meta, "branches", req.groups["rev"])
    return Response(body={})


# ------------------------------------------------------------------ trees
def _add_last_commits(app: HubApp, meta: RepoMeta, sha: str, entries: list[dict]) -> None:
    """Set ``lastCommit`` of each file entry: the newest commit that changed it."""
    last: dict[str, CommitInfo] = app.storage.last_commits(
        meta, sha, [e["path"] for e in entries if e["type"] == "file"])
    for e in entries:
        c = last.get(e["path"])
        if c is not None:
            e["lastCommit"] = {"id": c.id, "title": c.title, "date": c.date}


def list_tree(app: HubApp, req: Request) -> Response:
    meta = read_repo(app, req)
    sha = app.storage.resolve(meta, req.groups["rev"])
    path = req.groups.get("path", "").strip("/")
    if path:
        boundary.repo_path(path, missing_is_404=True)
    commit_ = app.storage.get_commit(meta, sha)
    entries = trees.tree_entries(commit_.files, path, req.flag("recursive"))
    if req.flag("expand"):
        _add_last_commits(app, meta, sha, entries)
    return Response(body=entries)


def paths_info(app: HubApp, req: Request) -> Response:
    meta = read_repo(app, req)
    sha = app.storage.resolve(meta, req.groups["rev"])
    commit_ = app.storage.get_commit(meta, sha)
    form = req.form()
    out = trees.paths_info(commit_.files, form.get("paths", []))
    if str((form.get("expand") or ["false"])[-1]).lower() == "true":
        _add_last_commits(app, meta, sha, out)
    return Response(body=out)


ROUTES: list[Route] = [
    route("GET", r"/api/whoami-v2", whoami),
    route("POST", r"/api/repos/create", create_repo),
    route("DELETE", r"/api/repos/delete", delete_repo),
    route("GET", REPO, repo_info),
    route("GET", REPO + r"/revision/" + REV, repo_info),
    route("PUT", REPO + r"/settings", update_settings),
    route("GET", REPO + r"/refs", list_refs),
    route("POST", REPO + r"/tag/" + REV, create_tag),
    route("DELETE", REPO + r"/tag/" + REV, delete_tag),
    route("POST", REPO + r"/branch/" + REV, create_branch),
    route("DELETE", REPO + r"/branch/" + REV, delete_branch),
    route("GET", REPO + r"/tree/" + REV + r"(?:/(?P<path>.*))?", list_tree),
    route("POST", REPO + r"/paths-info/" + REV, paths_info),
]
