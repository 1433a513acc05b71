"""YAML front matter of README.md cards, as the hub server reads and validates it.

Cards come from anyone who may write a repo, validate-yaml takes them from anyone, and they are
answered to anyone who may read the repo, so the YAML is loaded with limits that this module
owns (they do not depend on how a PyYAML version builds merges or aliases):

- the front matter is at most ``max_bytes`` long (default 1 MiB);
- before any node is built, the parser's event stream (constant memory) is counted: the
  document may hold at most ``MAX_NODES`` nodes *once every alias and merge key (``<<``) is
  expanded*, so neither a "billion laughs" of nested aliases nor a merge-key bomb gets
  further than this count;
- it is then loaded with PyYAML's safe loader (libyaml when present: nesting deeper than
  1000 levels is refused), at most ``PARSERS`` cards at a time for anonymous requests and as
  many for authenticated ones (the work is CPU-bound, so this costs no throughput and bounds
  the memory of parallel requests; a user's card never waits behind anonymous ones);
- the loaded value must stay small once aliases are expanded (at most ``EXPANSION_FACTOR``
  times the front matter's size, no alias cycles, at most ``MAX_DEPTH`` levels).

Values YAML builds that JSON cannot hold (dates, binary, sets) are turned into strings or lists.
"""

from __future__ import annotations

import base64
import datetime
import math
import re
import threading
from typing import Any

import yaml

_FRONT_MATTER = re.compile(r"\A---[ \t]*\r?\n(.*?)\r?\n---[ \t]*(?:\r?\n|\Z)", re.DOTALL)
_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
MAX_CARD_BYTES = 1 << 20
EXPANSION_FACTOR = 4
MAX_DEPTH = 100
MAX_NODES = 100_000
PARSERS = 2
#: anonymous request -> its parser slots (separate, so users never queue behind anonymous cards)
_PARSING = {True: threading.BoundedSemaphore(PARSERS), False: threading.BoundedSemaphore(PARSERS)}


class CardError(ValueError):
    """The card's YAML front matter is malformed or too large."""


def front_matter(text: str, strict: bool = False, max_bytes: int = MAX_CARD_BYTES, *,
                 anonymous: bool = True) -> dict | None:
    """The YAML mapping at the top of a card as JSON-ready data, or None when there is none.

    Args:
        text: README.md content (its first ``max_bytes`` bytes and a little more suffice).
        strict: raise CardError on malformed or oversized YAML instead of returning None.
        max_bytes: longest front matter accepted, in bytes of UTF-8.
        anonymous: parsed for a request without a token (it takes an anonymous parser slot).
    """
    try:
        return _front_matter(text, max_bytes, anonymous)
    except CardError:
        if strict:
            raise
        return None


def _front_matter(text: str, max_bytes: int, anonymous: bool) -> dict | None:
    m = _FRONT_MATTER.match(text.lstrip("\ufeff"))
    if m is None:
        return None
    source = m.group(1)
    size = len(source.encode("utf-8", "surrogatepass"))
    if size > max_bytes:
        raise CardError(f"YAML front matter is {size} bytes; this server accepts at most {max_bytes}")
    try:
        _count_nodes(source)
        with _PARSING[anonymous]:
            data = yaml.load(source, Loader=_LOADER)
    except CardError:
        raise
    except (yaml.YAMLError, ValueError, TypeError, RecursionError) as err:
        raise CardError(f"YAML front matter does not parse: {str(err)[:300]}") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise CardError(f"YAML front matter must be a mapping, got {type(data).__name__}")
    budget = _Budget(max(EXPANSION_FACTOR * max(size, 1024), 1024))
    return budget.convert(data)


