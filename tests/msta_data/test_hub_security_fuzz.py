"""Property-based test of the hub server (hypothesis): random paths, refs, names, tokens and
JSON / NDJSON bodies thrown at every route of a real server on 127.0.0.1.

Invariants checked on every answer: no 5xx; no byte of a canary file that sits next to the
root, of /etc/passwd or of alice's private file reaches anyone but alice; and, through a Python
audit hook on the server's request threads, no file outside the root (and the interpreter's
own install) is ever opened. Slow and oversized senders (random framing, sizes around the
limits, header floods, requests cut into pieces with pauses or never finished) against a
server with short deadlines: every connection is answered or closed within its deadline,
never with a 5xx, and the server keeps serving. ``MSTA_FUZZ_EXAMPLES`` (default 300 per
test, a twentieth of it for the slow senders) sets the budget; the examples are the same on
every run unless ``MSTA_FUZZ_RANDOM=1``.
"""

from __future__ import annotations

import base64
import json
import os
import socket
import sys
import threading
import time
from pathlib import Path
from urllib.parse import quote

import msta_hub_security_helpers as H  # registered by tests/conftest.py
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

ALICE, BOB = H.ALICE, H.BOB
CANARY = b"CANARY-" + os.urandom(12).hex().encode()
ALICE_SECRET = b"ALICE-PRIVATE-" + os.urandom(12).hex().encode()
EXAMPLES = int(os.environ.get("MSTA_FUZZ_EXAMPLES", "300"))
FUZZ = settings(max_examples=EXAMPLES, deadline=None, database=None,
                derandomize=os.environ.get("MSTA_FUZZ_RANDOM") != "1",
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])

# ------------------------------------------------------------------ files opened by the server
_OUTSIDE: list[str] = []
_WATCH: dict[str, Path] = {}
_SOURCE = Path(sys.modules["msta.data.hub_server"].__file__).parents[1]  # tracebacks read source lines
_ALLOWED = tuple({os.path.realpath(p) for p in (sys.prefix, sys.base_prefix, sys.exec_prefix, _SOURCE)})


def _audit(event: str, args: tuple) -> None:
    if event != "open" or "root" not in _WATCH or not isinstance(args[0], (str, bytes, os.PathLike)):
        return
    if "process_request_thread" not in threading.current_thread().name:
        return  # only the server's request threads
    path = os.path.realpath(os.fsdecode(args[0]))
    if not path.startswith(str(_WATCH["root"]) + os.sep) and not path.startswith(_ALLOWED):
        _OUTSIDE.append(path)


sys.addaudithook(_audit)  # audit hooks cannot be removed; _audit does nothing unless watching


@pytest.fixture(scope="module")
def hub(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("fuzz")
    (tmp / "canary.txt").write_bytes(CANARY)
    srv = H.start_server(tmp / "hub", read_timeout_s=2.0)
    for token, name, private in ((ALICE, "pub", False), (ALICE, "priv", True), (BOB, "mine", False)):
        H.create_repo(srv, token, name, private=private)
    assert H.commit(srv, ALICE, "alice/priv", [H.inline_file("s.txt", ALICE_SECRET)])[0] == 200
    assert H.commit(srv, ALICE, "alice/pub", [H.inline_file("dir/a.txt", b"public")])[0] == 200
    _WATCH["root"] = Path(os.path.realpath(srv.config.root))
    yield srv
    _WATCH.clear()
    srv.stop()


# ------------------------------------------------------------------ strategies
_TRICKY = ["..", ".", "%2e%2e", "%2E%2E", "..%2f..", "%2f", "..%5c..", "..\\..", "canary.txt", "etc", "passwd",
           "main", "refs", "heads", "tags", "v1", "s.txt", "dir", "a.txt", "%00", "%ff", "a%20b", ".git", "",
           "%252e%252e", "~", "*", "HEAD", "0" * 40, "0" * 7]
segment = st.one_of(st.sampled_from(_TRICKY),
                    st.text(st.characters(codec="utf-8", exclude_categories=["Cs"]), max_size=10).map(
                        lambda s: quote(s, safe="")))
path = st.lists(segment, min_size=1, max_size=6).map("/".join)
namespace = st.sampled_from(["alice", "bob", "lab", "..", "%2e%2e", "api", "x"]) | segment
name = st.sampled_from(["pub", "priv", "mine", "..", "nope"]) | segment
token = st.sampled_from([None, ALICE, BOB, "hf_not_a_user"])
oid = st.one_of(st.sampled_from(["../canary.txt", "../../canary.txt", "/etc/passwd", "../" * 9 + "etc/passwd",
                                 "a" * 64, "A" * 64, "", "0" * 63]), path, st.integers(), st.none())
json_value = st.recursive(st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=8)
                          | path, lambda kids: st.lists(kids, max_size=4) | st.dictionaries(
                              st.sampled_from(["name", "type", "organization", "private", "tag", "files", "path",
                                               "size", "oid", "objects", "operation", "paths", "content",
                                               "visibility", "startingPoint", "emptyBranch", "expand", "x"]),
                              kids, max_size=5), max_leaves=12)

