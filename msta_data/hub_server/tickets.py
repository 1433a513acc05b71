"""Git LFS upload tickets: one-time, repo-bound, expiring permissions to PUT one object (issued
by the batch endpoint of :mod:`msta.data.hub_server.files`, kept in memory).
"""

from __future__ import annotations

import contextlib
import secrets
import threading
import time
from collections import OrderedDict
from collections.abc import Iterator
from dataclasses import dataclass

from msta.data.hub_server import boundary
from msta.data.hub_server.protocol import HttpError

TICKET_TTL_S = 3600.0


@dataclass(frozen=True)
class Ticket:
    """An upload the batch endpoint allowed: object, size and the repo it is for."""

    oid: str
    size: int
    repo_type: str
    repo_id: str
    expires: float


class TicketBook:
    """Upload tickets handed out by the LFS batch endpoint (kept in memory).

    A ticket allows one successful upload: ``claim`` holds it for the duration of a ``PUT``
    and keeps it marked as used when the upload succeeds (a failed upload gives it back, so a
    client may retry). A used ticket still serves ``verify``, which closes it. Every ticket
    lives ``TICKET_TTL_S`` from its issue, so tickets expire in the order they were issued:
    ``issue`` drops expired ones from the front of that order, in O(1) amortized time.
    """

    def __init__(self) -> None:
        self._tickets: OrderedDict[str, Ticket] = OrderedDict()
        self._used: set[str] = set()  # being uploaded or uploaded
        self._lock = threading.Lock()

    def issue(self, oid: str, size: int, repo_type: str, repo_id: str) -> str:
        key = secrets.token_urlsafe(32)
        with self._lock:
            now = time.monotonic()
            while self._tickets:
                first, ticket = next(iter(self._tickets.items()))
                if ticket.expires > now:
                    break
                del self._tickets[first]
                self._used.discard(first)
            self._tickets[key] = Ticket(oid, size, repo_type, repo_id, now + TICKET_TTL_S)
        return key

    def _live(self, key: str) -> Ticket:
        """The ticket ``key`` (call with the lock held); 403 when unknown or expired."""
        ticket = self._tickets.get(key)
        if ticket is None or ticket.expires < time.monotonic():
            raise HttpError(403, "upload ticket is unknown or expired; ask the batch endpoint again")
        return ticket

    def used(self, key: str) -> bool:
        """Whether an upload holds the ticket ``key`` now or has used it."""
        with self._lock:
            return key in self._used

    def get(self, key: str) -> Ticket:
        key = boundary.ticket(key)
        with self._lock:
            return self._live(key)

    @contextlib.contextmanager
    def claim(self, key: str) -> Iterator[Ticket]:
        """The ticket of one upload, held while it runs; 403 when it was used already."""
        key = boundary.ticket(key)
        with self._lock:
            ticket = self._live(key)
            if key in self._used:
                raise HttpError(403, "upload ticket was already used; ask the batch endpoint again")
            self._used.add(key)
        done = False
        try:
            yield ticket
            done = True
        finally:
            if not done:
                with self._lock:
                    self._used.discard(key)

    def close(self, key: str) -> None:
        with self._lock:
            self._tickets.pop(key, None)
            self._used.discard(key)
