"""The error a job raises when it cannot go on."""
from __future__ import annotations

from coordinator.errors import CoordinatorError


class JobError(CoordinatorError):
    """A job cannot go on; the message names the parameter, slot, camera or file at fault."""
