"""Errors the coordinator raises; each message says what the operator can do."""
from imaging.errors import ImagingError


class CoordinatorError(Exception):
    """Base of every coordinator error."""


class RigError(CoordinatorError):
    """The rig directory or one of its files is missing or invalid."""


class AssetError(CoordinatorError):
    """An asset cannot be added, found, read or removed; the message names the file or id."""


#: what the coordinator reports to an operator as one line: its own errors and the numerics'
OPERATOR_ERRORS: tuple[type[Exception], ...] = (CoordinatorError, ImagingError)
