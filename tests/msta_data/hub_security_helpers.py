"""Raw-HTTP helpers shared by the hub security tests (a real server on 127.0.0.1, no mocks).

Holds no tests. ``tests/conftest.py`` registers it as ``msta_hub_security_helpers`` (with
``--import-mode=importlib`` a test directory is not on ``sys.path``, and a ``tests`` package
installed in site-packages shadows this tree's ``tests`` directory).
"""

from __future__ import annotations

import base64
import hashlib
import http.client
import json
import socket
from pathlib import Path
from urllib.parse import urlsplit

from msta.data.hub_server import HubServer, Limits, ServerConfig

__test__ = False  # nothing to collect here

ALICE, BOB = "hf_aaaaaaaa", "hf_bbbbbbbb"
TOKENS = [f"alice:{ALICE}", f"bob:{BOB}"]


def read_until_closed(s: socket.socket) -> bytes:
    """Everything the server sends on ``s`` until it hangs up (or the socket's timeout)."""
    chunks = []
    try:
        while chunk := s.recv(65536):
            chunks.append(chunk)
    except (TimeoutError, ConnectionResetError):
        pass
    return b"".join(chunks)


def status(answer: bytes) -> int:
    """The status code of a raw HTTP answer (-1: no status line)."""
    return int(answer.split(b" ", 2)[1]) if answer.startswith(b"HTTP/") else -1


def start_server(root: Path, **limits: float) -> HubServer:
    """A server on 127.0.0.1 with users alice and bob (the auditor's setup)."""
    return HubServer(ServerConfig(root=root, tokens=list(TOKENS), limits=Limits(**limits))).start()


def call(srv: HubServer, method: str, path: str, body: bytes | str | None = None, token: str | None = None,
         headers: dict[str, str] | None = None) -> tuple[int, bytes, dict[str, str]]:
    """One request on a fresh connection: (status, body, headers)."""
    conn = http.client.HTTPConnection("127.0.0.1", srv.port, timeout=30)
    h = dict(headers or {})
    if token:
        h["Authorization"] = f"Bearer {token}"
    try:
        conn.request(method, path, body=body.encode() if isinstance(body, str) else body, headers=h)
        r = conn.getresponse()
        return r.status, r.read(), {k.lower(): v for k, v in r.getheaders()}
    finally:
        conn.close()


def create_repo(srv: HubServer, token: str, name: str, private: bool = False, repo_type: str = "model") -> None:
    status, body, _ = call(srv, "POST", "/api/repos/create", json.dumps(
        {"name": name, "private": private, "type": repo_type}), token)
    assert status == 200, body


def commit(srv: HubServer, token: str, repo: str, ops: list[dict], summary: str = "x",
           repo_type: str = "models") -> tuple[int, bytes]:
    """POST an NDJSON commit: a header line then ``ops`` (each {"key": ..., "value": ...})."""
    lines = [{"key": "header", "value": {"summary": summary}}, *ops]
    body = "\n".join(json.dumps(x) for x in lines)
    status, data, _ = call(srv, "POST", f"/api/{repo_type}/{repo}/commit/main", body, token,
                           {"Content-Type": "application/x-ndjson"})
    return status, data


def inline_file(path: str, data: bytes) -> dict:
    return {"key": "file", "value": {"path": path, "content": base64.b64encode(data).decode(),
                                     "encoding": "base64"}}


def lfs_file(path: str, oid: str, size: int | None = None) -> dict:
    value: dict = {"path": path, "algo": "sha256", "oid": oid}
    if size is not None:
        value["size"] = size
    return {"key": "lfsFile", "value": value}


def lfs_batch(srv: HubServer, token: str, repo: str, oid: str, size: int) -> dict:
    """The batch answer's one object for an upload of (oid, size) to ``repo``."""
    status, body, _ = call(srv, "POST", f"/{repo}.git/info/lfs/objects/batch", json.dumps(
        {"operation": "upload", "transfers": ["basic"], "objects": [{"oid": oid, "size": size}]}), token,
        {"Content-Type": "application/vnd.git-lfs+json"})
    assert status == 200, body
    return json.loads(body)["objects"][0]


def lfs_upload(srv: HubServer, token: str, repo: str, data: bytes, claimed_oid: str | None = None) -> int:
    """Git LFS basic transfer of ``data`` into ``repo``: batch, PUT, verify; the PUT's status."""
    oid = claimed_oid or hashlib.sha256(data).hexdigest()
    obj = lfs_batch(srv, token, repo, oid, len(data))
    if "actions" not in obj:
        return 200
    put = urlsplit(obj["actions"]["upload"]["href"]).path
    status, _, _ = call(srv, "PUT", put, data)
    if status == 200:
        verify = urlsplit(obj["actions"]["verify"]["href"]).path
        vstatus, body, _ = call(srv, "POST", verify, json.dumps({"oid": oid, "size": len(data)}), token)
        assert vstatus == 200, body
    return status


def git_sha1(data: bytes) -> str:
    """Git blob id of ``data`` (the tree's ``oid`` of a regular file)."""
    return hashlib.sha1(b"blob %d\0" % len(data) + data).hexdigest()
