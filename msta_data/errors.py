"""Errors raised by the msta data layer.

Every message names the offending file and/or column so a user can find the problem
without a debugger. Nothing in the data layer skips or fills bad data silently.
"""

from __future__ import annotations


class DatasetError(Exception):
    """Base class of every msta data-layer error."""


class DatasetFormatError(DatasetError, ValueError):
    """A dataset on disk does not match the expected schema (file and column named)."""


class EpisodeValidationError(DatasetError, ValueError):
    """An episode handed to the writer is malformed (column named)."""


class DatasetIntegrityError(DatasetFormatError):
    """A committed file is missing or differs from the size / sha256 recorded at commit
    (``meta/msta_checksums.json``), or ``meta/info.json`` matches no recorded commit."""


class DirectoryLockedError(RuntimeError):
    """Another process holds a directory's lock file (a dataset writer, a training run)."""


class DatasetLockedError(DatasetError, DirectoryLockedError):
    """Another writer holds the dataset's lock file."""
