"""Strict HTTP framing, honest error statuses and clean logs of a real hub server on 127.0.0.1
(issue 41, item 7; docs/security.md).

Lenient chunk sizes, folded or malformed header lines and odd Content-Length values are 400,
never accepted and never a 500; a repo deleted while its commit arrives is 404 (409 when it was
created again), and while an LFS upload to it arrives 404; a full disk is 507 with no
temporary file left behind; control characters sent by a client are escaped in
X-Error-Message and in the log.
"""

from __future__ import annotations

import hashlib
import json
import logging
import resource
import socket
import subprocess
import sys
import time
from urllib.parse import urlsplit

import msta_hub_security_helpers as H  # registered by tests/conftest.py
import pytest

ALICE = H.ALICE
_VALID = b'{"content": ""}'


@pytest.fixture(scope="module")
def srv(tmp_path_factory):
    server = H.start_server(tmp_path_factory.mktemp("framing") / "hub", read_timeout_s=2.0)
    yield server
    server.stop()


def _raw(port: int, data: bytes, pause_after: int | None = None, between=None) -> bytes:
    """Send ``data`` (optionally in two parts with ``between()`` run in the pause); the answer."""
    with socket.create_connection(("127.0.0.1", port), timeout=10) as s:
        if pause_after is None:
            s.sendall(data)
        else:
            s.sendall(data[:pause_after])
            time.sleep(0.2)
            between()
            s.sendall(data[pause_after:])
        return H.read_until_closed(s)


_status = H.status


def _post(head: bytes, body: bytes = b"") -> bytes:
    return b"POST /api/validate-yaml HTTP/1.1\r\nHost: x\r\nConnection: close\r\n" + head + b"\r\n" + body


_CHUNKED = b"Transfer-Encoding: chunked\r\n"
MALFORMED = {
    "chunk size 0x..": _post(_CHUNKED, b"0xf\r\n" + _VALID + b"\r\n0\r\n\r\n"),
    "chunk size +..": _post(_CHUNKED, b"+f\r\n" + _VALID + b"\r\n0\r\n\r\n"),
    "chunk size 0_..": _post(_CHUNKED, b"0_f\r\n" + _VALID + b"\r\n0\r\n\r\n"),
    "chunk size after a space": _post(_CHUNKED, b" f\r\n" + _VALID + b"\r\n0\r\n\r\n"),
    "no CRLF after a chunk": _post(_CHUNKED, b"f\r\n" + _VALID + b"XY\r\n0\r\n\r\n"),
    "folded Transfer-Encoding": _post(b"Transfer-Encoding:\r\n chunked\r\n", b"f\r\n" + _VALID + b"\r\n0\r\n\r\n"),
    "two Transfer-Encoding lines": _post(_CHUNKED * 2, b"f\r\n" + _VALID + b"\r\n0\r\n\r\n"),
    "space before the colon": _post(b"Content-Length : 15\r\n", _VALID),
    "NUL in a header": _post(b"X-A: a\x00b\r\nContent-Length: 15\r\n", _VALID),
    "Content-Length superscript two": _post(b"Content-Length: \xb2\r\n", b"{}"),
    "Content-Length +15": _post(b"Content-Length: +15\r\n", _VALID),
    "Content-Length -15": _post(b"Content-Length: -15\r\n", _VALID),
    "Content-Length huge": _post(b"Content-Length: 99999999999999999999999\r\n", _VALID),
    "two differing Content-Lengths": _post(b"Content-Length: 15\r\nContent-Length: 2\r\n", _VALID),
}


@pytest.mark.parametrize("name", MALFORMED)
def test_lenient_framing_is_a_400(srv, name):
    answer = _raw(srv.port, MALFORMED[name])
    assert _status(answer) == 400, answer[:200]
    assert H.call(srv, "POST", "/api/validate-yaml", _VALID)[0] == 200  # a well-framed one works


