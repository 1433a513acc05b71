"""The hub server's request handler: framing, limits, authentication, routing, answers, logs.

Order of work for each request, cheapest checks first: the body's framing (Content-Length /
chunked) is checked (400), the route is found (404/405), the declared body size is checked
against the route's limit (413, nothing read), then the token is checked (401) and only then
the endpoint reads the body, bounded in size (413) and time (408). Small bodies are drained
after an error answer so keep-alive clients keep their connection; large or broken ones close
it. Logged lines carry the method, the path without its query string (LFS upload tickets
replaced by ``<ticket>``) and the status: never headers, query strings, bodies or tokens.
"""

from __future__ import annotations

import io
import json
import logging
import re
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler
from typing import TYPE_CHECKING, Any
from urllib.parse import parse_qs, unquote, urlsplit

from msta_data.hub_server.boundary import InputError
from msta_data.hub_server.protocol import (
    CHUNK,
    BodyReader,
    HttpError,
    Request,
    Response,
    Route,
    http_error_from_input,
    http_error_from_store,
)
from msta_data.hub_server.storage import StoreError

if TYPE_CHECKING:
    from msta_data.hub_server.server import HubApp

logger = logging.getLogger("msta_data.hub_server")
_TICKET_PATH = re.compile(r"^/lfs/(upload|verify)/[^/]*")


def redact(path: str) -> str:
    """The path as it may be logged: no query string, LFS tickets replaced by ``<ticket>``."""
    path = urlsplit(path).path
    return _TICKET_PATH.sub(r"/lfs/\1/<ticket>", path)[:1000]


class HubHandler(BaseHTTPRequestHandler):
    """Parses a request, checks limits, authenticates it, dispatches it to a route and answers."""

    protocol_version = "HTTP/1.1"
    server_version = "msta-hub/1"
    app: HubApp  # set on the subclass made by the server
    timeout: float | None = None  # socket timeout, set from Limits.read_timeout_s by the server

    def do_GET(self) -> None:
        self._handle()

    do_HEAD = do_POST = do_PUT = do_DELETE = do_PATCH = do_OPTIONS = do_GET

    def _handle(self) -> None:
        reader: BodyReader | None = None
        try:
            length, chunked = self._framing()
            route, groups = self._match()
            limit = self._body_limit(route)
            if length is not None and length > limit:
                raise HttpError(413, f"request body is larger than this server accepts ({limit} bytes)")
            reader = BodyReader(self.rfile, length, chunked, limit, self.app.limits.read_timeout_s)
            response = self._dispatch(route, groups, io.BufferedReader(reader, buffer_size=CHUNK))
        except HttpError as err:
            response = self._error_response(err)
        except InputError as err:
            response = self._error_response(http_error_from_input(err))
        except StoreError as err:
            response = self._error_response(http_error_from_store(err, None))
        except Exception:
            logger.exception("internal error on %s %s", self.command, redact(self.path))
            response = self._error_response(HttpError(500, "internal server error"))
        if reader is None or not reader.drain(self.app.limits.max_body_bytes):
            self.close_connection = True
        self._send(response)

    def _framing(self) -> tuple[int | None, bool]:
        """(Content-Length or None, chunked); 400 for anything ambiguous or malformed."""
        lengths = self.headers.get_all("Content-Length") or []
        encoding = (self.headers.get("Transfer-Encoding") or "").strip().lower()
        if encoding not in ("", "chunked") or (encoding and lengths) or len(lengths) > 1:
            raise HttpError(400, "unsupported or ambiguous request framing (Transfer-Encoding, Content-Length)")
        if not lengths:
            return None, encoding == "chunked"
        value = lengths[0].strip()
        if not value.isdigit() or len(value) > 18:
            raise HttpError(400, "Content-Length must be a non-negative integer")
        return int(value), False

    def _match(self) -> tuple[Route, dict[str, str]]:
        path = urlsplit(self.path).path
        method = "GET" if self.command == "HEAD" else self.command
        path_matched = False
        for r in self.app.routes:
            m = r.pattern.match(path)
            if m is None:
                continue
            path_matched = True
            if r.method == method:
                try:
                    groups = {k: unquote(v, errors="strict") for k, v in m.groupdict().items() if v is not None}
                except UnicodeDecodeError:
                    raise HttpError(400, "path is not valid percent-encoded UTF-8") from None
                return r, groups
        if path_matched:
            raise HttpError(405, f"method {self.command} not allowed here")
        raise HttpError(404, "not found")

    def _body_limit(self, route: Route) -> int:
        limits = self.app.limits
        if route.body == "commit":
            return limits.max_commit_bytes
        if route.body == "upload":
            return 1 << 62  # bounded by the ticket's announced size in the endpoint
        return limits.max_body_bytes

    def _dispatch(self, route: Route, groups: dict[str, str], body: io.BufferedReader) -> Response:
        parts = urlsplit(self.path)
        try:
            query = parse_qs(parts.query, keep_blank_values=True, max_num_fields=100, errors="strict")
        except (ValueError, UnicodeDecodeError):
            raise HttpError(400, "malformed query string") from None
        params = {k: v[-1] for k, v in query.items()}
        user = self._authenticate()
        req = Request(self.command, parts.path, params, self.headers, body, user,
                      self.app.base_url(self.headers.get("Host")), groups)
        try:
            return route.endpoint(self.app, req)
        except StoreError as err:
            raise http_error_from_store(err, user) from None

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
        message = err.message.encode("ascii", "backslashreplace").decode()  # headers are latin-1
        headers = {"X-Error-Message": message.replace("\n", " ").replace("\r", " ")[:500], **err.headers}
        if err.code:
            headers["X-Error-Code"] = err.code
        return Response(err.status, {"error": err.message, **err.extra}, headers)

    def _send(self, response: Response) -> None:
        if response.stream is not None:
            payload, length = b"", response.stream[2]
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
        if self.close_connection:
            self.send_header("Connection", "close")
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
            logger.error("a blob is truncated on disk (answering %s)", redact(self.path))
            self.close_connection = True

    # Logging: method, redacted path and status only.
    def log_request(self, code: Any = "-", size: Any = "-") -> None:
        path = redact(self.path) if hasattr(self, "path") else "?"
        logger.info("%s %s -> %s", getattr(self, "command", "?"), path, code)

    def log_error(self, format: str, *args: Any) -> None:
        if format.startswith("Request timed out"):  # an idle keep-alive connection closed
            logger.debug("idle connection from %s closed", self.client_address[0])
            return
        logger.warning("bad request from %s", self.client_address[0])

    def log_message(self, format: str, *args: Any) -> None:
        pass


def _file_chunks(path: str, offset: int, length: int) -> Iterator[bytes]:
    with open(path, "rb") as f:
        f.seek(offset)
        remaining = length
        while remaining > 0:
            chunk = f.read(min(remaining, CHUNK))
            if not chunk:
                return
            remaining -= len(chunk)
            yield chunk
