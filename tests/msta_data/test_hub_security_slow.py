"""Slow and greedy clients against a real hub server on 127.0.0.1 (issue 41; docs/security.md).

A client that trickles its headers or its chunked trailers is cut off at the request's deadline,
not only when it falls silent; anonymous clients hold at most their share of the request slots,
per address and in all, so authenticated users are still served while 64 slow anonymous
connections are open. Linux routes all of 127.0.0.0/8 to loopback, so connections from
127.0.0.2 and 127.0.0.3 stand in for other client machines.
"""

from __future__ import annotations

import io
import select
import socket
import threading
import time

import msta_hub_security_helpers as H  # registered by tests/conftest.py
from huggingface_hub import hf_hub_url
from huggingface_hub.file_download import http_get

ALICE = H.ALICE
_YAML_HEAD = b"POST /api/validate-yaml HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\n\r\n"


def _connect(srv, source: str = "127.0.0.1") -> socket.socket:
    return socket.create_connection(("127.0.0.1", srv.port), timeout=10, source_address=(source, 0))


def _slow_headers(srv, source: str = "127.0.0.1") -> socket.socket:
    """A request whose line and first header arrived, the rest still to come."""
    s = _connect(srv, source)
    s.sendall(b"GET /api/whoami-v2 HTTP/1.1\r\nHost: x\r\n")
    return s


def _slow_trailers(srv, source: str = "127.0.0.1") -> socket.socket:
    """An anonymous validate-yaml whose body is complete but whose trailers never end."""
    s = _connect(srv, source)
    s.sendall(_YAML_HEAD + b"2\r\n{}\r\n0\r\nX-Trailer: 1\r\n")
    return s


def _answer(s: socket.socket, wait_s: float) -> bytes:
    """What the server sent within ``wait_s`` (b"" when nothing yet or closed)."""
    s.settimeout(wait_s)
    try:
        return s.recv(4096)
    except (TimeoutError, ConnectionResetError):
        return b""


def _answers(socks: list[socket.socket], expected: int, wait_s: float = 10.0) -> list[int]:
    """Statuses of the first ``expected`` sockets the server answers (fewer after ``wait_s``),
    then of any other answered within 0.3 s more."""
    got: dict[socket.socket, int] = {}
    deadline = time.monotonic() + wait_s
    while len(got) < expected and time.monotonic() < deadline:
        ready, _, _ = select.select([s for s in socks if s not in got], [], [], 0.1)
        got.update((s, _status(_answer(s, 1.0))) for s in ready)
    ready, _, _ = select.select([s for s in socks if s not in got], [], [], 0.3)
    return list(got.values()) + [_status(_answer(s, 1.0)) for s in ready]


_status = H.status


def _trickle(s: socket.socket, pieces: list[bytes], every_s: float) -> tuple[bytes, float]:
    """Send ``pieces`` one by one every ``every_s`` until the server answers or hangs up."""
    t0 = time.monotonic()
    s.settimeout(every_s)
    for piece in pieces:
        try:
            s.sendall(piece)
            answer = s.recv(4096)
        except TimeoutError:
            continue
        except OSError:
            answer = b""
        return answer, time.monotonic() - t0
    return b"still open", time.monotonic() - t0


def test_headers_trickled_line_by_line_are_cut_off_at_the_header_deadline(tmp_path):
    """One header line every 0.2 s never lets a read time out (5 s), but the headers' deadline
    (1 s) closes the connection with 408."""
    srv = H.start_server(tmp_path / "hub", read_timeout_s=5.0, header_timeout_s=1.0)
    try:
        with _slow_headers(srv) as s:
            answer, seconds = _trickle(s, [b"X-Slow: %d\r\n" % i for i in range(40)], 0.2)
        assert _status(answer) == 408 and seconds < 6, (answer[:80], seconds)
        assert H.call(srv, "GET", "/api/whoami-v2", token=ALICE)[0] == 200
    finally:
        srv.stop()


def test_endless_chunked_trailers_are_cut_off_by_pace_and_by_size(tmp_path):
    """Trailers count against the body's deadline and its size: trickled ones end in 408,
    a flood of them in 431, both anonymous on /api/validate-yaml."""
    srv = H.start_server(tmp_path / "hub", read_timeout_s=1.0)
    try:
        with _slow_trailers(srv) as s:
            answer, seconds = _trickle(s, [b"X-Trailer: %d\r\n" % i for i in range(40)], 0.2)
        assert _status(answer) == 408 and seconds < 6, (answer[:80], seconds)
        with _connect(srv) as s:
            s.sendall(_YAML_HEAD + b"2\r\n{}\r\n0\r\n" + b"X-Trailer: 123456789\r\n" * 1000)
            assert _status(_answer(s, 5)) == 431
    finally:
        srv.stop()


