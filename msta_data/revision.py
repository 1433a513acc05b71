"""One content hash for "which version is this": teachers, checkpoints and student weights.

A checkpoint *directory* is named by :func:`checkpoint_revision` (its files: msta-eval's
entries, the model card's eval match); a student's *weights* in memory by
:func:`msta.policies.checkpoint.weights_revision` (stage 2's provenance of the episodes a
student drove, before any checkpoint is written); a teacher by
:func:`msta.policies.teacher.config.teacher_revision`.

A revision is the first 12 hex digits of a sha256 over a sequence of parts, with an
optional ``<prefix>-`` (the policy or teacher type). Datasets record it per episode
(``provenance/policy_revision``) and msta-eval per entry, so equal content gives an equal
revision in every process. Dataset *files* are checked with full sha256 digests instead
(:mod:`msta.data.integrity`).
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable, Iterator
from pathlib import Path

#: Hex digits kept.
REVISION_LENGTH = 12


def file_parts(path: str | Path) -> Iterator[bytes]:
    """Name and bytes of every file under ``path`` (sorted; names relative to ``path``), or
    of ``path`` itself (its file name) when it is a file.

    Args:
        path: a file or a directory.
    """
    path = Path(path)
    if path.is_file():
        yield path.name.encode()
        yield path.read_bytes()
        return
    for f in sorted(path.rglob("*")):
        if f.is_file():
            yield f.relative_to(path).as_posix().encode()
            yield f.read_bytes()


def content_revision(parts: Iterable[bytes | str], prefix: str = "") -> str:
    """``[<prefix>-]<12 hex>``: sha256 over ``parts`` in order (``str`` parts UTF-8 encoded).

    Args:
        parts: what identifies the content (names, bytes, a JSON dump), in a fixed order.
        prefix: prepended with a dash (a teacher or policy type); none when empty.
    """
    h = hashlib.sha256()
    for part in parts:
        h.update(part.encode() if isinstance(part, str) else part)
    digest = h.hexdigest()[:REVISION_LENGTH]
    return f"{prefix}-{digest}" if prefix else digest


def checkpoint_revision(path: str | Path) -> str:
    """The revision of a checkpoint directory (or file): :func:`content_revision` over its
    :func:`file_parts`."""
    return content_revision(file_parts(path))
