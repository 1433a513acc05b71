"""The server's settings (:class:`ServerConfig`) and what every request handler shares
(:class:`HubApp`: storage, users, LFS tickets, routes). The route modules import it; it
imports none of them (the server hands it its routes).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

from msta.data.hub_server.auth import AuthConfig, read_token_file
from msta.data.hub_server.protocol import HttpError, Limits, Route
from msta.data.hub_server.storage import Storage
from msta.data.hub_server.tickets import TicketBook

_HOST = re.compile(r"(?:[A-Za-z0-9_.-]{1,253}|\[[0-9A-Fa-f:.]{2,45}\])(?::[0-9]{1,5})?")


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
    """Everything a request handler needs: storage, users, LFS tickets and routes.

    Args:
        config: the server's settings.
        routes: the endpoints, tried in order (the server passes every route module's).
    """

    def __init__(self, config: ServerConfig, routes: list[Route]):
        specs = list(config.tokens)
        if config.token_file is not None:
            specs += read_token_file(config.token_file)
        self.auth = AuthConfig.from_specs(specs, config.orgs)
        self.storage = Storage(config.root)
        self.tickets = TicketBook(config.limits.max_user_tickets, config.limits.max_tickets)
        self.limits = config.limits
        self.lfs_threshold = config.lfs_threshold
        self.public_url = config.public_url.rstrip("/") if config.public_url else None
        self.routes = list(routes)
        self.fallback_url = f"http://{config.host}:{config.port}"

    def base_url(self, host_header: str | None) -> str:
        """The URL links start with: ``public_url``, else the request's Host (400 unless it is
        a host name or address with an optional port, at most 261 characters), else the bound
        address. A Host of any length or shape would be copied into every link of an answer."""
        if self.public_url:
            return self.public_url
        if not host_header:
            return self.fallback_url
        if not _HOST.fullmatch(host_header):
            raise HttpError(400, "the Host header must be HOST or HOST:PORT (a name or an address)")
        return f"http://{host_header}"
