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

from msta_data.hub_server import boundary
from msta_data.hub_server.boundary import InputError
from msta_data.hub_server.storage import StoreError

if TYPE_CHECKING:
    from msta_data.hub_server.server import HubApp

CHUNK = 1 << 20
MIN_UPLOAD_RATE = 1024  # bytes/s a body must average once its first read_timeout_s is over


@dataclass(frozen=True)
class Limits:
    """Request limits of the server (``msta-hub serve --max_body_bytes`` ...).

    Args:
        max_body_bytes: largest body of a JSON request (everything but commits and LFS uploads);
            checked against Content-Length before anything is read or authenticated (413).
        max_commit_bytes: largest commit body (NDJSON; inline files travel base64-encoded in it,
            and one file is held in memory at a time).
        read_timeout_s: a client that sends nothing for this long is disconnected (408 while a
            body is expected); a body must also average 1 KiB/s after this time.
        max_card_bytes: largest YAML front matter of a README.md the server parses.
        max_connections: connections served at once; more are answered 503 and closed.
    """

    max_body_bytes: int = 8 << 20
    max_commit_bytes: int = 2 << 30
    read_timeout_s: float = 60.0
    max_card_bytes: int = 1 << 20
    max_connections: int = 64

    def __post_init__(self) -> None:
        for name in ("max_body_bytes", "max_commit_bytes", "max_card_bytes", "max_connections"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        if not self.read_timeout_s > 0:
            raise ValueError(f"read_timeout_s must be positive, got {self.read_timeout_s}")


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

    Args:
        rfile: the connection's input.
        length: Content-Length, or None (chunked or no body).
        chunked: Transfer-Encoding: chunked.
        limit: most bytes accepted (413 beyond).
        timeout_s: see ``Limits.read_timeout_s``; the socket itself times out single reads.
    """

    def __init__(self, rfile: io.BufferedIOBase, length: int | None, chunked: bool, limit: int, timeout_s: float):
        super().__init__()
        self._rfile = rfile
        self._chunked = chunked
        self._remaining = 0 if chunked else (length or 0)
        self._eof = not chunked and not length
        self._limit = limit
        self._timeout_s = timeout_s
        self._started = time.monotonic()
        self.received = 0
        self.broken = False  # the stream is unusable: do not drain, close the connection

    def readable(self) -> bool:
        return True

    def _fail(self, status: int, message: str) -> HttpError:
        self.broken = True
        return HttpError(status, message)

    def _next_chunk(self) -> None:
        line = self._rfile.readline(1024)
        try:
            size = int(line.split(b";")[0].strip(), 16)
        except ValueError:
            raise self._fail(400, "malformed chunked request body") from None
        if size < 0:
            raise self._fail(400, "malformed chunked request body")
        if size == 0:
            while self._rfile.readline(1024) not in (b"\r\n", b"\n", b""):
                pass  # trailers
            self._eof = True
        self._remaining = size

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
        elapsed = time.monotonic() - self._started
        if elapsed > self._timeout_s + self.received / MIN_UPLOAD_RATE:
            raise self._fail(408, "request body arrives too slowly")
        if self._remaining == 0:
            if not self._chunked:
                self._eof = True
                return 0
            self._next_chunk()
            if self._eof:
                return 0
        if self.received + min(len(buffer), self._remaining) > self._limit:
            raise self._fail(413, f"request body is larger than this server accepts ({self._limit} bytes)")
        data = self._rfile.read1(min(len(buffer), self._remaining, CHUNK))  # one recv: paced
        if not data:
            raise self._fail(400, "request body ended early")
        buffer[: len(data)] = data
        self._remaining -= len(data)
        self.received += len(data)
        if self._chunked and self._remaining == 0:
            self._rfile.readline(16)  # CRLF after each chunk
        return len(data)

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

    def json(self) -> Any:
        """The body as JSON (an empty body reads as ``{}``); 400 when malformed."""
        return boundary.parse_json(self.body.read())

    def json_object(self) -> dict[str, Any]:
        """The body as a JSON object; 400 for any other shape."""
        return boundary.json_object(self.json())

    def form(self) -> dict[str, list[str]]:
        """Body as form fields (x-www-form-urlencoded) or as a JSON object; only string values."""
        raw = self.body.read()
        if "json" in (self.headers.get("Content-Type") or ""):
            data = boundary.json_object(boundary.parse_json(raw))
            out: dict[str, list[str]] = {}
            for k, v in data.items():
                values = v if isinstance(v, list) else [v]
                out[k] = [str(x).lower() if isinstance(x, bool) else x for x in values if isinstance(x, (str, bool))]
            return out
        try:
            return parse_qs(raw.decode(), keep_blank_values=True, max_num_fields=100_000)
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


Endpoint = Callable[["HubApp", Request], Response]
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
