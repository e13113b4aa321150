"""Logging set-up shared by the coordinator's commands."""
from __future__ import annotations

import logging
import sys


def setup_logging(level: str = "info", *, name: str = "") -> None:
    fmt = f"%(asctime)s %(levelname)-7s {name + ' ' if name else ''}%(name)s: %(message)s"
    logging.basicConfig(level=getattr(logging, level.upper(), logging.INFO), format=fmt, stream=sys.stderr, force=True)
