"""JSON API endpoints of the hub server (``/api/...``): repos, refs, commits, trees, infos.

Each endpoint is a function ``(app, request) -> Response``; ``ROUTES`` maps method and path
pattern to it. Shapes of requests and answers follow what huggingface_hub's HfApi sends and
parses (see docs/hub.md for the list of covered calls).
"""

from __future__ import annotations

import base64
import binascii
import hashlib
import json
from typing import TYPE_CHECKING

from msta_data.hub_server.cards import front_matter
from msta_data.hub_server.protocol import HttpError, Request, Response, Route, route
from msta_data.hub_server.storage import (
    Commit,
    FileEntry,
    RepoMeta,
    StoreError,
    git_blob_sha1,
    lfs_pointer,
)

if TYPE_CHECKING:
    from msta_data.hub_server.server import HubApp

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


def validate_path(path: str) -> str:
    """A repo-relative file path without empty, '.' or '..' segments."""
    parts = path.split("/")
    if not path or any(p in ("", ".", "..") for p in parts) or parts[0] == ".git":
        raise HttpError(400, f"invalid path in repo: '{path}'")
    return path


# ------------------------------------------------------------------ user and repos
def whoami(app: HubApp, req: Request) -> Response:
    if req.user is None:
        raise HttpError(401, "Authentication required: no token was sent")
    orgs = [{"type": "org", "name": o, "fullname": o} for o in app.auth.orgs_of(req.user)]
    return Response(body={"type": "user", "id": req.user, "name": req.user, "fullname": req.user,
                          "orgs": orgs, "auth": {"type": "access_token",
                                                 "accessToken": {"displayName": req.user, "role": "write"}}})


def _repo_type_of(value: str | None) -> str:
    repo_type = value or "model"
    if repo_type not in ("model", "dataset"):
        raise HttpError(400, f"repo type '{repo_type}' is not supported by this server (model, dataset)")
    return repo_type


def create_repo(app: HubApp, req: Request) -> Response:
    data = req.json()
    if req.user is None:
        raise HttpError(401, "Authentication required: pass a token (HF_TOKEN) to create a repo")
    repo_type = _repo_type_of(data.get("type"))
    namespace = data.get("organization") or req.user
    name = data.get("name") or ""
    private = data.get("visibility") == "private" if "visibility" in data else bool(data.get("private"))
    if not app.auth.can_write(req.user, namespace):
        raise HttpError(403, f"You don't have the rights to create a {repo_type} under the namespace '{namespace}'")
    existing = app.storage.get_repo(repo_type, f"{namespace}/{name}")
    base = req.base_url
    if existing is not None:
        raise HttpError(409, f"You already created this {repo_type} repo", extra={"url": repo_url(base, existing)})
    meta = app.storage.create_repo(repo_type, namespace, name, private, author=req.user)
    return Response(body={"url": repo_url(base, meta), "name": meta.repo_id, "id": meta.repo_id})


def delete_repo(app: HubApp, req: Request) -> Response:
    data = req.json()
    repo_type = _repo_type_of(data.get("type"))
    req.groups.update(ns=data.get("organization") or req.user or "", name=data.get("name") or "")
    meta = write_repo(app, req, repo_type)
    app.storage.delete_repo(meta.repo_type, meta.repo_id)
    return Response(body={})


def update_settings(app: HubApp, req: Request) -> Response:
    meta = write_repo(app, req)
    data = req.json()
    if data.get("gated") not in (None, False):
        raise HttpError(400, "gated repos are not supported by this server")
    if "visibility" in data:
        app.storage.set_private(meta, data["visibility"] == "private")
    elif "private" in data:
        app.storage.set_private(meta, bool(data["private"]))
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
    card = None
    if "README.md" in commit.files:
        card = front_matter(app.storage.blob_path(commit.files["README.md"].sha256).read_text(errors="replace"))
    body = {"_id": meta.repo_id, "id": meta.repo_id, "author": meta.namespace, "sha": sha,
            "lastModified": commit.date, "createdAt": meta.created_at, "private": meta.private,
            "disabled": False, "gated": False, "downloads": 0, "likes": 0,
            "tags": list((card or {}).get("tags") or []), "siblings": siblings,
            "usedStorage": sum(e.size for e in commit.files.values())}
    if card is not None:
        body["cardData"] = card
    if meta.repo_type == "model":
        body["modelId"] = meta.repo_id
        if card and isinstance(card.get("library_name"), str):
            body["library_name"] = card["library_name"]
    return Response(body=body)


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
    data = req.json()
    tag = data.get("tag")
    if not isinstance(tag, str) or not tag:
        raise HttpError(400, "missing 'tag' in request body")
    sha = app.storage.resolve(meta, req.groups["rev"])
    app.storage.create_ref(meta, "tags", tag, sha)
    return Response(body={"name": tag, "ref": f"refs/tags/{tag}", "targetCommit": sha})


