"""Git LFS upload tickets: one-time, repo-bound, expiring permissions to PUT one object (issued
by the batch endpoint of :mod:`msta.data.hub_server.files`, kept in memory).
"""

from __future__ import annotations

import contextlib
import secrets
import threading
import time
from collections import Counter, OrderedDict
from collections.abc import Iterator
from dataclasses import dataclass

from msta.data.hub_server import boundary
from msta.data.hub_server.protocol import HttpError

TICKET_TTL_S = 3600.0


@dataclass(frozen=True, slots=True)
class Ticket:
    """An upload the batch endpoint allowed: object, size, the repo it is for and the user
    who asked (the upload counts against that user's request slots)."""

    oid: str
    size: int
    repo_type: str
    repo_id: str
    user: str
    expires: float


class TicketBook:
    """Upload tickets handed out by the LFS batch endpoint (kept in memory, bounded).

    A ticket allows one successful upload: ``claim`` holds it for the duration of a ``PUT``
    and keeps it marked as used when the upload succeeds (a failed upload gives it back, so a
    client may retry). A used ticket still serves ``verify``, which closes it. Every ticket
    lives ``TICKET_TTL_S`` from its issue, so tickets expire in the order they were issued:
    ``issue`` drops expired ones from the front of that order, in O(1) amortized time. Open
    tickets are counted per user and in all; a batch that would pass either cap gets none.

    Args:
        max_per_user: open tickets of one user (429 beyond: ``Limits.max_user_tickets``).
        max_total: open tickets in all (503 beyond: ``Limits.max_tickets``).
    """

    def __init__(self, max_per_user: int, max_total: int) -> None:
        self._tickets: OrderedDict[str, Ticket] = OrderedDict()
        self._used: set[str] = set()  # being uploaded or uploaded
        self._per_user: Counter[str] = Counter()
        self._max_per_user, self._max_total = max_per_user, max_total
        self._lock = threading.Lock()

    def issue(self, objects: list[tuple[str, int]], repo_type: str, repo_id: str, user: str) -> list[str]:
        """One ticket for each ``(oid, size)`` of a batch, or none: 429 when ``user`` would
        hold more than its cap, 503 when the server would."""
        keys = [secrets.token_urlsafe(32) for _ in objects]
        with self._lock:
            now = time.monotonic()
            while self._tickets:
                first, ticket = next(iter(self._tickets.items()))
                if ticket.expires > now:
                    break
                self._drop(first)
            if self._per_user[user] + len(objects) > self._max_per_user:
                raise HttpError(429, f"user {user} holds {self._per_user[user]} open LFS upload tickets and may "
                                     f"hold {self._max_per_user} (max_user_tickets); finish those uploads or "
                                     "wait for them to expire", headers={"Retry-After": "1"})
            if len(self._tickets) + len(objects) > self._max_total:
                raise HttpError(503, f"the server holds {len(self._tickets)} open LFS upload tickets and may hold "
                                     f"{self._max_total} (max_tickets); retry later", headers={"Retry-After": "1"})
            for key, (oid, size) in zip(keys, objects, strict=True):
                self._tickets[key] = Ticket(oid, size, repo_type, repo_id, user, now + TICKET_TTL_S)
            self._per_user[user] += len(objects)
        return keys

    def _drop(self, key: str) -> None:
        """Forget the ticket ``key`` (call with the lock held)."""
        ticket = self._tickets.pop(key, None)
        self._used.discard(key)
        if ticket is not None:
            self._per_user[ticket.user] -= 1
            if self._per_user[ticket.user] <= 0:
                del self._per_user[ticket.user]

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
            self._drop(key)
