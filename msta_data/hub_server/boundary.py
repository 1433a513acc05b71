"""The one place where the hub server checks what a client sends: names, refs, revisions,
paths, object ids, sizes and the shapes of JSON bodies.

Every value that comes from a request and later names something on disk or in a repo passes
through a function of this module first; storage re-checks object ids before it builds a
path (``blob_path``), so nothing a client sends can name a file outside the server root.
A failed check raises :class:`InputError`, which the HTTP layer answers with its status
(400 unless said otherwise), never 500.
"""

from __future__ import annotations

import json
import json.scanner
import re
from typing import Any

SHA256_RE = re.compile(r"^[0-9a-f]{64}$")
SHA1_RE = re.compile(r"^[0-9a-f]{40}$")
SHORT_SHA_RE = re.compile(r"^[0-9a-f]{7,39}$")
TICKET_RE = re.compile(r"^[A-Za-z0-9_-]{16,128}$")
_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,95}$")
_REF_RE = re.compile(r"^[A-Za-z0-9._/-]{1,200}$")
_CONTROL_RE = re.compile(r"[\x00-\x1f\x7f]")
RESERVED_NAMESPACES = frozenset({"api", "datasets", "spaces", "models", "lfs", "resolve"})
MAX_PATH_BYTES = 4096
MAX_SEGMENT_BYTES = 255
MAX_JSON_DEPTH = 64
MAX_JSON_VALUES = 200_000  # objects, arrays, strings and numbers in one JSON body
MAX_ANONYMOUS_JSON_VALUES = 10_000  # the same for a request without a token


class InputError(ValueError):
    """A value sent by the client is malformed; answered with ``status`` (and ``code``)."""

    def __init__(self, message: str, status: int = 400, code: str | None = None):
        super().__init__(message)
        self.message = message
        self.status = status
        self.code = code


def _shown(value: object) -> str:
    """A short, printable rendering of a rejected value for error messages."""
    text = value if isinstance(value, str) else repr(value)
    return _CONTROL_RE.sub("?", text)[:120]


# ------------------------------------------------------------------ names, refs, revisions
def repo_name(namespace: object, name: object) -> tuple[str, str]:
    """``(namespace, name)`` if ``namespace/name`` is a valid repo id, else InputError."""
    for part in (namespace, name):
        if (not isinstance(part, str) or not _NAME_RE.match(part) or part.endswith(".git")
                or ".." in part):
            raise InputError(f"invalid repo id '{_shown(namespace)}/{_shown(name)}'")
    if namespace in RESERVED_NAMESPACES:
        raise InputError(f"namespace '{namespace}' is reserved")
    return namespace, name  # type: ignore[return-value]


def is_repo_name(namespace: str, name: str) -> bool:
    """Whether ``namespace/name`` passes :func:`repo_name` (for lookups that answer 404)."""
    try:
        repo_name(namespace, name)
    except InputError:
        return False
    return True


def ref_name(name: object) -> str:
    """A new branch or tag name: git's rules, and never one that reads as another ref or a sha.

    Refused: ``refs/...`` (a tag ``refs/heads/main`` would shadow the branch), ``HEAD``, 7 to 40
    lowercase hex characters (a ref named like a short sha would take over ``repo@<short sha>``
    pins), ``..``, ``//``, a leading or trailing ``/``, a part starting with ``.`` or ``-``, a
    part ending with ``.lock`` or ``.``.
    """
    if not isinstance(name, str) or not _REF_RE.match(name):
        raise InputError(f"invalid branch or tag name '{_shown(name)}'")
    if SHA1_RE.match(name) or SHORT_SHA_RE.match(name):
        raise InputError(f"invalid branch or tag name '{_shown(name)}': "
                         "7 to 40 hex characters read as a commit sha")
    parts = name.split("/")
    bad = (name.startswith("refs/") or name == "HEAD" or ".." in name
           or any(not p or p[0] in ".-" or p.endswith((".lock", ".")) for p in parts))
    if bad:
        raise InputError(f"invalid branch or tag name '{_shown(name)}'")
    return name


def revision(rev: object) -> str:
    """A revision as sent by a client (branch, tag, sha, short sha, ``refs/heads/x``,
    ``refs/tags/x``). One that no ref could be named is answered 404 RevisionNotFound."""
    if not isinstance(rev, str) or not _REF_RE.match(rev) or ".." in rev:
        raise InputError(f"Invalid rev id: {_shown(rev)}", 404, "RevisionNotFound")
    return rev


def commit_sha(value: object, what: str = "commit") -> str:
    """A full 40-hex commit id."""
    if not isinstance(value, str) or not SHA1_RE.match(value):
        raise InputError(f"{what} must be a 40-character hex commit id, got '{_shown(value)}'")
    return value


# ------------------------------------------------------------------ paths, objects, sizes
def repo_path(path: object, *, missing_is_404: bool = False) -> str:
    """A repo-relative file path: valid UTF-8 text (no lone surrogate), '/'-separated, no
    empty, '.', '..' or '.git' part, no backslash, no control character, not absolute, at most
    4096 bytes (255 a part).

    Args:
        path: the value sent by the client.
        missing_is_404: answer 404 EntryNotFound instead of 400 (read routes: such a path
            cannot exist in any repo, because every commit went through this check).
    """
    problem = _path_problem(path)
    if problem is None:
        return path  # type: ignore[return-value]
    if missing_is_404:
        raise InputError(f"Entry not found: {_shown(path)}", 404, "EntryNotFound")
    raise InputError(f"invalid path in repo '{_shown(path)}': {problem}")