def delete_tag(app: HubApp, req: Request) -> Response:
    meta = write_repo(app, req)
    app.storage.delete_ref(meta, "tags", req.groups["rev"])
    return Response(body={})


def create_branch(app: HubApp, req: Request) -> Response:
    meta = write_repo(app, req)
    data = req.json()
    branch = req.groups["rev"]
    if data.get("emptyBranch"):
        sha = app.storage.empty_commit(meta, author=req.user or "")
    else:
        sha = app.storage.resolve(meta, data.get("startingPoint") or "main")
    app.storage.create_ref(meta, "branches", branch, sha)
    return Response(body={})


def delete_branch(app: HubApp, req: Request) -> Response:
    meta = write_repo(app, req)
    if req.groups["rev"] == "main":
        raise HttpError(403, "Cannot delete the default branch 'main'")
    app.storage.delete_ref(meta, "branches", req.groups["rev"])
    return Response(body={})


# ------------------------------------------------------------------ commits
def preupload(app: HubApp, req: Request) -> Response:
    meta = write_repo(app, req)
    if req.flag("create_pr"):
        raise HttpError(400, "pull requests are not supported by this server")
    data = req.json()
    head = app.storage.resolve(meta, req.groups["rev"])
    tree = app.storage.get_commit(meta, head).files
    out = []
    for f in data.get("files") or []:
        path, size = f.get("path"), f.get("size")
        if not isinstance(path, str) or not isinstance(size, int):
            raise HttpError(400, "each file needs 'path' and 'size'")
        lfs = app.lfs_threshold is not None and size >= app.lfs_threshold and size > 0
        item = {"path": path, "uploadMode": "lfs" if lfs else "regular", "shouldIgnore": False}
        entry = tree.get(path)
        if entry is not None and entry.lfs == lfs:
            item["oid"] = entry.sha256 if lfs else entry.oid
        out.append(item)
    return Response(body={"files": out, "commitOid": head})


def _parse_commit_line(app: HubApp, item: dict, ops: dict) -> None:
    key, value = item.get("key"), item.get("value") or {}
    if key == "header":
        ops["header"] = value
        return
    path = validate_path(str(value.get("path", "")).lstrip("/"))
    if key == "file":
        try:
            content = (base64.b64decode(value.get("content", ""), validate=True)
                       if value.get("encoding", "base64") == "base64" else str(value["content"]).encode())
        except (binascii.Error, ValueError):
            raise HttpError(400, f"content of '{path}' is not valid base64") from None
        sha, size = app.storage.put_blob_bytes(content)
        ops["files"][path] = FileEntry(sha, size, git_blob_sha1(content), False)
    elif key == "lfsFile":
        oid, size = value.get("oid"), value.get("size")
        if value.get("algo", "sha256") != "sha256" or not app.storage.has_blob(str(oid), size):
            raise HttpError(400, f"LFS object {oid} for '{path}' was not uploaded to this server")
        size = app.storage.blob_path(oid).stat().st_size
        ops["files"][path] = FileEntry(oid, size, git_blob_sha1(lfs_pointer(oid, size)), True)
    elif key == "deletedFile":
        ops["deleted"].append(path)
    elif key == "deletedFolder":
        ops["deleted_folders"].append(path)
    else:
        raise HttpError(400, f"unknown commit operation '{key}'")


def commit(app: HubApp, req: Request) -> Response:
    meta = write_repo(app, req)
    if req.flag("create_pr"):
        raise HttpError(400, "pull requests are not supported by this server")
    ops: dict = {"header": None, "files": {}, "deleted": [], "deleted_folders": []}
    for line in req.body:
        if line.strip():
            try:
                item = json.loads(line)
            except ValueError:
                raise HttpError(400, "commit body is not valid NDJSON") from None
            _parse_commit_line(app, item, ops)
    header = ops["header"]
    if not isinstance(header, dict) or not header.get("summary"):
        raise HttpError(400, "commit needs a header line with a non-empty 'summary'")
    branch = req.groups["rev"].removeprefix("refs/heads/")
    if branch not in app.storage.refs(meta)["branches"]:
        app.storage.resolve(meta, branch)  # RevisionNotFound for unknown names
        raise HttpError(400, f"Invalid rev id: {branch} is not a branch; commits go to branches")
    new = app.storage.commit(meta, branch, ops["files"], ops["deleted"], ops["deleted_folders"],
                             header["summary"], header.get("description") or "", req.user or "",
                             header.get("parentCommit"))
    return Response(body={"commitUrl": f"{repo_url(req.base_url, meta)}/commit/{new.id}",
                          "commitOid": new.id, "success": True, "pullRequestUrl": None})