_REPO_ROUTES = [("GET", ""), ("GET", "/revision/{rev}"), ("PUT", "/settings"), ("GET", "/refs"),
                ("POST", "/tag/{rev}"), ("DELETE", "/tag/{rev}"), ("POST", "/branch/{rev}"),
                ("DELETE", "/branch/{rev}"), ("POST", "/preupload/{rev}"), ("POST", "/commit/{rev}"),
                ("GET", "/commits/{rev}"), ("GET", "/tree/{rev}/{path}"), ("POST", "/paths-info/{rev}")]
_OTHER_ROUTES = [("GET", "/api/whoami-v2"), ("POST", "/api/repos/create"), ("DELETE", "/api/repos/delete"),
                 ("POST", "/api/validate-yaml"), ("PUT", "/lfs/upload/{rev}"), ("POST", "/lfs/verify/{rev}"),
                 ("POST", "/{ns}/{name}.git/info/lfs/objects/batch"), ("GET", "/{ns}/{name}/resolve/{rev}/{path}"),
                 ("HEAD", "/datasets/{ns}/{name}/resolve/{rev}/{path}"), ("GET", "/{path}")]


@st.composite
def request_line(draw: st.DrawFn) -> tuple[str, str]:
    """A (method, url) for a random route with random parts."""
    parts = {"ns": draw(namespace), "name": draw(name), "rev": draw(segment | st.sampled_from(["main", "v1"])),
             "path": draw(path)}
    if draw(st.booleans()):
        method, tail = draw(st.sampled_from(_REPO_ROUTES))
        kind = draw(st.sampled_from(["models", "datasets", "spaces"]))
        url = f"/api/{kind}/{{ns}}/{{name}}{tail}"
    else:
        method, url = draw(st.sampled_from(_OTHER_ROUTES))
    return method, url.format(**parts)


@st.composite
def commit_body(draw: st.DrawFn) -> bytes:
    """NDJSON with a header and random file / lfsFile / delete operations."""
    lines: list = [{"key": "header", "value": {"summary": draw(st.text(min_size=0, max_size=5))}}]
    for _ in range(draw(st.integers(0, 3))):
        key = draw(st.sampled_from(["file", "lfsFile", "deletedFile", "deletedFolder", "header", "junk"]))
        value = {"path": draw(path | st.integers()), "oid": draw(oid), "size": draw(st.none() | st.integers(-1, 99)),
                 "content": base64.b64encode(draw(st.binary(max_size=16))).decode()}
        lines.append({"key": key, "value": value} if draw(st.booleans()) else draw(json_value))
    return "\n".join(json.dumps(x) for x in lines).encode()


body = st.one_of(st.none(), json_value.map(lambda v: json.dumps(v).encode()), commit_body(),
                 st.binary(max_size=64))


# ------------------------------------------------------------------ the properties
def _check(srv, method: str, url: str, data: bytes | None, who: str | None) -> None:
    status, answer, headers = H.call(srv, method, url, data, who, {"Content-Type": "application/json"})
    assert status < 500, (method, url, data, who, status, answer[:300])
    leaked = CANARY in answer or b"root:x:0:0" in answer or any(CANARY.decode() in v for v in headers.values())
    assert not leaked, (method, url, data)
    if who != ALICE:
        assert ALICE_SECRET not in answer, (method, url, data, who)
    assert not _OUTSIDE, _OUTSIDE


@FUZZ
@given(line=request_line(), who=token)
def test_random_urls_never_fail_or_leak(hub, line, who):
    method, url = line
    _check(hub, method, url, None, who)


@FUZZ
@given(line=request_line(), data=body, who=token)
def test_random_bodies_never_fail_or_leak(hub, line, data, who):
    method, url = line
    _check(hub, method, url, data, who)


@FUZZ
@given(data=commit_body(), repo=st.sampled_from(["bob/mine", "alice/pub"]), who=st.sampled_from([ALICE, BOB]))
def test_random_commits_never_fail_or_leak(hub, data, repo, who):
    _check(hub, "POST", f"/api/models/{repo}/commit/main", data, who)
    for file in ("p.txt", "s.txt", "dir/a.txt"):
        _check(hub, "GET", f"/{repo}/resolve/main/{file}", None, who)
    _check(hub, "GET", f"/api/models/{repo}", None, who)