def test_control_characters_are_escaped_in_headers_and_logs(srv, caplog):
    H.create_repo(srv, ALICE, "ctl")
    with caplog.at_level(logging.INFO, logger="msta.data.hub_server"):
        for path in (b"/api/models/alice/x%1b[31m%07", b"/api/models/alice/ctl/revision/a\x1b[31m\x07b"):
            answer = _raw(srv.port, b"GET " + path + b" HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n")
            head = answer.split(b"\r\n\r\n")[0]
            assert 400 <= _status(answer) < 500 and b"X-Error-Message" in head, answer[:300]
            assert not any(c < 32 and c not in b"\r\n" or c == 127 for c in head), head
    assert "/revision/a\\x1b[31m\\x07b -> 404" in caplog.text
    assert not any(c in caplog.text for c in "\x1b\x07")


def test_a_repo_deleted_during_its_commit_is_404_and_recreated_409(srv):
    body = "\n".join(json.dumps(x) for x in [{"key": "header", "value": {"summary": "s"}}, H.inline_file("f", b"x")])
    request = (b"POST /api/models/alice/gone/commit/main HTTP/1.1\r\nHost: x\r\nConnection: close\r\n"
               b"Authorization: Bearer " + ALICE.encode() + b"\r\nContent-Type: application/x-ndjson\r\n"
               b"Content-Length: %d\r\n\r\n" % len(body) + body.encode())
    delete = json.dumps({"name": "gone", "type": "model"})
    for again, expected in ((False, 404), (True, 409)):
        H.create_repo(srv, ALICE, "gone")

        def delete_it(again: bool = again) -> None:
            assert H.call(srv, "DELETE", "/api/repos/delete", delete, ALICE)[0] == 200
            if again:
                H.create_repo(srv, ALICE, "gone")

        answer = _raw(srv.port, request, pause_after=len(request) - 10, between=delete_it)
        assert _status(answer) == expected, answer[:300]
        assert H.call(srv, "DELETE", "/api/repos/delete", delete, ALICE)[0] in (200, 404)


def test_a_repo_deleted_during_an_lfs_upload_is_404(srv):
    H.create_repo(srv, ALICE, "lfsgone")
    data = b"z" * 5000
    obj = H.lfs_batch(srv, ALICE, "alice/lfsgone", hashlib.sha256(data).hexdigest(), len(data))
    put = urlsplit(obj["actions"]["upload"]["href"]).path.encode()
    request = b"PUT " + put + b" HTTP/1.1\r\nHost: x\r\nContent-Length: %d\r\n\r\n" % len(data) + data

    def delete_it() -> None:
        assert H.call(srv, "DELETE", "/api/repos/delete", json.dumps({"name": "lfsgone"}), ALICE)[0] == 200

    answer = _raw(srv.port, request, pause_after=len(request) - 100, between=delete_it)
    assert _status(answer) == 404, answer[:300]


def test_a_full_disk_is_507_and_leaves_no_temporary_files(tmp_path):
    """`msta-hub serve` whose files may not grow past 64 KiB (RLIMIT_FSIZE: writes fail with
    EFBIG, as they fail with ENOSPC on a full disk)."""
    tokens, port_file, root = tmp_path / "tokens", tmp_path / "port", tmp_path / "hub"
    tokens.write_text(f"alice:{ALICE}\n")
    proc = subprocess.Popen([sys.executable, "-m", "msta.data.hub_cli", "serve", "--root", str(root),
                             "--token-file", str(tokens), "--port-file", str(port_file)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while not (port_file.exists() and port_file.read_text().strip()):
            assert proc.poll() is None and time.monotonic() < deadline, "server did not start"
            time.sleep(0.05)
        resource.prlimit(proc.pid, resource.RLIMIT_FSIZE, (64 << 10, 64 << 10))
        srv = type("Served", (), {"port": int(port_file.read_text())})()
        H.create_repo(srv, ALICE, "full")
        status, body = H.commit(srv, ALICE, "alice/full", [H.inline_file("big.bin", b"x" * (256 << 10))])
        assert status == 507, body
        assert H.lfs_upload(srv, ALICE, "alice/full", b"y" * (256 << 10)) == 507
        assert H.commit(srv, ALICE, "alice/full", [H.inline_file("small.txt", b"fits")])[0] == 200
        leftovers = [p for p in root.rglob("*") if p.name.endswith(".tmp") or p.parent == root / "tmp"]
        assert leftovers == []
    finally:
        proc.terminate()
        _, err = proc.communicate(timeout=20)
    assert "no space left for POST /api/models/alice/full/commit/main (EFBIG)" in err
    assert "Traceback" not in err
