"""The hub server: configuration, the application state and the threaded HTTP server."""

from __future__ import annotations

import logging
import sys
import threading
from dataclasses import dataclass, field
from http.server import ThreadingHTTPServer
from pathlib import Path
from typing import Any, Self

from msta.data.hub_server import api, commit_routes, files
from msta.data.hub_server.auth import AuthConfig, read_token_file
from msta.data.hub_server.connections import Admission
from msta.data.hub_server.handler import HubHandler
from msta.data.hub_server.protocol import Limits, Route
from msta.data.hub_server.storage import Storage

logger = logging.getLogger("msta.data.hub_server")


@dataclass
class ServerConfig:
    """Settings of ``msta-hub serve``.

    Args:
        root: directory holding all repos, commits and blobs (created when missing).
        host: interface to bind; loopback unless you mean to serve a network.
        port: TCP port; 0 picks a free one.
        tokens: ``NAME:SECRET`` entries; each secret authenticates user NAME.
        token_file: file with one ``NAME:SECRET`` a line (keeps secrets out of the process list).
        orgs: ``ORG:USER1,USER2`` entries; members may write in the ORG namespace.
        lfs_threshold: files of at least this many bytes are uploaded through Git LFS; None
            keeps every upload inline ("regular"), which works with every huggingface_hub
            setting. LFS needs clients started with HF_HUB_DISABLE_XET=1.
        public_url: base URL written into links (repo URLs, LFS upload URLs); by default the
            Host header of each request.
        limits: request size, time and connection limits (see ``Limits``; docs/security.md).
    """

    root: Path
    host: str = "127.0.0.1"
    port: int = 0
    tokens: list[str] = field(default_factory=list)
    token_file: Path | None = None
    orgs: list[str] = field(default_factory=list)
    lfs_threshold: int | None = None
    public_url: str | None = None
    limits: Limits = field(default_factory=Limits)

    def __post_init__(self) -> None:
        self.root = Path(self.root)
        if not 0 <= self.port < 65536:
            raise ValueError(f"port must be in [0, 65535], got {self.port}")
        if self.lfs_threshold is not None and self.lfs_threshold < 1:
            raise ValueError(f"lfs_threshold must be a positive byte count, got {self.lfs_threshold}")


class HubApp:
    """Everything a request handler needs: storage, users, LFS tickets and routes."""

    def __init__(self, config: ServerConfig):
        specs = list(config.tokens)
        if config.token_file is not None:
            specs += read_token_file(config.token_file)
        self.auth = AuthConfig.from_specs(specs, config.orgs)
        self.storage = Storage(config.root)
        self.tickets = files.TicketBook()
        self.limits = config.limits
        self.lfs_threshold = config.lfs_threshold
        self.public_url = config.public_url.rstrip("/") if config.public_url else None
        self.routes: list[Route] = api.ROUTES + commit_routes.ROUTES + files.ROUTES
        self.fallback_url = f"http://{config.host}:{config.port}"

    def base_url(self, host_header: str | None) -> str:
        if self.public_url:
            return self.public_url
        return f"http://{host_header}" if host_header else self.fallback_url


_BUSY = (b"HTTP/1.1 503 Service Unavailable\r\nContent-Type: application/json\r\n"
         b"Content-Length: 38\r\nConnection: close\r\n\r\n"
         b'{"error": "too many open connections"}')


class _HttpServer(ThreadingHTTPServer):
    """A threading HTTP server that caps open connections (in all and per client address),
    holds the request slots its handlers take, and logs broken connections in one line."""

    daemon_threads = True
    request_queue_size = 128  # a burst of connections waits in the kernel, not in SYN retries

    def __init__(self, address: tuple[str, int], handler: type, limits: Limits):
        self.admission = Admission(limits.max_open_connections, limits.max_open_per_client,
                                   limits.max_connections, limits.max_anonymous, limits.max_anonymous_per_client)
        super().__init__(address, handler)

    def process_request(self, request: Any, client_address: Any) -> None:
        if not self.admission.open(client_address[0]):
            logger.warning("too many open connections: one from %s refused (503)", client_address[0])
            try:
                request.sendall(_BUSY)
            except OSError:
                pass
            self.shutdown_request(request)
            return
        try:
            super().process_request(request, client_address)
        except BaseException:
            self.admission.close(client_address[0])
            raise

    def process_request_thread(self, request: Any, client_address: Any) -> None:
        try:
            super().process_request_thread(request, client_address)
        finally:
            self.admission.close(client_address[0])

    def handle_error(self, request: Any, client_address: Any) -> None:
        logger.warning("connection from %s ended with %s", client_address[0], sys.exc_info()[0].__name__)


class HubServer:
    """A running hub server. Use as a context manager, or ``start()`` / ``stop()``.

    Args:
        config: the server settings.
    """

    def __init__(self, config: ServerConfig):
        self.config = config
        self.app = HubApp(config)
        handler = type("BoundHubHandler", (HubHandler,),
                       {"app": self.app, "timeout": config.limits.read_timeout_s})
        try:
            self.httpd = _HttpServer((config.host, config.port), handler, config.limits)
        except OSError:
            self.app.storage.close()
            raise
        host, port = self.httpd.server_address[:2]
        self.app.fallback_url = f"http://{host}:{port}"
        self._thread: threading.Thread | None = None

    @property
    def port(self) -> int:
        return int(self.httpd.server_address[1])

    @property
    def url(self) -> str:
        """Endpoint to give clients (HF_ENDPOINT)."""
        host = self.config.host
        host = "127.0.0.1" if host in ("0.0.0.0", "") else host
        return self.app.public_url or f"http://{host}:{self.port}"

    def start(self) -> HubServer:
        """Serve in a background thread and return immediately."""
        self._thread = threading.Thread(target=self.httpd.serve_forever, args=(0.05,), name="msta-hub", daemon=True)
        self._thread.start()
        logger.info("msta-hub serving %s on %s", self.config.root, self.url)
        return self

    def serve_forever(self) -> None:
        """Serve in this thread until interrupted (Ctrl-C), then release the root."""
        logger.info("msta-hub serving %s on %s", self.config.root, self.url)
        try:
            self.httpd.serve_forever()
        except KeyboardInterrupt:
            logger.info("msta-hub stopping")
        finally:
            self.httpd.server_close()
            self.app.storage.close()

    def stop(self) -> None:
        """Stop serving, close the socket and release the root's lock."""
        if self._thread is not None:
            self.httpd.shutdown()
            self._thread.join(timeout=10)
            self._thread = None
        self.httpd.server_close()
        self.app.storage.close()

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