# ------------------------------------------------------------------ slow and oversized senders
_DEADLINE_S = 0.3  # read_timeout_s and header_timeout_s of the server below
SLOW = settings(FUZZ, max_examples=max(EXAMPLES // 20, 10))


@pytest.fixture(scope="module")
def strict(tmp_path_factory):
    srv = H.start_server(tmp_path_factory.mktemp("slow") / "hub", read_timeout_s=_DEADLINE_S,
                         header_timeout_s=_DEADLINE_S, max_body_bytes=2048, max_anonymous_body_bytes=1024)
    H.create_repo(srv, ALICE, "pub")
    yield srv
    srv.stop()


def _chunked(draw: st.DrawFn, payload: bytes) -> bytes:
    """``payload`` in random chunks (sizes in any hex case, optional extensions) and trailers."""
    out, rest = [], payload
    while rest:
        n = draw(st.integers(1, max(len(rest), 1)))
        ext = draw(st.sampled_from([b"", b";a=b", b" ;x"]))
        out.append(draw(st.sampled_from([b"%x", b"%X"])) % n + ext + b"\r\n" + rest[:n] + b"\r\n")
        rest = rest[n:]
    trailers = draw(st.lists(st.sampled_from([b"X-T: 1\r\n", b"bad\r\n", b"X-Big: " + b"a" * 3000 + b"\r\n"]),
                             max_size=4))
    return b"".join(out) + b"0\r\n" + b"".join(trailers) + b"\r\n"


@st.composite
def wire_request(draw: st.DrawFn) -> tuple[list[bytes], list[float]]:
    """A request's bytes, cut into pieces sent after pauses, possibly never finished."""
    method, url = draw(request_line())
    who = draw(token)
    payload = draw(body) or b""
    payload = (payload + b" " * draw(st.sampled_from([0, 900, 1100, 2100, 5000])))[:6000]
    framing = draw(st.sampled_from(["length", "longer", "shorter", "chunked", "none"]))
    head = [f"{method} {url} HTTP/1.1", "Host: x"] + ([f"Authorization: Bearer {who}"] if who else [])
    head += [f"X-Pad-{i}: " + "p" * draw(st.sampled_from([1, 900])) for i in range(draw(st.sampled_from([0, 5, 150])))]
    sent = payload
    if framing == "chunked":
        head.append("Transfer-Encoding: chunked")
        sent = _chunked(draw, payload)
    elif framing != "none":
        extra = {"length": 0, "longer": draw(st.integers(1, 10**12)), "shorter": -draw(st.integers(0, 50))}[framing]
        head.append(f"Content-Length: {max(len(payload) + extra, 0)}")
    data = ("\r\n".join(head) + "\r\n\r\n").encode() + sent
    if draw(st.booleans()):  # a sender that stops before the end
        data = data[: draw(st.integers(0, len(data)))]
    cuts = sorted(draw(st.lists(st.integers(0, len(data)), max_size=4)))
    pieces = [data[a:b] for a, b in zip([0, *cuts], [*cuts, len(data)], strict=True)]
    return pieces, draw(st.lists(st.floats(0, 0.1), min_size=len(pieces), max_size=len(pieces)))


@SLOW
@given(request=wire_request())
def test_slow_and_oversized_senders_are_answered_or_closed_in_time(strict, request):
    pieces, pauses = request
    with socket.create_connection(("127.0.0.1", strict.port), timeout=10) as s:
        sent = 0
        for piece, pause in zip(pieces, pauses, strict=True):
            time.sleep(pause)
            try:
                s.sendall(piece)
            except OSError:
                break  # answered and closed already
            sent += len(piece)
        # after the last byte: the header deadline, or the body's (one second per KiB received)
        s.settimeout(2 * _DEADLINE_S + sent / 1024 + 3.0)
        try:
            answer = s.recv(4096)
        except TimeoutError:
            pytest.fail(f"connection held past its deadline: {[p[:60] for p in pieces]}")
        except ConnectionResetError:
            answer = b""
    status = int(answer.split(b" ", 2)[1]) if answer.startswith(b"HTTP/") else 0
    assert status < 500, (status, answer[:300], [p[:80] for p in pieces])
    assert H.call(strict, "GET", "/api/whoami-v2", token=ALICE)[0] == 200


_SIZE_FORMS = {b"%x": True, b"%X": True, b"%04x": True, b"0x%x": False, b"+%x": False, b"0_%x": False,
               b" %x": False, b"%x\n": False}  # spelling of a chunk size -> valid HTTP/1.1


@FUZZ
@given(data=st.data())
def test_chunk_sizes_are_accepted_only_as_plain_hex(strict, data):
    """A valid validate-yaml body in random chunks: 200 when every size line is plain hex ending
    in CRLF, 400 as soon as one is spelled the way Python's int() would also take."""
    payload = json.dumps({"content": "---\ntags: [a]\n---\n", "repoType": "model"}).encode()
    chunks, rest, valid = [], payload, True
    while rest:
        n = data.draw(st.integers(1, len(rest)))
        form = data.draw(st.sampled_from(sorted(_SIZE_FORMS)))
        valid &= _SIZE_FORMS[form]
        line = form % n if form.endswith(b"\n") else form % n + b"\r\n"
        chunks.append(line + rest[:n] + b"\r\n")
        rest = rest[n:]
    request = (b"POST /api/validate-yaml HTTP/1.1\r\nHost: x\r\nConnection: close\r\n"
               b"Transfer-Encoding: chunked\r\n\r\n" + b"".join(chunks) + b"0\r\n\r\n")
    with socket.create_connection(("127.0.0.1", strict.port), timeout=10) as s:
        s.sendall(request)
        answer = s.recv(4096)
    assert answer.startswith(b"HTTP/1.1 200 " if valid else b"HTTP/1.1 400 "), (answer[:200], chunks)
