"""Budgets per principal (a user, or the address of a client without a token) and LFS upload
tickets, against a real hub server on 127.0.0.1 (issue harden-3; docs/security.md): one user
at its cap of request slots, body bytes or open tickets leaves the others served; a batch lists
at most 1000 objects and its answer stays small; one Authorization header a request; a bad
``--host`` or ``--port`` of ``msta-hub serve`` is one line.
"""

from __future__ import annotations

import hashlib
import json
import select
import socket
import subprocess
import sys
import time
from urllib.parse import urlsplit

import msta_hub_security_helpers as H  # registered by tests/conftest.py
import pytest

ALICE, BOB = H.ALICE, H.BOB
_LFS = {"Content-Type": "application/vnd.git-lfs+json"}


def _slow_commit(srv, token: str, repo: str, length: int = 100_000) -> socket.socket:
    """A commit whose headers arrived and whose body (``length`` bytes announced) trickles."""
    s = socket.create_connection(("127.0.0.1", srv.port), timeout=10)
    s.sendall(b"POST /api/models/%s/commit/main HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer %s\r\n"
              b"Content-Type: application/x-ndjson\r\nContent-Length: %d\r\n\r\n{\"key\"" % (
                  repo.encode(), token.encode(), length))
    return s


def _refusals(socks: list[socket.socket], expected: int, wait_s: float = 10.0) -> list[bytes]:
    """The answers of the first ``expected`` sockets the server answers (fewer after
    ``wait_s``), then of any other answered within 0.3 s more."""
    got: dict[socket.socket, bytes] = {}
    deadline = time.monotonic() + wait_s
    while len(got) < expected and time.monotonic() < deadline:
        ready, _, _ = select.select([s for s in socks if s not in got], [], [], 0.1)
        got.update((s, H.read_until_closed(s)) for s in ready)
    ready, _, _ = select.select([s for s in socks if s not in got], [], [], 0.3)
    return list(got.values()) + [H.read_until_closed(s) for s in ready]


def _until(condition, wait_s: float = 10.0) -> None:
    deadline = time.monotonic() + wait_s
    while not condition():
        assert time.monotonic() < deadline, "the server never got there"
        time.sleep(0.02)


def _held(srv, user: str, requests: int) -> None:
    """Wait until ``user`` has ``requests`` requests in progress on the server. Polling with
    the user's own requests instead would race: a poll that takes a slot while a slow commit's
    headers arrive gets that commit refused."""
    _until(lambda: srv.httpd.admission.in_progress(user)[0] == requests)


# ------------------------------------------------------------------ request slots and bytes
def test_one_user_with_64_slow_commits_leaves_other_users_and_anonymous_clients_served(tmp_path):
    """With the default limits alice holds 16 request slots (max_user_connections); her other
    48 slow commits get 429 at once, naming the limit; bob and anonymous clients are served."""
    srv = H.start_server(tmp_path / "hub")
    H.create_repo(srv, ALICE, "m")
    slow = [_slow_commit(srv, ALICE, "alice/m") for _ in range(64)]
    try:
        refused = _refusals(slow, 64 - 16)
        assert len(refused) == 48 and {H.status(a) for a in refused} == {429}, refused[:1]
        assert b"max_user_connections" in refused[0] and b"retry-after: 1" in refused[0].lower()
        t0 = time.monotonic()
        assert H.call(srv, "GET", "/api/whoami-v2", token=BOB)[0] == 200
        assert H.commit(srv, BOB, "bob/none", [])[0] == 404  # served: the repo does not exist
        assert H.call(srv, "GET", "/api/whoami-v2")[0] == 401  # anonymous: served, no token
        assert time.monotonic() - t0 < 2.0
        status, body, _ = H.call(srv, "GET", "/api/whoami-v2", token=ALICE)
        assert status == 429 and b"user alice" in body
    finally:
        for s in slow:
            s.close()
        srv.stop()


