"""YAML front matter of README.md cards, as the hub server reads and validates it."""

from __future__ import annotations

import re

import yaml

_FRONT_MATTER = re.compile(r"\A---\s*\n(.*?)\n---\s*(?:\n|\Z)", re.DOTALL)


class CardError(ValueError):
    """The card's YAML front matter is malformed."""


def front_matter(text: str, strict: bool = False) -> dict | None:
    """The YAML mapping at the top of a card, or None when there is none.

    Args:
        text: full README.md content.
        strict: raise CardError on malformed YAML instead of returning None.
    """
    m = _FRONT_MATTER.match(text.lstrip("\ufeff"))
    if m is None:
        return None
    try:
        data = yaml.safe_load(m.group(1))
    except yaml.YAMLError as err:
        if strict:
            raise CardError(f"YAML front matter does not parse: {err}") from None
        return None
    if data is None:
        return {}
    if not isinstance(data, dict):
        if strict:
            raise CardError(f"YAML front matter must be a mapping, got {type(data).__name__}")
        return None
    return data


def validate_card(text: str, repo_type: str) -> list[str]:
    """Errors found in a card's metadata (empty list when valid)."""
    try:
        data = front_matter(text, strict=True)
    except CardError as err:
        return [str(err)]
    errors = []
    for key in ("tags", "datasets", "language"):
        value = (data or {}).get(key)
        if value is not None and not isinstance(value, (str, list)):
            errors.append(f"'{key}' must be a string or a list of strings in a {repo_type} card")
    return errors
