"""Errors of the compensation package; each message says what the operator can do."""
from __future__ import annotations

from coordinator.errors import CoordinatorError


class CompensationError(CoordinatorError):
    """Base of every error raised by :mod:`coordinator.compensation` (bad shapes raise ``ValueError``)."""


class TransportFileError(CompensationError):
    """A stored light-transport file is missing, truncated or inconsistent."""
