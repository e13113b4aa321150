"""Errors of the compensation package; each message says what the operator can do."""
from __future__ import annotations

from imaging.errors import ImagingError


class CompensationError(ImagingError):
    """Base of every error raised by :mod:`imaging.compensation` and the compensation jobs (bad shapes raise ``ValueError``)."""


class TransportFileError(CompensationError):
    """A stored light-transport file is missing, truncated or inconsistent."""
