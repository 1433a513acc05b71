"""Hub ids, errors and the client: what every hub operation starts from.

Everything goes through the huggingface_hub client. The endpoint and token come from
``HF_ENDPOINT`` / ``HF_TOKEN`` (read when a function runs, so they may be set after import)
unless passed explicitly; nothing names a host. Hub ids look like ``user/name[@revision]``
(``datasets/user/name[@revision]`` for datasets); a revision is a branch, a tag or a commit sha.

The hub client is split by job: ids and the API here, :mod:`msta.data.hub_cards` (model
and dataset cards), :mod:`msta.data.hub_push`, :mod:`msta.data.hub_pull` (resolve, pull,
materialize) and :mod:`msta.data.hub_versions`; ``msta-hub`` is :mod:`msta.data.hub_cli`.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

from huggingface_hub import HfApi, constants

_HUB_ID_RE = re.compile(
    r"^(?:(?P<type>datasets|models)/)?(?P<repo>[A-Za-z0-9][\w.-]*/[A-Za-z0-9][\w.-]*)(?:@(?P<rev>[^\s@]+))?$"
)


class HubError(RuntimeError):
    """A hub operation failed; the message names the repo, revision and local path involved."""


class HubIntegrityError(HubError):
    """Downloaded files do not match the hashes the hub reports."""


@dataclass(frozen=True)
class HubId:
    """A parsed ``[datasets/]user/name[@revision]``."""

    repo_id: str
    revision: str | None = None
    repo_type: str = "model"

    def __str__(self) -> str:
        prefix = "datasets/" if self.repo_type == "dataset" else ""
        return f"{prefix}{self.repo_id}" + (f"@{self.revision}" if self.revision else "")


def parse_hub_id(spec: str, repo_type: str | None = None) -> HubId:
    """Parse ``[datasets/]user/name[@revision]``.

    Args:
        spec: the hub id.
        repo_type: "model" or "dataset"; overrides the ``datasets/`` prefix when given.
    """
    m = _HUB_ID_RE.match(spec.strip())
    if m is None:
        raise ValueError(f"'{spec}' is not a hub id of the form user/name[@revision]")
    kind = repo_type or ("dataset" if m.group("type") == "datasets" else "model")
    if kind not in ("model", "dataset"):
        raise ValueError(f"repo_type must be 'model' or 'dataset', got '{kind}'")
    return HubId(m.group("repo"), m.group("rev"), kind)


def is_hub_id(value: str | os.PathLike) -> bool:
    """True when ``value`` is not an existing local path and parses as a hub id."""
    text = os.fspath(value)
    return not Path(text).exists() and _HUB_ID_RE.match(text.strip()) is not None


def endpoint_url(endpoint: str | None = None) -> str:
    """The hub URL a call goes to: ``endpoint``, else HF_ENDPOINT (read now), else
    huggingface_hub's default (huggingface.co)."""
    return (endpoint or os.environ.get("HF_ENDPOINT") or constants.ENDPOINT).rstrip("/")


def hub_api(endpoint: str | None = None, token: str | bool | None = None) -> HfApi:
    """An HfApi on ``endpoint`` (default: HF_ENDPOINT, else huggingface_hub's default).

    Args:
        endpoint: hub URL; None reads HF_ENDPOINT now.
        token: secret; None lets huggingface_hub read HF_TOKEN or its stored login; False sends none.
    """
    return HfApi(endpoint=endpoint_url(endpoint), token=token)
