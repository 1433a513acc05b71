"""The hub server's request handler: deadlines, framing, limits, authentication, routing,
answers, logs.

Order of work for each request, cheapest checks first. The request line and headers must
arrive within ``header_timeout_s`` and 64 KiB (else 408 / 431, connection closed). The framing
(Content-Length / chunked, no folded or malformed header lines) is checked (400), the route is
found (404/405), the token is checked (401; 400 for two Authorization headers), the declared
body size is checked against the route's limit, smaller for anonymous requests (413, nothing
read), a request slot is taken for the request's principal (its user, or its address without a
token: 503 when the server has none left, 429 when the principal's share of slots or body bytes
is used; connection closed, after reading off for up to 2 s what the client still sends, so
it gets the answer rather than a reset), and only then the endpoint reads the body, bounded in size (413)
and pace (408). After another error answer a body of at most ``max_anonymous_body_bytes`` (``max_body_bytes`` for users) is drained, at the
same pace, so keep-alive clients keep their connection; larger or broken ones close it. A full
disk is a 507. Logged lines carry the method, the path without its query string (LFS upload tickets
replaced by ``<ticket>``, control characters escaped) and the status: never headers, query
strings, bodies or tokens.
"""

from __future__ import annotations

import errno
import io
import json
import logging
import re
import socket
import time
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler
from typing import TYPE_CHECKING, Any
from urllib.parse import parse_qs, unquote, urlsplit

from msta.data.hub_server import boundary
from msta.data.hub_server.boundary import InputError
from msta.data.hub_server.connections import MAX_HEADER_BYTES, HeadersTooLarge, SocketInput
from msta.data.hub_server.protocol import (
    CHUNK,
    BodyReader,
    HttpError,
    Request,
    Response,
    Route,
    http_error_from_input,
    http_error_from_store,
)
from msta.data.hub_server.storage import StoreError

if TYPE_CHECKING:
    from msta.data.hub_server.app import HubApp

logger = logging.getLogger("msta.data.hub_server")
_TICKET_PATH = re.compile(r"^/lfs/(upload|verify)/[^/]*")
_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f]")
_BAD_HEADER_VALUE = re.compile(r"[\x00-\x08\x0a-\x1f\x7f]")  # CR, LF (folded lines), NUL ...
_CONTENT_LENGTH = re.compile(r"[0-9]{1,18}")
_DISK_FULL = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)
_CLOSING = {408: b"408 Request Timeout", 431: b"431 Request Header Fields Too Large"}
#: after an answer that closes the connection while the client may still be sending its
#: body: how long and how much of it is read and dropped before the socket closes
LINGER_S, LINGER_BYTES = 2.0, 16 << 20


def escape_controls(text: str) -> str:
    """``text`` with control characters written as ``\\xNN`` (safe for headers and logs)."""
    return _CONTROL.sub(lambda m: f"\\x{ord(m.group()):02x}", text)


def redact(path: str) -> str:
    """The path as it may be logged: no query string, LFS tickets replaced by ``<ticket>``,
    control characters escaped."""
    path = urlsplit(path).path
    return escape_controls(_TICKET_PATH.sub(r"/lfs/\1/<ticket>", path)[:1000])


def linger(sock: Any, seconds: float = LINGER_S, max_bytes: int = LINGER_BYTES) -> None:
    """Close the sending side, then read and drop what the client still sends (until it
    closes, ``seconds`` pass or ``max_bytes`` arrive). A socket closed with unread input
    answers a reset, which can reach the client before it reads the answer just sent (a 429
    or 413 would then look like a broken connection to it)."""
    deadline = time.monotonic() + seconds
    try:
        sock.shutdown(socket.SHUT_WR)
        while max_bytes > 0 and (left := deadline - time.monotonic()) > 0:
            sock.settimeout(left)
            data = sock.recv(min(max_bytes, 1 << 16))
            if not data:
                return
            max_bytes -= len(data)
    except OSError:  # reset, or timed out
        pass