def _path_problem(path: object) -> str | None:
    if not isinstance(path, str) or not path:
        return "must be a non-empty string"
    try:
        path.encode("utf-8")
    except UnicodeEncodeError:  # a lone surrogate ("\\udc80" in JSON): not text
        return "not valid UTF-8 text (a lone surrogate)"
    if len(path.encode("utf-8")) > MAX_PATH_BYTES:
        return f"longer than {MAX_PATH_BYTES} bytes"
    if _CONTROL_RE.search(path) or "\\" in path:
        return "control characters and backslashes are not allowed"
    for part in path.split("/"):
        if part in ("", ".", "..") or part.lower() == ".git":
            return "empty, '.', '..' and '.git' parts are not allowed (nor a leading '/')"
        if len(part.encode("utf-8")) > MAX_SEGMENT_BYTES:
            return f"a part is longer than {MAX_SEGMENT_BYTES} bytes"
    return None


def sha256_oid(oid: object) -> str:
    """An LFS object id: exactly 64 lowercase hex characters (a sha256)."""
    if not isinstance(oid, str) or not SHA256_RE.match(oid):
        raise InputError(f"object id must be a sha256 (64 lowercase hex characters), got '{_shown(oid)}'")
    return oid


def byte_size(value: object, what: str = "size") -> int:
    """A non-negative integer byte count (booleans are refused)."""
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise InputError(f"{what} must be a non-negative integer, got '{_shown(value)}'")
    return value


def ticket(key: object) -> str:
    """An LFS upload ticket as it appears in upload and verify URLs."""
    if not isinstance(key, str) or not TICKET_RE.match(key):
        raise InputError("upload ticket is unknown or expired; ask the batch endpoint again", 403)
    return key


# ------------------------------------------------------------------ JSON bodies
class _TooManyValues(Exception):
    pass


class _CountingDecoder(json.JSONDecoder):
    """A JSON decoder (the pure-Python scanner) that stops once it has built ``max_values``
    values, so a body of ``[{},{},...]`` costs at most that many objects before its 400."""

    def __init__(self, max_values: int):
        super().__init__()
        self.left = max_values
        for name in ("parse_object", "parse_array", "parse_string", "parse_int", "parse_float"):
            setattr(self, name, self._counted(getattr(self, name)))
        self.scan_once = json.scanner.py_make_scanner(self)

    def _counted(self, parse: Any) -> Any:
        def counted(*args: Any) -> Any:
            self.left -= 1
            if self.left < 0:
                raise _TooManyValues
            return parse(*args)
        return counted


def parse_json(raw: bytes, empty: Any = None, max_values: int = MAX_JSON_VALUES) -> Any:
    """Decode a JSON document; malformed, non-UTF-8, too deeply nested input, or one of more
    than ``max_values`` values (objects, arrays, strings, numbers) is a 400.

    The values are bounded before they are built: when the body's commas and brackets allow
    at most ``max_values`` values the C decoder runs; otherwise (commas inside strings, or
    really too many values) a counting decoder stops at the limit.
    """
    if not raw.strip():
        return {} if empty is None else empty
    try:
        if raw.count(b",") + raw.count(b"[") + raw.count(b"{") < max_values:
            value = json.loads(raw)
        else:
            value = _CountingDecoder(max_values).decode(raw.decode(json.detect_encoding(raw), "surrogatepass"))
    except _TooManyValues:
        raise InputError(f"request body holds more than {max_values} JSON values") from None
    except (ValueError, RecursionError):
        raise InputError("request body is not valid JSON") from None
    if _depth_exceeds(value, MAX_JSON_DEPTH):
        raise InputError(f"request body nests deeper than {MAX_JSON_DEPTH} levels")
    return value


def _depth_exceeds(value: Any, limit: int) -> bool:
    stack = [(value, 1)]
    while stack:
        item, depth = stack.pop()
        if depth > limit:
            return True
        if isinstance(item, dict):
            stack.extend((v, depth + 1) for v in item.values())
        elif isinstance(item, list):
            stack.extend((v, depth + 1) for v in item)
    return False


def json_object(value: Any, what: str = "request body") -> dict[str, Any]:
    """``value`` if it is a JSON object, else InputError."""
    if not isinstance(value, dict):
        raise InputError(f"{what} must be a JSON object, got {type(value).__name__}")
    return value


_MISSING = object()


def field(data: dict[str, Any], key: str, kind: type | tuple[type, ...], default: Any = _MISSING) -> Any:
    """``data[key]`` checked against ``kind`` (``None`` counts as absent when a default is given).

    Args:
        data: a JSON object from the request.
        key: the field name.
        kind: accepted Python type(s); ``bool`` is never accepted where ``int`` is asked.
        default: returned when the field is absent or null; without it the field is required.
    """
    value = data.get(key)
    if value is None:
        if default is _MISSING:
            raise InputError(f"missing '{key}' in request body")
        return default
    kinds = kind if isinstance(kind, tuple) else (kind,)
    if not isinstance(value, kinds) or (isinstance(value, bool) and bool not in kinds):
        names = " or ".join(k.__name__ for k in kinds)
        raise InputError(f"'{key}' must be {names}, got {type(value).__name__}")
    return value
