"""The hub server: configuration, the application state and the threaded HTTP server."""

from __future__ import annotations

import logging
import sys
import threading
from http.server import ThreadingHTTPServer
from typing import Any, Self

from msta.data.hub_server import api, commit_routes, files
from msta.data.hub_server.app import HubApp, ServerConfig
from msta.data.hub_server.connections import Admission
from msta.data.hub_server.handler import HubHandler
from msta.data.hub_server.protocol import Limits

logger = logging.getLogger("msta.data.hub_server")


_BUSY = (b"HTTP/1.1 503 Service Unavailable\r\nContent-Type: application/json\r\n"
         b"Content-Length: 38\r\nConnection: close\r\n\r\n"
         b'{"error": "too many open connections"}')


class _HttpServer(ThreadingHTTPServer):
    """A threading HTTP server that caps open connections (in all and per client address),
    holds the request slots its handlers take, and logs broken connections in one line."""

    daemon_threads = True
    request_queue_size = 128  # a burst of connections waits in the kernel, not in SYN retries

    def __init__(self, address: tuple[str, int], handler: type, limits: Limits):
        self.admission = Admission(
            max_open=limits.max_open_connections, max_open_per_client=limits.max_open_per_client,
            max_busy=limits.max_connections, max_anonymous=limits.max_anonymous,
            max_anonymous_per_client=limits.max_anonymous_per_client, max_user=limits.max_user_connections,
            max_user_bytes=limits.max_user_body_bytes)
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
        self.app = HubApp(config, api.ROUTES + commit_routes.ROUTES + files.ROUTES)
        handler = type("BoundHubHandler", (HubHandler,),
                       {"app": self.app, "timeout": config.limits.read_timeout_s})
        try:
            self.httpd = _HttpServer((config.host, config.port), handler, config.limits)
        except OSError as err:  # a host that names no interface, a port in use: one line
            self.app.storage.close()
            reason = err.strerror or type(err).__name__
            raise ValueError(f"cannot listen on {config.host!r} port {config.port}: {reason}") from None
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