def test_body_bytes_in_progress_are_capped_per_user(tmp_path):
    """max_user_body_bytes = 1 MiB: while alice's 800 kB commit trickles in, her second commit
    of 300 kB is 429 naming the limit, a small one and a request without a body pass, bob's
    300 kB one passes; alone, a body over the cap passes (the size limits bound a single body)."""
    srv = H.start_server(tmp_path / "hub", max_user_body_bytes=1 << 20)
    for token in (ALICE, BOB):
        H.create_repo(srv, token, "m")
    big = [H.inline_file("big.bin", b"\0" * 225_000)]  # ~300 kB of base64
    slow = _slow_commit(srv, ALICE, "alice/m", 800_000)
    try:
        _held(srv, "alice", 1)
        status, body = H.commit(srv, ALICE, "alice/m", big)
        assert status == 429 and "max_user_body_bytes" in json.loads(body)["error"]
        assert H.commit(srv, ALICE, "alice/m", [H.inline_file("small.txt", b"x")])[0] == 200
        assert H.call(srv, "GET", "/api/whoami-v2", token=ALICE)[0] == 200  # no body: counts nothing
        assert H.commit(srv, BOB, "bob/m", big)[0] == 200
    finally:
        slow.close()
    _until(lambda: H.commit(srv, ALICE, "alice/m", [H.inline_file("big.bin", b"\1" * 900_000)])[0] == 200)
    srv.stop()


def test_a_refused_client_still_sending_its_body_reads_the_429(tmp_path):
    """A body refused unread (alice's byte budget in use) and larger than the sockets' buffers:
    the server reads off what she still sends before it closes, so her client gets the 429
    and not a reset while sending (the race a smaller refused body met now and then)."""
    srv = H.start_server(tmp_path / "hub", max_user_body_bytes=1 << 20)
    H.create_repo(srv, ALICE, "m")
    slow = _slow_commit(srv, ALICE, "alice/m", 800_000)
    try:
        _held(srv, "alice", 1)
        status, body = H.commit(srv, ALICE, "alice/m", [H.inline_file("big.bin", b"\0" * (6 << 20))])
        assert status == 429 and "max_user_body_bytes" in json.loads(body)["error"]
    finally:
        slow.close()
    srv.stop()


def test_an_lfs_upload_counts_for_the_user_whose_ticket_it_carries(tmp_path):
    """A PUT carries no token but a ticket: alice at her cap of 2 slots gets 429 for an upload
    with her ticket, while bob's upload is served."""
    srv = H.start_server(tmp_path / "hub", max_user_connections=2)
    for token in (ALICE, BOB):
        H.create_repo(srv, token, "m")
    puts = {}
    for token, repo in ((ALICE, "alice/m"), (BOB, "bob/m")):
        obj = H.lfs_batch(srv, token, repo, hashlib.sha256(repo.encode()).hexdigest(), len(repo))
        puts[repo] = urlsplit(obj["actions"]["upload"]["href"]).path
    slow = [_slow_commit(srv, ALICE, "alice/m") for _ in range(2)]
    try:
        _held(srv, "alice", 2)
        assert H.call(srv, "GET", "/api/whoami-v2", token=ALICE)[0] == 429
        status, body, _ = H.call(srv, "PUT", puts["alice/m"], b"alice/m")
        assert status == 429 and b"user alice" in body and b"max_user_connections" in body
        assert H.call(srv, "PUT", puts["bob/m"], b"bob/m")[0] == 200
    finally:
        for s in slow:
            s.close()
        srv.stop()


# ------------------------------------------------------------------ LFS tickets
def _content(repo: str, i: int) -> bytes:
    return b"%s %d" % (repo.encode(), i)


def _batch(srv, token: str, repo: str, n: int, start: int = 0, headers: dict | None = None):
    """A batch request for the objects ``_content(repo, i)``, i in [start, start + n)."""
    objects = [{"oid": hashlib.sha256(_content(repo, i)).hexdigest(), "size": len(_content(repo, i))}
               for i in range(start, start + n)]
    body = json.dumps({"operation": "upload", "transfers": ["basic"], "objects": objects})
    return H.call(srv, "POST", f"/{repo}.git/info/lfs/objects/batch", body, token, {**_LFS, **(headers or {})})


