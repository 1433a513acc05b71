"""HTTP plumbing of the hub server: request bodies, responses, errors, routing and logging.

The handler always consumes the whole request body (also when it answers with an error), so
clients that keep connections alive (httpx, requests) never see a reset. Logged lines carry the
method, the path without its query string and the status: never headers, query strings or
bodies, so tokens and upload tickets never reach a log.
"""

from __future__ import annotations

import io
import json
import logging
import re
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler
from typing import IO, TYPE_CHECKING, Any
from urllib.parse import parse_qs, unquote, urlsplit

from msta_data.hub_server.storage import StoreError

if TYPE_CHECKING:
    from msta_data.hub_server.server import HubApp

logger = logging.getLogger("msta_data.hub_server")
_CHUNK = 1 << 20


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


class BodyReader(io.RawIOBase):
    """The request body as a stream: Content-Length or chunked transfer encoding."""

    def __init__(self, rfile: IO[bytes], length: int | None, chunked: bool):
        super().__init__()
        self._rfile = rfile
        self._chunked = chunked
        self._remaining = 0 if chunked else (length or 0)
        self._eof = not chunked and not length
        self.length = None if chunked else (length or 0)

    def readable(self) -> bool:
        return True

    def _next_chunk(self) -> None:
        line = self._rfile.readline(1024)
        try:
            size = int(line.split(b";")[0].strip(), 16)
        except ValueError:
            raise HttpError(400, "malformed chunked request body") from None
        if size == 0:
            while self._rfile.readline(1024) not in (b"\r\n", b"\n", b""):
                pass  # trailers
            self._eof = True
        self._remaining = size

    def readinto(self, buffer: Any) -> int:
        if self._eof:
            return 0
        if self._remaining == 0:
            if not self._chunked:
                self._eof = True
                return 0
            self._next_chunk()
            if self._eof:
                return 0
        data = self._rfile.read(min(len(buffer), self._remaining, _CHUNK))
        if not data:
            raise HttpError(400, "request body ended early")
        buffer[: len(data)] = data
        self._remaining -= len(data)
        if self._chunked and self._remaining == 0:
            self._rfile.readline(16)  # CRLF after each chunk
        return len(data)

    def drain(self) -> None:
        """Read and discard what is left of the body."""
        while self.read(_CHUNK):
            pass


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
        raw = self.body.read()
        try:
            return json.loads(raw or b"{}")
        except ValueError:
            raise HttpError(400, "request body is not valid JSON") from None

    def form(self) -> dict[str, list[str]]:
        """Body as form fields (x-www-form-urlencoded) or as a JSON object."""
        raw = self.body.read()
        if "json" in (self.headers.get("Content-Type") or ""):
            data = json.loads(raw or b"{}")
            return {k: v if isinstance(v, list) else [v] for k, v in data.items()}
        return parse_qs(raw.decode(), keep_blank_values=True)

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


@dataclass(frozen=True)
class Route:
    method: str
    pattern: re.Pattern
    endpoint: Endpoint


def route(method: str, regex: str, endpoint: Endpoint) -> Route:
    return Route(method, re.compile("^" + regex + "$"), endpoint)


class HubHandler(BaseHTTPRequestHandler):
    """Parses a request, authenticates it, dispatches it to a route and answers."""

    protocol_version = "HTTP/1.1"
    server_version = "msta-hub/1"
    app: HubApp  # set on the subclass made by the server

    def do_GET(self) -> None:
        self._handle()

    do_HEAD = do_POST = do_PUT = do_DELETE = do_GET

    def _handle(self) -> None:
        length_header = self.headers.get("Content-Length")
        chunked = "chunked" in (self.headers.get("Transfer-Encoding") or "").lower()
        try:
            length = int(length_header) if length_header else None
        except ValueError:
            length = None
            self.close_connection = True
        raw_body = BodyReader(self.rfile, length, chunked)
        body = io.BufferedReader(raw_body, buffer_size=_CHUNK)
        try:
            response = self._dispatch(body)
        except HttpError as err:
            response = self._error_response(err)
        except StoreError as err:
            response = self._error_response(http_error_from_store(err, None))
        except Exception:
            logger.exception("internal error on %s %s", self.command, urlsplit(self.path).path)
            response = self._error_response(HttpError(500, "internal server error"))
        try:
            raw_body.drain()
        except HttpError:
            self.close_connection = True
        self._send(response)

    def _dispatch(self, body: io.BufferedReader) -> Response:
        parts = urlsplit(self.path)
        params = {k: v[-1] for k, v in parse_qs(parts.query, keep_blank_values=True).items()}
        user = self._authenticate()
        method = "GET" if self.command == "HEAD" else self.command
        path_matched = False
        for r in self.app.routes:
            m = r.pattern.match(parts.path)
            if m is None:
                continue
            path_matched = True
            if r.method != method:
                continue
            groups = {k: unquote(v) for k, v in m.groupdict().items() if v is not None}
            req = Request(self.command, parts.path, params, self.headers, body, user,
                          self.app.base_url(self.headers.get("Host")), groups)
            try:
                return r.endpoint(self.app, req)
            except StoreError as err:
                raise http_error_from_store(err, user) from None
        if path_matched:
            raise HttpError(405, f"method {self.command} not allowed here")
        raise HttpError(404, "not found")

    def _authenticate(self) -> str | None:
        header = self.headers.get("Authorization")
        if not header:
            return None
        scheme, _, secret = header.partition(" ")
        user = self.app.auth.user_for(secret.strip()) if scheme.lower() == "bearer" else None
        if user is None:
            raise HttpError(401, "Invalid credentials in Authorization header")
        return user

    def _error_response(self, err: HttpError) -> Response:
        headers = {"X-Error-Message": err.message.replace("\n", " ")[:500], **err.headers}
        if err.code:
            headers["X-Error-Code"] = err.code
        return Response(err.status, {"error": err.message, **err.extra}, headers)

    def _send(self, response: Response) -> None:
        if response.stream is not None:
            payload = b""
            length = response.stream[2]
        elif isinstance(response.body, bytes):
            payload, length = response.body, len(response.body)
        elif response.body is None:
            payload, length = b"", 0
        else:
            payload = json.dumps(response.body).encode()
            length = len(payload)
        self.send_response(response.status)
        self.send_header("Content-Type", response.content_type)
        self.send_header("Content-Length", str(length))
        for k, v in response.headers.items():
            self.send_header(k, v)
        self.end_headers()
        if self.command == "HEAD":
            return
        if response.stream is None:
            self.wfile.write(payload)
            return
        sent = 0
        for chunk in _file_chunks(*response.stream):
            self.wfile.write(chunk)
            sent += len(chunk)
        if sent < length:  # the stored blob is shorter than recorded: make the client notice
            logger.error("blob %s is truncated on disk", response.stream[0])
            self.close_connection = True

    # Logging: method, path (no query string) and status only.
    def log_request(self, code: Any = "-", size: Any = "-") -> None:
        path = urlsplit(self.path).path if hasattr(self, "path") else "?"
        logger.info("%s %s -> %s", getattr(self, "command", "?"), path, code)

    def log_error(self, format: str, *args: Any) -> None:
        logger.warning("bad request from %s", self.client_address[0])

    def log_message(self, format: str, *args: Any) -> None:
        pass


def _file_chunks(path: str, offset: int, length: int) -> Iterator[bytes]:
    with open(path, "rb") as f:
        f.seek(offset)
        remaining = length
        while remaining > 0:
            chunk = f.read(min(remaining, _CHUNK))
            if not chunk:
                return
            remaining -= len(chunk)
            yield chunk
