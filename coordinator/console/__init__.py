"""The operator console: a web page served by the coordinator (see :mod:`coordinator.console.service`)."""
from coordinator.console.service import DEFAULT_LISTEN, Console

__all__ = ["Console", "DEFAULT_LISTEN"]