def test_64_slow_anonymous_connections_leave_authenticated_users_served(tmp_path):
    """With the default limits, 32 trickled headers and 32 endless trailers from one address:
    an authenticated request is answered within 1 s; the address holds 8 anonymous request
    slots (``max_anonymous_per_client``), its other slow bodies got 429 at once."""
    srv = H.start_server(tmp_path / "hub")
    slow = [_slow_headers(srv) for _ in range(32)]
    trailers = [_slow_trailers(srv) for _ in range(32)]
    try:
        refused = _answers(trailers, 32 - 8)
        t0 = time.monotonic()
        status, body, _ = H.call(srv, "GET", "/api/whoami-v2", token=ALICE)
        assert status == 200 and time.monotonic() - t0 < 1.0, body
        assert refused == [429] * (32 - 8)
        status, _, headers = H.call(srv, "POST", "/api/validate-yaml", b"{}")
        assert status == 429 and headers["retry-after"] == "1"  # this address's anonymous share is used
        assert H.call(srv, "POST", "/api/validate-yaml", b"{}", ALICE)[0] == 200
    finally:
        for s in slow + trailers:
            s.close()
        srv.stop()


def test_per_client_caps_hold_one_address_and_not_the_others(tmp_path):
    """One address at its open-connection cap, another at its anonymous-request cap: a third
    address is served as usual."""
    srv = H.start_server(tmp_path / "hub", max_open_per_client=3, max_anonymous_per_client=1)
    idle = [_connect(srv, "127.0.0.2") for _ in range(3)]  # accepted in order: before the 4th
    held = _hold_anonymous_slots(srv, 1, "127.0.0.3")
    try:
        with _slow_headers(srv, "127.0.0.2") as s:
            assert _status(_answer(s, 5)) == 503  # 127.0.0.2 has 3 open connections
        with _slow_trailers(srv, "127.0.0.3") as s:
            assert _status(_answer(s, 5)) == 429  # 127.0.0.3 holds its one anonymous slot
        assert H.call(srv, "POST", "/api/validate-yaml", b"{}")[0] == 200  # from 127.0.0.1
    finally:
        for s in [*idle, *held]:
            s.close()
        srv.stop()


def _probe(srv, source: str) -> int:
    """Status of an anonymous request from ``source`` (401 while it has a slot free)."""
    with _connect(srv, source) as s:
        s.sendall(b"GET /api/whoami-v2 HTTP/1.1\r\nHost: x\r\n\r\n")
        return _status(_answer(s, 10))


def _hold_anonymous_slots(srv, n: int, source: str = "127.0.0.1") -> list[socket.socket]:
    """``n`` slow bodies holding the ``n`` anonymous request slots of ``source``, checked by
    an anonymous probe that is refused. A slow body refused because a probe held a slot at
    that moment (it got an answer) is sent again."""
    held = [_slow_trailers(srv, source) for _ in range(n)]
    deadline = time.monotonic() + 20
    while True:
        assert time.monotonic() < deadline, "the slow bodies never took their slots"
        refused, _, _ = select.select(held, [], [], 0.05)
        for s in refused:
            held.remove(s)
            s.close()
            held.append(_slow_trailers(srv, source))
        if not refused and _probe(srv, source) in (429, 503):
            return held


def test_a_download_over_the_anonymous_share_waits_and_succeeds(tmp_path):
    """An anonymous client over its share is told 429 with Retry-After, which huggingface_hub's
    file download retries (it does not retry 503): a snapshot_download with more threads than
    ``max_anonymous_per_client`` gets every file. Here the address's two slots are held by slow
    bodies released after 1 s, while a file download is refused and retried."""
    srv = H.start_server(tmp_path / "hub", max_anonymous_per_client=2)
    H.create_repo(srv, ALICE, "pub", repo_type="dataset")
    data = bytes(range(256)) * 64
    assert H.commit(srv, ALICE, "alice/pub", [H.inline_file("f.bin", data)], repo_type="datasets")[0] == 200
    held = _hold_anonymous_slots(srv, 2)
    try:
        threading.Timer(1.0, lambda: [s.close() for s in held]).start()
        got = io.BytesIO()
        http_get(hf_hub_url("alice/pub", "f.bin", repo_type="dataset",
                            endpoint=f"http://127.0.0.1:{srv.port}"), got)
        assert got.getvalue() == data
    finally:
        for s in held:
            s.close()
        srv.stop()
