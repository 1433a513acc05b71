"""Connections of the hub server: deadlines on every socket read, and who may take a slot.

A slow client must not hold the server. Every read from a connection goes through
:class:`SocketInput`, which enforces the deadline of the current phase (waiting for the next
request, receiving the request line and headers, receiving the body) on each ``recv``, so a
client that sends one byte just before each read timeout is still cut off when the phase's
deadline passes. :class:`Admission` counts open connections and requests in progress, per
client address, per user and for anonymous requests, so anonymous clients can never take the
slots kept for authenticated ones, nor one user those of the others (docs/security.md,
"Limits").
"""

from __future__ import annotations

import http.client
import io
import math
import socket
import threading
import time
from collections import Counter
from dataclasses import dataclass
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


@dataclass(frozen=True)
class Refusal:
    """Why a request gets no slot: 503 (the server is full) or 429 (its sender's share is
    used), and a one-line message naming the limit."""

    status: int
    message: str


class Admission:
    """Counts open connections and requests in progress; says who may have one more.

    Requests are counted per principal: a user (a token's user, or the user whose LFS upload
    ticket a request carries) or, without either, the client's address.

    Args:
        max_open: connections open at once (waiting, sending headers or being served).
        max_open_per_client: of those, from one client address.
        max_busy: requests in progress at once (headers received until the answer is sent).
        max_anonymous: of those, requests without a valid token or upload ticket; the other
            ``max_busy - max_anonymous`` slots stay free for authenticated requests.
        max_anonymous_per_client: anonymous requests in progress from one client address.
        max_user: requests in progress of one user.
        max_user_bytes: body bytes one principal may have in progress (see ``begin``).
    """

    def __init__(self, *, max_open: int, max_open_per_client: int, max_busy: int, max_anonymous: int,
                 max_anonymous_per_client: int, max_user: int, max_user_bytes: int):
        self._lock = threading.Lock()
        self._max_open, self._max_open_per_client = max_open, max_open_per_client
        self._max_busy, self._max_anonymous = max_busy, max_anonymous
        self._max_per_address, self._max_user, self._max_bytes = max_anonymous_per_client, max_user, max_user_bytes
        self._open: Counter[str] = Counter()
        self._busy: Counter[tuple[str, str]] = Counter()  # principal -> requests in progress
        self._bytes: Counter[tuple[str, str]] = Counter()  # principal -> body bytes in progress
        self._n_open = self._n_busy = self._n_anonymous = 0

    def open(self, client: str) -> bool:
        """Take a connection slot for ``client``; False when the server or the client is full."""
        with self._lock:
            if self._n_open >= self._max_open or self._open[client] >= self._max_open_per_client:
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

    def begin(self, client: str, user: str | None, body_bytes: int) -> Refusal | None:
        """Take a request slot for ``user`` (None: anonymous, counted by ``client``'s address)
        whose body will hold up to ``body_bytes``; None when taken, else the refusal.

        The principal's share answers 429, not 503: huggingface_hub retries a file download
        and its upload calls on 429 (after ``Retry-After``), so a client with more threads
        than its share waits instead of failing. A request is never refused for its bytes
        when it is the principal's only one in progress (the size limits bound it alone)."""
        principal = ("address", client) if user is None else ("user", user)
        with self._lock:
            refusal = self._refusal(principal, body_bytes)
            if refusal is not None:
                return refusal
            self._n_busy += 1
            self._n_anonymous += user is None
            self._busy[principal] += 1
            self._bytes[principal] += body_bytes
            return None

    def _refusal(self, principal: tuple[str, str], body_bytes: int) -> Refusal | None:
        kind, who = principal
        if self._n_busy >= self._max_busy:
            return Refusal(503, f"the server is busy ({self._max_busy} requests in progress, "
                                "max_connections); retry later")
        if kind == "address" and self._n_anonymous >= self._max_anonymous:
            return Refusal(429, f"too many requests without a token in progress ({self._max_anonymous}, "
                                "max_anonymous); retry later, or pass a token")
        if kind == "address" and self._busy[principal] >= self._max_per_address:
            return Refusal(429, "too many requests without a token in progress from this address "
                                f"({self._max_per_address}, max_anonymous_per_client); retry later, or pass a token")
        if kind == "user" and self._busy[principal] >= self._max_user:
            return Refusal(429, f"too many requests of user {who} in progress ({self._max_user}, "
                                "max_user_connections); retry later")
        held = self._bytes[principal]
        if held and held + body_bytes > self._max_bytes:
            sender = f"user {who}" if kind == "user" else "this address"
            return Refusal(429, f"request bodies in progress of {sender} would exceed {self._max_bytes} bytes "
                                "(max_user_body_bytes); retry later")
        return None

    def in_progress(self, user: str) -> tuple[int, int]:
        """Requests of ``user`` in progress and the body bytes they hold."""
        with self._lock:
            return self._busy[("user", user)], self._bytes[("user", user)]

    def end(self, client: str, user: str | None, body_bytes: int) -> None:
        principal = ("address", client) if user is None else ("user", user)
        with self._lock:
            self._n_busy -= 1
            self._n_anonymous -= user is None
            for counter, n in ((self._busy, 1), (self._bytes, body_bytes)):
                counter[principal] -= n
                if counter[principal] <= 0:
                    del counter[principal]