class HubHandler(BaseHTTPRequestHandler):
    """Parses a request, checks limits, authenticates it, dispatches it to a route and answers."""

    protocol_version = "HTTP/1.1"
    server_version = "msta-hub/1"
    app: HubApp  # set on the subclass made by the server
    timeout: float | None = None  # socket timeout, set from Limits.read_timeout_s by the server
    _slot: tuple[str | None, int] | None = None  # the request slot taken: (user or None, body bytes)
    _reader: BodyReader | None = None  # the current request's body, once a slot is taken
    _linger = False  # closing with the body maybe still coming: read it off first (linger)

    def setup(self) -> None:
        super().setup()
        self.rfile.close()  # reads go through SocketInput and its deadlines instead
        self.conn = SocketInput(self.connection, self.app.limits.read_timeout_s)
        self.rfile = io.BufferedReader(self.conn)

    def finish(self) -> None:
        """Flush the answer; linger (:func:`linger`) when the client may still be sending."""
        super().finish()
        if self._linger:
            linger(self.connection)

    def handle_one_request(self) -> None:
        """Wait for a request (read_timeout_s), read its line and headers against their own
        deadline (header_timeout_s) and size (64 KiB), then answer it."""
        limits = self.app.limits
        self.conn.start("idle", limits.read_timeout_s)
        try:
            if not self.rfile.peek(1):
                self.close_connection = True
                return
        except OSError:  # timed out or reset: an idle keep-alive connection ends
            logger.debug("idle connection from %s closed", self.client_address[0])
            self.close_connection = True
            return
        self.conn.start("headers", limits.header_timeout_s, MAX_HEADER_BYTES)
        try:
            self.raw_requestline = self.rfile.readline(65537)
            if len(self.raw_requestline) > 65536:
                raise HeadersTooLarge("request line too long")
            if not self.raw_requestline.endswith(b"\n"):  # the client left mid-line
                self.close_connection = True
                return
            if not self.parse_request():
                return  # answered (400, 431, ...) by parse_request
        except TimeoutError:
            logger.warning("request headers from %s not received within %g s: closed",
                           self.client_address[0], limits.header_timeout_s)
            return self._close_with(408)
        except HeadersTooLarge:
            logger.warning("request headers from %s longer than %d bytes: closed",
                           self.client_address[0], MAX_HEADER_BYTES)
            return self._close_with(431)
        except OSError:
            self.close_connection = True
            return
        self.connection.settimeout(limits.read_timeout_s)
        method = getattr(self, "do_" + self.command, None)
        if method is None:
            self.send_error(501, f"Unsupported method ({self.command!r})")
            return
        try:
            method()
            self.wfile.flush()
        except OSError:  # the client stopped reading the answer
            logger.debug("answer to %s not taken in time: closed", self.client_address[0])
            self.close_connection = True

    def _close_with(self, status: int) -> None:
        self.close_connection = True
        try:
            self.connection.settimeout(1.0)
            self.wfile.write(b"HTTP/1.1 %s\r\nContent-Length: 0\r\nConnection: close\r\n\r\n" % _CLOSING[status])
        except OSError:
            pass

    def do_GET(self) -> None:
        self._handle()

    do_HEAD = do_POST = do_PUT = do_DELETE = do_PATCH = do_OPTIONS = do_GET

    def _handle(self) -> None:
        try:
            try:
                response = self._respond()
            except HttpError as err:
                response = self._error_response(err)
            except InputError as err:
                response = self._error_response(http_error_from_input(err))
            except StoreError as err:
                response = self._error_response(http_error_from_store(err, None))
            except OSError as err:
                response = self._error_response(self._os_error(err))
            except Exception:
                logger.exception("internal error on %s %s", self.command, redact(self.path))
                response = self._error_response(HttpError(500, "internal server error"))
            limits = self.app.limits
            user = self._slot[0] if self._slot is not None else None
            drain = limits.max_body_bytes if user is not None else limits.max_anonymous_body_bytes
            if self._reader is None or not self._reader.drain(drain):  # small bodies: keep-alive
                self.close_connection = True
                self._linger = self._reader is not None and self._reader.left_unread
            self._send(response)
        finally:
            self._reader = None
            if self._slot is not None:
                self.server.admission.end(self.client_address[0], *self._slot)  # type: ignore[attr-defined]
                self._slot = None

    def _respond(self) -> Response:
        """Check the request, take a request slot, and run the endpoint. The body is read
        only once the slot is taken (or drained, at most an anonymous body, after an error)."""
        limits = self.app.limits
        length, chunked = self._framing()
        self.conn.start("body", limits.read_timeout_s)  # BodyReader moves the deadline on
        self._reader = BodyReader(self.rfile, length, chunked, limits.max_anonymous_body_bytes,
                                  limits.read_timeout_s, self.conn)
        route, groups = self._match()
        user = self._authenticate()
        principal = user if user is not None else self._ticket_user(groups)
        anonymous = principal is None
        limit = self._body_limit(route, anonymous)
        if length is not None and length > limit:
            raise HttpError(413, f"request body is larger than this server accepts ({limit} bytes)")
        held = _held_bytes(route, length, chunked, limit)
        refused = self.server.admission.begin(self.client_address[0], principal, held)  # type: ignore[attr-defined]
        if refused is not None:
            self._reader.broken = True  # busy: close rather than read the body
            raise HttpError(refused.status, refused.message, headers={"Retry-After": "1"})
        self._slot = (principal, held)
        self._reader.limit = limit
        values = boundary.MAX_ANONYMOUS_JSON_VALUES if anonymous else boundary.MAX_JSON_VALUES
        return self._dispatch(route, groups, user, io.BufferedReader(self._reader, buffer_size=CHUNK), values)

    def _os_error(self, err: OSError) -> HttpError:
        if err.errno in _DISK_FULL:
            logger.error("no space left for %s %s (%s)", self.command, redact(self.path), errno.errorcode[err.errno])
            return HttpError(507, "the server has no space left to store this request")
        logger.exception("internal error on %s %s", self.command, redact(self.path))
        return HttpError(500, "internal server error")

    def _framing(self) -> tuple[int | None, bool]:
        """(Content-Length or None, chunked); 400 for anything ambiguous or malformed."""
        if self.headers.defects or self.headers.get_payload():
            raise HttpError(400, "malformed header line (no colon, or a space before it)")
        if any(_BAD_HEADER_VALUE.search(v) for v in self.headers.values()):
            raise HttpError(400, "header values may not be folded or hold control characters")
        lengths = self.headers.get_all("Content-Length") or []
        encodings = self.headers.get_all("Transfer-Encoding") or []
        encoding = encodings[0].strip().lower() if encodings else ""
        if (encoding not in ("", "chunked") or (encodings and lengths) or len(lengths) > 1
                or len(encodings) > 1):
            raise HttpError(400, "unsupported or ambiguous request framing (Transfer-Encoding, Content-Length)")
        if not lengths:
            return None, encoding == "chunked"
        value = lengths[0].strip(" \t")
        if not _CONTENT_LENGTH.fullmatch(value):
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

    def _body_limit(self, route: Route, anonymous: bool) -> int:
        limits = self.app.limits
        if route.body == "upload":
            return 1 << 62  # bounded by the ticket's announced size in the endpoint
        limit = limits.max_commit_bytes if route.body == "commit" else limits.max_body_bytes
        return min(limit, limits.max_anonymous_body_bytes) if anonymous else limit

    def _ticket_user(self, groups: dict[str, str]) -> str | None:
        """The user of the valid LFS upload ticket in the URL (it stands in for the token), or None."""
        if "ticket" not in groups:
            return None
        try:
            return self.app.tickets.get(groups["ticket"]).user
        except (HttpError, InputError):
            return None

    def _dispatch(self, route: Route, groups: dict[str, str], user: str | None, body: io.BufferedReader,
                  max_json_values: int) -> Response:
        parts = urlsplit(self.path)
        try:
            query = parse_qs(parts.query, keep_blank_values=True, max_num_fields=100, errors="strict")
        except (ValueError, UnicodeDecodeError):
            raise HttpError(400, "malformed query string") from None
        params = {k: v[-1] for k, v in query.items()}
        req = Request(self.command, parts.path, params, self.headers, body, user,
                      self.app.base_url(self.headers.get("Host")), groups, max_json_values)
        try:
            return route.endpoint(self.app, req)
        except StoreError as err:
            raise http_error_from_store(err, user) from None

    def _authenticate(self) -> str | None:
        if len(self.headers.get_all("Authorization") or []) > 1:
            raise HttpError(400, "more than one Authorization header; send one")
        header = self.headers.get("Authorization")
        if not header:
            return None
        scheme, _, secret = header.partition(" ")
        user = self.app.auth.user_for(secret.strip()) if scheme.lower() == "bearer" else None
        if user is None:
            raise HttpError(401, "Invalid credentials in Authorization header")
        return user

    def _error_response(self, err: HttpError) -> Response:
        message = escape_controls(err.message.encode("ascii", "backslashreplace").decode())  # latin-1, no CR/LF
        headers = {"X-Error-Message": message[:500], **err.headers}
        if err.code:
            headers["X-Error-Code"] = err.code
        return Response(err.status, {"error": err.message, **err.extra}, headers)

    def _send(self, response: Response) -> None:
        self.connection.settimeout(self.app.limits.read_timeout_s)  # reads may have left it shorter
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
        logger.info("%s %s -> %s", escape_controls(getattr(self, "command", "?")[:20]), path, code)

    def log_error(self, format: str, *args: Any) -> None:
        logger.warning("bad request from %s", self.client_address[0])

    def log_message(self, format: str, *args: Any) -> None:
        pass


def _held_bytes(route: Route, length: int | None, chunked: bool, limit: int) -> int:
    """What a request's body counts against its principal's ``max_user_body_bytes``: its
    Content-Length, a chunked one its route's limit, none for no body or an LFS upload
    (streamed to disk, never held)."""
    if route.body == "upload" or not (chunked or length):
        return 0
    return limit if chunked else length or 0


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
