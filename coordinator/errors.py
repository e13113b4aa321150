"""Errors the coordinator raises; each message says what the operator can do."""


class CoordinatorError(Exception):
    """Base of every coordinator error."""


class RigError(CoordinatorError):
    """The rig directory or one of its files is missing or invalid."""


class AssetError(CoordinatorError):
    """An asset cannot be added, found, read or removed; the message names the file or id."""
