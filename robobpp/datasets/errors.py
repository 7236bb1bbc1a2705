"""Errors of the datasets layer: each one names the file involved and what was expected.

They all derive from :class:`DatasetError` so a command line can turn any of them into one clear message
and a non-zero exit code without catching unrelated bugs.
"""

from __future__ import annotations


class DatasetError(Exception):
    """Base class: a data problem the user can act on (re-fetch, fix a file, pick another name)."""


class FetchError(DatasetError):
    """The packsim wheel could not be obtained (no network, pip failed, file not found)."""


class ChecksumError(DatasetError):
    """A wheel or a data file inside it is missing, truncated or altered."""


class SourceFormatError(DatasetError):
    """A data file has an unexpected layout (columns, counts, values): our reader refuses to guess."""


class CacheCorruptError(DatasetError):
    """A converted file in the data cache no longer matches its manifest."""


class SpecFileError(DatasetError):
    """An episode-set file (synthetic or private) is malformed or holds invalid boxes."""