def list_commits(app: HubApp, req: Request) -> Response:
    meta = read_repo(app, req)
    sha = app.storage.resolve(meta, req.groups["rev"])
    return Response(body=[{"id": c.id, "title": c.title, "message": c.message, "date": c.date,
                           "authors": [{"user": c.author, "avatar": None}]}
                          for c in app.storage.history(meta, sha)])


# ------------------------------------------------------------------ trees
def _file_json(path: str, entry: FileEntry) -> dict:
    out = {"type": "file", "oid": entry.oid, "size": entry.size, "path": path}
    if entry.lfs:
        out["lfs"] = {"oid": entry.sha256, "size": entry.size,
                      "pointerSize": len(lfs_pointer(entry.sha256, entry.size))}
    return out


def _dir_json(path: str, files: dict[str, FileEntry]) -> dict:
    prefix = path + "/"
    listing = "".join(f"{p} {e.oid}\n" for p, e in sorted(files.items()) if p.startswith(prefix))
    return {"type": "directory", "oid": hashlib.sha1(listing.encode()).hexdigest(), "size": 0, "path": path}


def _last_commits(history: list[Commit], paths: list[str]) -> dict[str, dict]:
    """For each path, the commit that last changed it (walking first parents)."""
    out = {}
    for path in paths:
        entry, i = history[0].files.get(path), 0
        while i + 1 < len(history) and history[i + 1].files.get(path) == entry:
            i += 1
        c = history[i]
        out[path] = {"id": c.id, "title": c.title, "date": c.date}
    return out


def tree_entries(files: dict[str, FileEntry], path: str, recursive: bool) -> list[dict]:
    """Tree listing of ``path`` ('' = root) in the hub's JSON shape; StoreError when missing."""
    path = path.strip("/")
    prefix = path + "/" if path else ""
    dirs: set[str] = set()
    out = []
    for p, entry in sorted(files.items()):
        if not p.startswith(prefix):
            continue
        parts = p[len(prefix):].split("/")
        if len(parts) == 1 or recursive:
            out.append(_file_json(p, entry))
        if recursive:
            dirs.update(prefix + "/".join(parts[:k]) for k in range(1, len(parts)))
        elif len(parts) > 1:
            dirs.add(prefix + parts[0])
    if path and not out and not dirs:
        raise StoreError("entry_not_found", f"path '{path}' not found in this revision")
    return sorted(out + [_dir_json(d, files) for d in dirs], key=lambda e: e["path"])


def list_tree(app: HubApp, req: Request) -> Response:
    meta = read_repo(app, req)
    sha = app.storage.resolve(meta, req.groups["rev"])
    commit_ = app.storage.get_commit(meta, sha)
    entries = tree_entries(commit_.files, req.groups.get("path", ""), req.flag("recursive"))
    if req.flag("expand"):
        last = _last_commits(app.storage.history(meta, sha), [e["path"] for e in entries if e["type"] == "file"])
        for e in entries:
            if e["path"] in last:
                e["lastCommit"] = last[e["path"]]
    return Response(body=entries)


def paths_info(app: HubApp, req: Request) -> Response:
    meta = read_repo(app, req)
    sha = app.storage.resolve(meta, req.groups["rev"])
    commit_ = app.storage.get_commit(meta, sha)
    form = req.form()
    out = []
    for path in dict.fromkeys(p.strip("/") for p in form.get("paths", [])):
        if path in commit_.files:
            out.append(_file_json(path, commit_.files[path]))
        elif any(p.startswith(path + "/") for p in commit_.files):
            out.append(_dir_json(path, commit_.files))
    if str((form.get("expand") or ["false"])[-1]).lower() == "true":
        last = _last_commits(app.storage.history(meta, sha), [e["path"] for e in out if e["type"] == "file"])
        for e in out:
            if e["path"] in last:
                e["lastCommit"] = last[e["path"]]
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
    route("POST", REPO + r"/preupload/" + REV, preupload),
    route("POST", REPO + r"/commit/" + REV, commit),
    route("GET", REPO + r"/commits/" + REV, list_commits),
    route("GET", REPO + r"/tree/" + REV + r"(?:/(?P<path>.*))?", list_tree),
    route("POST", REPO + r"/paths-info/" + REV, paths_info),
]
