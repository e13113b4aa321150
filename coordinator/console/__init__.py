"""The operator console: a web page served by the coordinator (see :mod:`coordinator.console.service`).

``Console`` and ``DEFAULT_LISTEN`` are imported on first use, so that the command line can use
:mod:`coordinator.console.hosts` (an argument type) without loading aiohttp.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:  # pragma: no cover - types only
    from coordinator.console.service import DEFAULT_LISTEN, Console

__all__ = ["Console", "DEFAULT_LISTEN"]


def __getattr__(name: str):
    if name in __all__:
        from coordinator.console import service
        return getattr(service, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