def test_open_lfs_tickets_are_capped_per_user_and_in_all(tmp_path):
    """max_user_tickets = 5, max_tickets = 8: a batch past alice's 5 is 429, past the server's 8
    503, both naming the limit and issuing nothing; a verified upload frees its ticket."""
    srv = H.start_server(tmp_path / "hub", max_user_tickets=5, max_tickets=8)
    for token in (ALICE, BOB):
        H.create_repo(srv, token, "m")
    try:
        status, body, _ = _batch(srv, ALICE, "alice/m", 5)
        assert status == 200 and body.count(b'"upload"') == 5
        first = json.loads(body)["objects"][0]["actions"]
        status, body, _ = _batch(srv, ALICE, "alice/m", 1, start=5)
        assert status == 429 and b"max_user_tickets" in body, body
        status, body, _ = _batch(srv, BOB, "bob/m", 4)  # 9 in all
        assert status == 503 and b"max_tickets" in body, body
        status, body, _ = _batch(srv, BOB, "bob/m", 3)
        assert status == 200 and body.count(b'"upload"') == 3
        assert _batch(srv, BOB, "bob/m", 1, start=3)[0] == 503
        data = _content("alice/m", 0)
        assert H.call(srv, "PUT", urlsplit(first["upload"]["href"]).path, data)[0] == 200
        verify = json.dumps({"oid": hashlib.sha256(data).hexdigest(), "size": len(data)})
        assert H.call(srv, "POST", urlsplit(first["verify"]["href"]).path, verify, ALICE)[0] == 200
        status, body, _ = _batch(srv, ALICE, "alice/m", 1, start=5)
        assert status == 200 and body.count(b'"upload"') == 1
    finally:
        srv.stop()


def test_a_batch_lists_at_most_1000_objects_and_its_answer_stays_small(tmp_path):
    """60,000 objects (the auditor's batch) and 1001 are 413 naming the limit; 1000 objects with
    the longest Host the server accepts answer under 1 MiB; a longer or odd Host is 400."""
    srv = H.start_server(tmp_path / "hub")
    H.create_repo(srv, ALICE, "m")
    try:
        for n in (60_000, 1001):
            status, body, _ = _batch(srv, ALICE, "alice/m", n)
            assert status == 413 and b"at most 1000 objects" in body, body[:200]
        host = "h" * 253 + ":65535"
        status, body, _ = _batch(srv, ALICE, "alice/m", 1000, headers={"Host": host})
        assert status == 200 and body.count(b'"upload"') == 1000 and len(body) < 1 << 20, len(body)
        for bad in ("h" * 254, "evil.example/x?", "a b"):
            assert _batch(srv, ALICE, "alice/m", 1, headers={"Host": bad})[0] == 400
    finally:
        srv.stop()


# ------------------------------------------------------------------ headers and the command line
@pytest.mark.parametrize("first, second", [(ALICE, "hf_wrong-token"), ("hf_wrong-token", ALICE), (BOB, ALICE)])
def test_two_authorization_headers_are_refused(tmp_path, first, second):
    srv = H.start_server(tmp_path / "hub")
    try:
        with socket.create_connection(("127.0.0.1", srv.port), timeout=10) as s:
            s.sendall(b"GET /api/whoami-v2 HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer %s\r\n"
                      b"Authorization: Bearer %s\r\nConnection: close\r\n\r\n" % (first.encode(), second.encode()))
            answer = H.read_until_closed(s)
        assert H.status(answer) == 400 and b"more than one Authorization header" in answer, answer[:200]
    finally:
        srv.stop()


def test_serve_with_a_bad_host_or_port_says_so_in_one_line(tmp_path):
    """``msta-hub serve`` as a process: no traceback, one line naming the value."""
    cases = {"--host=0.0.0.0.0": "0.0.0.0.0", "--port=-1": "port", "--port=65536": "port", "--port=http": "port"}
    procs = {arg: subprocess.Popen([sys.executable, "-m", "msta.data.hub_cli", "serve", f"--root={tmp_path / 'h'}",
                                    "--token=alice:secret-123", arg], stdout=subprocess.PIPE,
                                   stderr=subprocess.PIPE, text=True) for arg in cases}
    for arg, proc in procs.items():
        _, err = proc.communicate(timeout=60)
        lines = [ln for ln in err.splitlines() if ln.strip()]
        assert proc.returncode in (1, 2) and "Traceback" not in err, (arg, err)
        assert len(lines) == 1 and cases[arg] in lines[0], (arg, err)
