"""Errors the coordinator raises; each message says what the operator can do.

:class:`Refusal` is a call the rig refuses, with a :class:`RefusalKind` that says why in terms
of the rig, not of a transport: the gRPC edge maps each kind to a status code and the console
maps it to an HTTP status, each in one table of its own.
"""
from __future__ import annotations

import enum

from imaging.errors import ImagingError


class CoordinatorError(Exception):
    """Base of every coordinator error."""


class RigError(CoordinatorError):
    """The rig directory or one of its files is missing or invalid."""


class AssetError(CoordinatorError):
    """An asset cannot be added, found, read or removed; the message names the file or id."""


class RefusalKind(enum.Enum):
    """Why the rig refuses a call."""

    INVALID = "invalid"                          # the request itself is malformed
    NOT_FOUND = "not found"                      # it names something the rig does not have
    CONFLICT = "conflict"                        # what it would create exists (a slot a live node holds)
    UNAUTHENTICATED = "unauthenticated"          # no proof of the rig token, or no live session
    FAILED_PRECONDITION = "failed precondition"  # the rig's state refuses it now (a version mismatch)
    RESOURCE_EXHAUSTED = "resource exhausted"    # over a budget (calls before authentication)
    DEADLINE_EXCEEDED = "deadline exceeded"      # the caller took too long (to send its message)
    UNAVAILABLE = "unavailable"                  # something the call needs cannot be reached now


class Refusal(CoordinatorError):
    """A call the rig refuses: its :class:`RefusalKind` and a message the caller can act on."""

    def __init__(self, kind: RefusalKind, message: str):
        super().__init__(message)
        self.kind, self.message = kind, message


#: what the coordinator reports to an operator as one line: its own errors and the numerics'
OPERATOR_ERRORS: tuple[type[Exception], ...] = (CoordinatorError, ImagingError)
