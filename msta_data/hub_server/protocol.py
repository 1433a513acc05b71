"""HTTP building blocks of the hub server: limits, errors, request bodies, requests, responses
and routes. The request handler that uses them lives in handler.py.
"""

from __future__ import annotations

import io
import re
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any
from urllib.parse import parse_qs

from msta.data.hub_server import boundary
from msta.data.hub_server.boundary import InputError
from msta.data.hub_server.storage import StoreError

if TYPE_CHECKING:
    from msta.data.hub_server.connections import SocketInput

CHUNK = 1 << 20
MIN_UPLOAD_RATE = 1024  # bytes/s a body must average once its first read_timeout_s is over
MAX_CHUNK_LINE = 1024  # a chunk-size line (with extensions) or a trailer line
MAX_TRAILER_BYTES = 8 << 10
_CHUNK_SIZE = re.compile(rb"([0-9A-Fa-f]{1,16})[ \t]*(?:;[^\r\n]*)?\r\n")


@dataclass(frozen=True)
class Limits:
    """Request limits of the server (``msta-hub serve --max_body_bytes`` ...; docs/security.md).

    Args:
        max_body_bytes: largest body of an authenticated JSON request (everything but commits
            and LFS uploads); checked against Content-Length before anything is read (413).
        max_anonymous_body_bytes: the same for requests without a token (validate-yaml).
        max_commit_bytes: largest commit body (NDJSON; inline files travel base64-encoded in it,
            and one file is held in memory at a time).
        read_timeout_s: longest silence: a connection waiting for its next request, or a
            single read, is closed after it (408 while a body is expected); a body must also
            average 1 KiB/s after this time.
        header_timeout_s: the request line and headers must arrive within this time from
            the request's first byte, however they are paced (else closed with 408).
        max_card_bytes: largest YAML front matter of a README.md the server parses.
        max_connections: requests served at once (from their headers to their answer);
            more get 503.
        max_anonymous: of those, at most this many without a token (or upload ticket); the
            rest stay free for authenticated users. More get 429 (huggingface_hub retries it).
        max_anonymous_per_client: anonymous requests served at once from one IP address
            (429 beyond).
        max_open_connections: open connections (idle, sending headers or being served); more
            are answered 503 and closed at once.
        max_open_per_client: open connections from one IP address.
        max_user_connections: requests one user serves at once (LFS uploads count for the
            user whose ticket they carry); more get 429, so other users keep their slots.
        max_user_body_bytes: bytes of request bodies one user (or, without a token, one
            address) may have in progress at once, each counted at its Content-Length (a
            chunked body at its route's size limit) from its start; more get 429. LFS uploads,
            streamed to disk, are not counted; a request is never refused for this when it is
            the principal's only one in progress.
        max_user_tickets: open LFS upload tickets of one user (issued, not yet verified or
            expired); a batch request that would exceed it gets 429.
        max_tickets: open LFS upload tickets in all; a batch beyond gets 503.
    """

    max_body_bytes: int = 8 << 20
    max_anonymous_body_bytes: int = 2 << 20
    max_commit_bytes: int = 2 << 30
    read_timeout_s: float = 60.0
    header_timeout_s: float = 20.0
    max_card_bytes: int = 1 << 20
    max_connections: int = 64
    max_anonymous: int = 32
    max_anonymous_per_client: int = 8
    max_open_connections: int = 512
    max_open_per_client: int = 128
    max_user_connections: int = 16
    max_user_body_bytes: int = 4 << 30
    max_user_tickets: int = 10_000
    max_tickets: int = 100_000

    def __post_init__(self) -> None:
        for name in ("max_body_bytes", "max_anonymous_body_bytes", "max_commit_bytes", "max_card_bytes",
                     "max_connections", "max_anonymous", "max_anonymous_per_client", "max_open_connections",
                     "max_open_per_client", "max_user_connections", "max_user_body_bytes", "max_user_tickets",
                     "max_tickets"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        for name in ("read_timeout_s", "header_timeout_s"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")


class HttpError(Exception):
    """An error answer: status, message, optional X-Error-Code and extra JSON fields."""

    def __init__(self, status: int, message: str, code: str | None = None,
                 extra: dict | None = None, headers: dict[str, str] | None = None):
        super().__init__(message)
        self.status = status
        self.message = message
        self.code = code
        self.extra = extra or {}
        self.headers = headers or {}


_STORE_ERRORS = {  # StoreError.kind -> (status, X-Error-Code)
    "bad_request": (400, None),
    "conflict": (409, None),
    "precondition": (412, None),
    "revision_not_found": (404, "RevisionNotFound"),
    "entry_not_found": (404, "EntryNotFound"),
    "repo_not_found": (404, "RepoNotFound"),
}


def http_error_from_store(err: StoreError, user: str | None) -> HttpError:
    status, code = _STORE_ERRORS[err.kind]
    if code == "RepoNotFound" and user is None:
        status = 401  # the real hub answers 401 to anonymous requests for missing or private repos
    return HttpError(status, err.message, code)


def http_error_from_input(err: InputError) -> HttpError:
    return HttpError(err.status, err.message, err.code)


class BodyReader(io.RawIOBase):
    """The request body as a stream (Content-Length or chunked), bounded in size and time.

    ``received`` counts every byte read for the body, chunk framing and trailers included,
    and that count is what the size limit and the pace are checked against: the body (with
    its trailers) must arrive within ``timeout_s`` plus one second per KiB received. Chunk
    sizes must be plain hex digits and every framing line must end with CRLF (400 otherwise).

    Args:
        rfile: the connection's input.
        length: Content-Length, or None (chunked or no body).
        chunked: Transfer-Encoding: chunked.
        limit: most bytes accepted (413 beyond); ``limit`` may be changed before the first
            read (the handler raises it once the request is authenticated).
        timeout_s: see ``Limits.read_timeout_s``.
        conn: the socket reader under ``rfile``; its deadline is kept at the body's, so no
            single read waits past it.
    """

    def __init__(self, rfile: io.BufferedIOBase, length: int | None, chunked: bool, limit: int,
                 timeout_s: float, conn: SocketInput | None = None):
        super().__init__()
        self._rfile = rfile
        self._chunked = chunked
        self._remaining = 0 if chunked else (length or 0)
        self._eof = not chunked and not length
        self.limit = limit
        self._timeout_s = timeout_s
        self._conn = conn
        self._started = time.monotonic()
        self.received = 0
        self.broken = False  # the stream is unusable: do not drain, close the connection

    def readable(self) -> bool:
        return True

    def _fail(self, status: int, message: str) -> HttpError:
        self.broken = True
        return HttpError(status, message)

    def _pace(self) -> None:
        deadline = self._started + self._timeout_s + self.received / MIN_UPLOAD_RATE
        if time.monotonic() > deadline:
            raise self._fail(408, "request body arrives too slowly")
        if self._conn is not None:
            self._conn.deadline = deadline

    def _count(self, n: int) -> None:
        self.received += n
        if self.received > self.limit:
            raise self._fail(413, f"request body is larger than this server accepts ({self.limit} bytes)")

    def _line(self) -> bytes:
        self._pace()
        line = self._rfile.readline(MAX_CHUNK_LINE)
        self._count(len(line))
        if not line.endswith(b"\r\n"):
            raise self._fail(400, "malformed chunked request body (a line is too long or does not end with CRLF)")
        return line

    def _next_chunk(self) -> None:
        m = _CHUNK_SIZE.fullmatch(self._line())
        if m is None:
            raise self._fail(400, "malformed chunked request body (chunk size must be hex digits)")
        self._remaining = int(m.group(1), 16)
        if self._remaining == 0:
            trailers = 0
            while (line := self._line()) != b"\r\n":
                trailers += len(line)
                if trailers > MAX_TRAILER_BYTES:
                    raise self._fail(431, f"request trailers are longer than {MAX_TRAILER_BYTES} bytes")
            self._eof = True

    def readinto(self, buffer: Any) -> int:
        try:
            return self._readinto(buffer)
        except TimeoutError:
            raise self._fail(408, "request body not received in time") from None
        except OSError:
            raise self._fail(400, "connection failed while reading the request body") from None

    def _readinto(self, buffer: Any) -> int:
        if self._eof:
            return 0
        if self._remaining == 0:
            if not self._chunked:
                self._eof = True
                return 0
            self._next_chunk()
            if self._eof:
                return 0
        if self.received + min(len(buffer), self._remaining) > self.limit:
            raise self._fail(413, f"request body is larger than this server accepts ({self.limit} bytes)")
        self._pace()
        data = self._rfile.read1(min(len(buffer), self._remaining, CHUNK))  # one recv: paced
        if not data:
            raise self._fail(400, "request body ended early")
        buffer[: len(data)] = data
        self._remaining -= len(data)
        self.received += len(data)
        if self._chunked and self._remaining == 0:
            self._pace()
            self._count(2)
            if self._rfile.read(2) != b"\r\n":
                raise self._fail(400, "malformed chunked request body (no CRLF after a chunk)")
        return len(data)

    @property
    def left_unread(self) -> bool:
        """Part of the body may still be on the connection (not read to its end)."""
        return not self._eof and (self._chunked or self._remaining > 0)

    def drain(self, max_bytes: int) -> bool:
        """Read and discard what is left if that is at most ``max_bytes``; False when the
        connection must be closed instead (broken stream, or too much left)."""
        if self.broken:
            return False
        if not self._chunked and self._remaining > max_bytes:
            return False
        budget = max_bytes
        try:
            while budget >= 0:
                n = len(self.read(CHUNK))
                if n == 0:
                    return True
                budget -= n
        except HttpError:
            return False
        return False


@dataclass
class Request:
    """One parsed request as the endpoint functions see it."""

    method: str
    path: str
    params: dict[str, str]
    headers: Any
    body: io.BufferedReader
    user: str | None
    base_url: str
    groups: dict[str, str] = field(default_factory=dict)
    max_json_values: int = boundary.MAX_JSON_VALUES  # smaller for anonymous requests

    def json(self) -> Any:
        """The body as JSON (an empty body reads as ``{}``); 400 when malformed or too many values."""
        return boundary.parse_json(self.body.read(), max_values=self.max_json_values)

    def json_object(self) -> dict[str, Any]:
        """The body as a JSON object; 400 for any other shape."""
        return boundary.json_object(self.json())

    def form(self) -> dict[str, list[str]]:
        """Body as form fields (x-www-form-urlencoded) or as a JSON object; only string values;
        at most ``max_json_values`` fields or values (400 beyond)."""
        raw = self.body.read()
        if "json" in (self.headers.get("Content-Type") or ""):
            data = boundary.json_object(boundary.parse_json(raw, max_values=self.max_json_values))
            out: dict[str, list[str]] = {}
            for k, v in data.items():
                values = v if isinstance(v, list) else [v]
                out[k] = [str(x).lower() if isinstance(x, bool) else x for x in values if isinstance(x, (str, bool))]
            return out
        try:
            return parse_qs(raw.decode(), keep_blank_values=True, max_num_fields=self.max_json_values)
        except (UnicodeDecodeError, ValueError):
            raise HttpError(400, "request body is not a valid form") from None

    def flag(self, name: str) -> bool:
        return self.params.get(name, "").lower() in ("1", "true", "yes")


@dataclass
class Response:
    """A JSON answer, a byte answer or a streamed file."""

    status: int = 200
    body: Any = None  # JSON-serialisable, bytes or None
    headers: dict[str, str] = field(default_factory=dict)
    stream: tuple[str, int, int] | None = None  # (file path, offset, length)
    content_type: str = "application/json"


#: an endpoint: (the server's HubApp, the request) -> the answer
Endpoint = Callable[[Any, Request], Response]
BODY_KINDS = ("json", "commit", "upload")


@dataclass(frozen=True)
class Route:
    """A method and path pattern mapped to an endpoint.

    ``body`` picks the size limit checked before the request is read or authenticated:
    "json" (``max_body_bytes``), "commit" (``max_commit_bytes``) or "upload" (an LFS upload,
    bounded by its ticket's size inside the endpoint).
    """

    method: str
    pattern: re.Pattern
    endpoint: Endpoint
    body: str = "json"


def route(method: str, regex: str, endpoint: Endpoint, body: str = "json") -> Route:
    if body not in BODY_KINDS:
        raise ValueError(f"body must be one of {BODY_KINDS}, got '{body}'")
    return Route(method, re.compile("^" + regex + "$"), endpoint, body)
