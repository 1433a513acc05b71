"""Hub server request limits and client mistakes (issue 15, defects 4 and 5; docs/security.md).

Oversized, slow and malformed requests against a real server on 127.0.0.1: each is answered
with a 4xx before the server does any work for it, never a 500, and the server keeps serving.
"""

from __future__ import annotations

import hashlib
import json
import logging
import socket
import time
from urllib.parse import urlsplit

import msta_hub_security_helpers as H  # registered by tests/conftest.py
import pytest
from huggingface_hub import HfApi
from huggingface_hub.errors import HfHubHTTPError

ALICE, BOB = H.ALICE, H.BOB


@pytest.fixture
def srv(tmp_path):
    server = H.start_server(tmp_path / "hub", read_timeout_s=1.0, max_body_bytes=1 << 20)
    yield server
    server.stop()


def _raw(srv, head: bytes, body: bytes = b"", wait_s: float = 0.0, read_s: float = 10.0) -> tuple[bytes, float]:
    """Send raw bytes, optionally pause, and read until the server closes: (answer, seconds)."""
    t0 = time.monotonic()
    with socket.create_connection(("127.0.0.1", srv.port), timeout=read_s) as s:
        s.sendall(head + body)
        time.sleep(wait_s)
        answer = H.read_until_closed(s)
    return answer, time.monotonic() - t0


_status = H.status


def _alive(srv) -> bool:
    return H.call(srv, "GET", "/api/whoami-v2", token=ALICE)[0] == 200


# ------------------------------------------------------------------ 4: sizes and times
@pytest.mark.parametrize("path", ["/api/validate-yaml", "/api/repos/create", "/api/models/alice/x/commit/main"])
def test_oversized_bodies_are_refused_before_reading_or_auth(srv, path):
    """A 200 MiB Content-Length is answered 413 at once, anonymously, without sending the body."""
    size = 200 << 20 if "commit" not in path else (3 << 30)
    head = f"POST {path} HTTP/1.1\r\nHost: x\r\nContent-Length: {size}\r\n\r\n".encode()
    answer, seconds = _raw(srv, head, b"{" * 1000)
    assert _status(answer) == 413 and seconds < 5, answer[:200]
    assert b"connection: close" in answer.lower()
    assert _alive(srv)


def test_chunked_body_over_the_limit_is_cut_off(srv):
    head = b"POST /api/validate-yaml HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\n\r\n"
    chunk = b"%x\r\n" % (256 << 10) + b"a" * (256 << 10) + b"\r\n"
    answer, _ = _raw(srv, head, chunk * 6)
    assert _status(answer) == 413
    assert _alive(srv)


@pytest.mark.parametrize("length", ["-1", "abc", "1e3", "99999999999999999999999", "10, 10"])
def test_bad_content_length_is_a_400(srv, length):
    head = f"POST /api/validate-yaml HTTP/1.1\r\nHost: x\r\nContent-Length: {length}\r\n\r\n".encode()
    answer, seconds = _raw(srv, head)
    assert _status(answer) == 400 and seconds < 5, answer[:200]


def test_content_length_larger_than_the_body_times_out_with_408(srv):
    head = b"POST /api/validate-yaml HTTP/1.1\r\nHost: x\r\nContent-Length: 1000\r\n\r\n"
    answer, seconds = _raw(srv, head, b'{"content": "')
    assert _status(answer) == 408 and seconds < 5, answer[:200]
    assert _alive(srv)


def test_trickled_body_is_cut_off(srv):
    """One byte every 0.3 s never hits the per-read timeout, but the body's pace does."""
    t0 = time.monotonic()
    with socket.create_connection(("127.0.0.1", srv.port), timeout=10) as s:
        s.sendall(b"POST /api/validate-yaml HTTP/1.1\r\nHost: x\r\nContent-Length: 100000\r\n\r\n")
        try:
            for _ in range(60):
                s.sendall(b" ")
                time.sleep(0.3)
        except OSError:
            pass  # the server hung up
        answer = s.recv(65536)
    assert _status(answer) == 408 and time.monotonic() - t0 < 10


def test_idle_connections_are_closed_and_connections_capped(tmp_path, caplog):
    caplog.set_level(logging.DEBUG, logger="msta.data.hub_server")
    srv = H.start_server(tmp_path / "hub", read_timeout_s=1.0, max_open_connections=2)
    try:
        idle = [socket.create_connection(("127.0.0.1", srv.port), timeout=5) for _ in range(2)]
        time.sleep(0.2)
        answer, _ = _raw(srv, b"GET /api/whoami-v2 HTTP/1.1\r\nHost: x\r\n\r\n")
        assert _status(answer) == 503
        for s in idle:  # closed by the server after read_timeout_s
            assert s.recv(10) == b""
            s.close()
        time.sleep(0.2)
        assert _alive(srv)
    finally:
        srv.stop()
    # closing an idle keep-alive connection is routine, not a client mistake
    assert "idle connection from 127.0.0.1 closed" in caplog.text
    assert not any("bad request" in r.getMessage() for r in caplog.records)