def _count_nodes(source: str) -> None:
    """Refuse YAML whose node count, with every alias and merge expanded, exceeds MAX_NODES.

    Reads the parser's events one by one (nothing is built): each collection's expanded size
    is summed as it closes and remembered under its anchor, so an alias (also one used as a
    merge key's value) counts as the size of what it names.
    """
    sizes: dict[str, int] = {}  # anchor -> expanded node count
    open_: list[list[Any]] = [[None, 0]]  # [anchor, expanded nodes so far] of each open collection
    total = 0
    for event in yaml.parse(source, Loader=_LOADER):
        if isinstance(event, (yaml.ScalarEvent, yaml.AliasEvent)):
            n = sizes.get(event.anchor, 1) if isinstance(event, yaml.AliasEvent) else 1
            if isinstance(event, yaml.ScalarEvent) and event.anchor:
                sizes[event.anchor] = 1
            open_[-1][1] += n
            total += n
        elif isinstance(event, yaml.CollectionStartEvent):
            open_.append([event.anchor, 1])
            total += 1
        elif isinstance(event, yaml.CollectionEndEvent) and len(open_) > 1:
            anchor, n = open_.pop()
            if anchor:
                sizes[anchor] = n
            open_[-1][1] += n
        if total > MAX_NODES:
            raise CardError(f"YAML front matter holds more than {MAX_NODES} nodes once its aliases "
                            "and merge keys are expanded")


class _Budget:
    """Converts loaded YAML to JSON-ready data while counting its expanded size."""

    def __init__(self, limit: int):
        self.limit = limit
        self.used = 0
        self._active: list[int] = []

    def _spend(self, n: int) -> None:
        self.used += n
        if self.used > self.limit:
            raise CardError(f"YAML front matter expands to more than {self.limit} bytes (aliases?)")

    def convert(self, value: Any) -> Any:
        if isinstance(value, (dict, list, set, tuple)):
            if id(value) in self._active:
                raise CardError("YAML front matter refers to itself (alias cycle)")
            if len(self._active) >= MAX_DEPTH:
                raise CardError(f"YAML front matter nests deeper than {MAX_DEPTH} levels")
            self._active.append(id(value))
            try:
                return self._container(value)
            finally:
                self._active.pop()
        return self._scalar(value)

    def _container(self, value: dict | list | set | tuple) -> Any:
        self._spend(2)
        if isinstance(value, dict):
            out = {}
            for k, v in value.items():
                key = k if isinstance(k, str) else str(self._scalar(k))
                self._spend(len(key) + 4)
                out[key] = self.convert(v)
            return out
        items = sorted(value, key=str) if isinstance(value, set) else value
        return [self.convert(v) for v in items]

    def _scalar(self, value: Any) -> Any:
        if isinstance(value, float) and not math.isfinite(value):
            value = None
        elif isinstance(value, (datetime.date, datetime.datetime)):
            value = value.isoformat()
        elif isinstance(value, bytes):
            value = base64.b64encode(value).decode()
        elif not isinstance(value, (str, int, float, bool, type(None))):
            value = str(value)
        self._spend(len(value) + 2 if isinstance(value, str) else 8)
        return value


def validate_card(text: str, repo_type: str, max_bytes: int = MAX_CARD_BYTES, *,
                  anonymous: bool = True) -> list[str]:
    """Errors found in a card's metadata (empty list when valid); ``anonymous`` as for
    :func:`front_matter`."""
    try:
        data = front_matter(text, strict=True, max_bytes=max_bytes, anonymous=anonymous)
    except CardError as err:
        return [str(err)]
    errors = []
    for key in ("tags", "datasets", "language"):
        value = (data or {}).get(key)
        if value is not None and not isinstance(value, (str, list)):
            errors.append(f"'{key}' must be a string or a list of strings in a {repo_type} card")
    return errors


def card_tags(card: dict | None) -> list[str]:
    """The card's ``tags`` as a list of strings (a single string becomes a one-item list)."""
    tags = (card or {}).get("tags")
    if isinstance(tags, str):
        return [tags]
    if isinstance(tags, list):
        return [t for t in tags if isinstance(t, str)]
    return []
