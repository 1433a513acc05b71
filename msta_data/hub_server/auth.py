"""Users, tokens and organisations of the hub server, and who may read or write what.

Rules (the same as the Hugging Face hub's for users and organisations):
- a token maps to one user; a user may be a member of organisations;
- a user writes (create, commit, tag, branch, delete) in their own namespace and in the
  namespaces of their organisations;
- public repos are readable by anyone; private repos only by those who may write them;
- a request carrying an unknown token is refused, even for public content.
"""

from __future__ import annotations

import hmac
from dataclasses import dataclass, field
from pathlib import Path


def parse_token_spec(spec: str) -> tuple[str, str]:
    """Parse ``NAME:SECRET`` into (name, secret).

    Args:
        spec: the token specification given on the command line or in a token file.
    """
    name, sep, secret = spec.partition(":")
    if not sep or not name or not secret:
        raise ValueError("token must look like NAME:SECRET (the value is not shown)")
    if len(secret) < 8:
        raise ValueError(f"token for user '{name}' is too short (need at least 8 characters)")
    return name, secret


def parse_org_spec(spec: str) -> tuple[str, list[str]]:
    """Parse ``ORG:USER1,USER2`` into (org, members)."""
    org, sep, members = spec.partition(":")
    names = [m.strip() for m in members.split(",") if m.strip()]
    if not sep or not org or not names:
        raise ValueError(f"organisation must look like ORG:USER1,USER2, got '{spec}'")
    return org, names


def read_token_file(path: str | Path) -> list[str]:
    """Token specs from a file: one ``NAME:SECRET`` a line; blank lines and ``#`` comments skipped."""
    lines = Path(path).read_text().splitlines()
    return [ln.strip() for ln in lines if ln.strip() and not ln.strip().startswith("#")]


@dataclass
class AuthConfig:
    """Users (token -> name) and organisations (org -> members)."""

    tokens: dict[str, str] = field(default_factory=dict)  # secret -> user name
    orgs: dict[str, set[str]] = field(default_factory=dict)

    @staticmethod
    def from_specs(token_specs: list[str], org_specs: list[str] | None = None) -> AuthConfig:
        """Build from ``NAME:SECRET`` and ``ORG:USER1,USER2`` strings."""
        cfg = AuthConfig()
        for spec in token_specs:
            name, secret = parse_token_spec(spec)
            if secret in cfg.tokens:
                raise ValueError(f"the same secret is given for users '{cfg.tokens[secret]}' and '{name}'")
            cfg.tokens[secret] = name
        users = set(cfg.tokens.values())
        seen: dict[str, str] = {}  # repo ids ignore case, so names must too
        for name in sorted(users):
            if seen.setdefault(name.lower(), name) != name:
                raise ValueError(f"users '{seen[name.lower()]}' and '{name}' differ only in "
                                 "case (repo ids ignore case); rename one")
        for spec in org_specs or []:
            org, members = parse_org_spec(spec)
            if org.lower() in {u.lower() for u in users}:
                raise ValueError(f"organisation '{org}' has the same name as a user (case "
                                 "ignored)")
            if seen.setdefault(org.lower(), org) != org:
                raise ValueError(f"organisations '{seen[org.lower()]}' and '{org}' differ only "
                                 "in case (repo ids ignore case); rename one")
            cfg.orgs.setdefault(org, set()).update(members)
        return cfg

    def user_for(self, secret: str) -> str | None:
        """The user owning ``secret``, compared in constant time; None when unknown."""
        found = None
        for known, user in self.tokens.items():
            if hmac.compare_digest(known.encode(), secret.encode()):
                found = user
        return found

    def orgs_of(self, user: str) -> list[str]:
        return sorted(org for org, members in self.orgs.items() if user in members)

    def can_write(self, user: str | None, namespace: str) -> bool:
        return user is not None and (namespace == user or user in self.orgs.get(namespace, set()))

    def can_read(self, user: str | None, namespace: str, private: bool) -> bool:
        return not private or self.can_write(user, namespace)
