"""Connections of the hub server: deadlines on every socket read, and who may take a slot.

A slow client must not hold the server. Every read from a connection goes through
:class:`SocketInput`, which enforces the deadline of the current phase (waiting for the next
request, receiving the request line and headers, receiving the body) on each ``recv``, so a
client that sends one byte just before each read timeout is still cut off when the phase's
deadline passes. :class:`Admission` counts open connections and requests in progress, per
client address and for anonymous requests, so anonymous clients can never take the slots
kept for authenticated ones (docs/security.md, "Limits").
"""

from __future__ import annotations

import http.client
import io
import math
import socket
import threading
import time
from collections import Counter
from typing import Any

MAX_HEADER_BYTES = 64 << 10  # request line and headers of one request


class HeadersTooLarge(http.client.HTTPException):
    """The request line and headers together are longer than ``MAX_HEADER_BYTES``."""


class SocketInput(io.RawIOBase):
    """A connection's input with a deadline and, while headers are read, a byte budget.

    Args:
        sock: the connected socket.
        read_timeout_s: longest wait for a single ``recv`` (``Limits.read_timeout_s``).
    """

    def __init__(self, sock: socket.socket, read_timeout_s: float):
        super().__init__()
        self._sock = sock
        self._read_timeout_s = read_timeout_s
        self.deadline = math.inf  # time.monotonic() after which reads fail with TimeoutError
        self.budget = math.inf  # bytes that may still be received in this phase
        self.phase = "idle"

    def start(self, phase: str, seconds: float, budget: float = math.inf) -> None:
        """Begin a phase ("idle", "headers", "body") that must end within ``seconds``."""
        self.phase = phase
        self.deadline = time.monotonic() + seconds
        self.budget = budget

    def readable(self) -> bool:
        return True

    def fileno(self) -> int:
        return self._sock.fileno()

    def readinto(self, buffer: Any) -> int:
        left = self.deadline - time.monotonic()
        if left <= 0:
            raise TimeoutError(f"{self.phase} not received in time")
        if self.budget <= 0:
            raise HeadersTooLarge(f"request headers are longer than {MAX_HEADER_BYTES} bytes")
        self._sock.settimeout(min(left, self._read_timeout_s))
        n = self._sock.recv_into(buffer)
        self.budget -= n
        return n


class Admission:
    """Counts open connections and requests in progress; says who may have one more.

    Args:
        max_open: connections open at once (waiting, sending headers or being served).
        max_open_per_client: of those, from one client address.
        max_busy: requests in progress at once (headers received until the answer is sent).
        max_anonymous: of those, requests without a valid token or upload ticket; the other
            ``max_busy - max_anonymous`` slots stay free for authenticated requests.
        max_anonymous_per_client: anonymous requests in progress from one client address.
    """

    def __init__(self, max_open: int, max_open_per_client: int, max_busy: int, max_anonymous: int,
                 max_anonymous_per_client: int):
        self._lock = threading.Lock()
        self._limits = (max_open, max_open_per_client, max_busy, max_anonymous, max_anonymous_per_client)
        self._open: Counter[str] = Counter()
        self._anonymous: Counter[str] = Counter()
        self._n_open = self._n_busy = self._n_anonymous = 0

    def open(self, client: str) -> bool:
        """Take a connection slot for ``client``; False when the server or the client is full."""
        max_open, per_client = self._limits[:2]
        with self._lock:
            if self._n_open >= max_open or self._open[client] >= per_client:
                return False
            self._n_open += 1
            self._open[client] += 1
            return True

    def close(self, client: str) -> None:
        with self._lock:
            self._n_open -= 1
            self._open[client] -= 1
            if self._open[client] <= 0:
                del self._open[client]

    def begin(self, client: str, anonymous: bool) -> int | None:
        """Take a request slot: None when taken, else the status of the refusal: 503 when
        the server has no slot left, 429 when the anonymous share (in all or of ``client``)
        is used. huggingface_hub retries a file download on 429, not on 503, so a client
        downloading with more threads than its share waits instead of failing."""
        _, _, max_busy, max_anonymous, per_client = self._limits
        with self._lock:
            if self._n_busy >= max_busy:
                return 503
            if anonymous:
                if self._n_anonymous >= max_anonymous or self._anonymous[client] >= per_client:
                    return 429
                self._n_anonymous += 1
                self._anonymous[client] += 1
            self._n_busy += 1
            return None

    def end(self, client: str, anonymous: bool) -> None:
        with self._lock:
            self._n_busy -= 1
            if anonymous:
                self._n_anonymous -= 1
                self._anonymous[client] -= 1
                if self._anonymous[client] <= 0:
                    del self._anonymous[client]