# ------------------------------------------------------------------ 5: client mistakes
NOT_AN_OBJECT = [b"[]", b"[1, 2]", b"1", b'"s"', b"null", b"{", b"\xff\xfe", b"[" * 5000 + b"]" * 5000,
                 b'{"a":' * 3000 + b"1" + b"}" * 3000]
MALFORMED = [*NOT_AN_OBJECT, b'{"name": 5}', b'{"name": ["a"]}',
             b'{"name": "ok", "organization": 7}', b'{"name": "ok", "private": "yes"}', b'{"type": 1}',
             b'{"tag": {"x": 1}}',
             b'{"files": [1, "a", {"path": 3, "size": "x"}]}', b'{"objects": {"oid": 1}}',
             b'{"operation": "upload", "objects": [null, {"oid": "../x", "size": -1}]}',
             b'{"content": 5, "repoType": []}', b'{"paths": [1, null]}', b'{"visibility": 3}',
             b'{"startingPoint": 5}', b'{"emptyBranch": "x"}', b'{"oid": []}']


def test_malformed_json_gets_4xx_never_500(srv, caplog):
    H.create_repo(srv, ALICE, "m")
    routes = [("POST", "/api/repos/create"), ("DELETE", "/api/repos/delete"), ("POST", "/api/validate-yaml"),
              ("PUT", "/api/models/alice/m/settings"), ("POST", "/api/models/alice/m/tag/main"),
              ("POST", "/api/models/alice/m/branch/b1"), ("POST", "/api/models/alice/m/preupload/main"),
              ("POST", "/api/models/alice/m/commit/main"), ("POST", "/api/models/alice/m/paths-info/main"),
              ("POST", "/alice/m.git/info/lfs/objects/batch"), ("POST", "/lfs/verify/" + "t" * 43)]
    with caplog.at_level(logging.INFO, logger="msta.data.hub_server"):
        for method, path in routes:
            for body in MALFORMED:
                for token in (None, ALICE):
                    status, answer, _ = H.call(srv, method, path, body, token,
                                               {"Content-Type": "application/json"})
                    assert status < 500, (method, path, body[:40], token, status, answer[:200])
                    if body in NOT_AN_OBJECT:
                        assert 400 <= status < 500, (method, path, body[:40], token, status)
    assert "internal error" not in caplog.text and "Traceback" not in caplog.text
    assert _alive(srv)


def test_ref_names_that_shadow_refs_are_refused(srv):
    api = HfApi(endpoint=srv.url, token=ALICE)
    api.create_repo("alice/r")
    sha = api.upload_file(path_or_fileobj=b"x", path_in_repo="x.txt", repo_id="alice/r").oid
    for bad in ("refs/heads/main", "refs/tags/v1", "HEAD", "a..b", ".hidden", "x.lock", "-x", "a//b", sha):
        with pytest.raises(HfHubHTTPError) as err:
            api.create_tag("alice/r", tag=bad, revision=sha)
        assert err.value.response.status_code == 400, bad
        with pytest.raises(HfHubHTTPError) as err:
            api.create_branch("alice/r", branch=bad, revision=sha)
        assert err.value.response.status_code in (400, 404), bad
    assert api.list_repo_refs("alice/r").tags == []
    assert api.model_info("alice/r", revision="refs/heads/main").sha == sha
    api.create_tag("alice/r", tag="stage1-r0", revision=sha)
    api.create_tag("alice/r", tag="v3.0", revision=sha)


def test_lfs_upload_tickets_never_reach_the_log(srv, caplog):
    H.create_repo(srv, ALICE, "lfs")
    data = b"some model weights"
    oid = hashlib.sha256(data).hexdigest()
    with caplog.at_level(logging.INFO, logger="msta.data.hub_server"):
        obj = H.lfs_batch(srv, ALICE, "alice/lfs", oid, len(data))
        upload = urlsplit(obj["actions"]["upload"]["href"]).path
        assert H.call(srv, "PUT", upload, data)[0] == 200
        verify = urlsplit(obj["actions"]["verify"]["href"]).path
        assert H.call(srv, "POST", verify, json.dumps({"oid": oid}), ALICE)[0] == 200
        assert H.call(srv, "PUT", upload + "?x=1", data)[0] == 403  # a closed ticket
    ticket = upload.rsplit("/", 1)[1]
    assert ticket not in caplog.text and ALICE not in caplog.text
    assert "PUT /lfs/upload/<ticket> -> 200" in caplog.text
    assert "POST /lfs/verify/<ticket> -> 200" in caplog.text
