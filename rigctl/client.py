"""What every operator command shares: the options that name a coordinator, and the errors that
stop a command in one line.

The connection itself is :class:`rigctl.link.Client` (gRPC); commands catch
:class:`OperatorError`, never a transport's error.
"""
from __future__ import annotations

import argparse

from coordinator.errors import CoordinatorError


class OperatorError(CoordinatorError):
    """The operator's command cannot go on: no token, no coordinator found, a refused call."""


class CallRefused(OperatorError):
    """A call the coordinator refused, or that failed on the way: ``code``, the status's name
    (``INVALID_ARGUMENT``, ``UNAVAILABLE``, ...), and ``details``, the coordinator's words ("" when
    it gave none). Its message is the details, or else the code's name."""

    def __init__(self, code: str, details: str):
        super().__init__(details or code)
        self.code, self.details = code, details


def add_connection_args(p: argparse.ArgumentParser, *, rig_dir: bool = True) -> None:
    """The options every operator command shares: which coordinator, and its token (``rig_dir``:
    with ``--rig-dir``, for commands that do not define it themselves)."""
    g = p.add_argument_group("which coordinator")
    g.add_argument("--coordinator", metavar="HOST:PORT", help="address of the coordinator (default: find it over mDNS)")
    if rig_dir:
        g.add_argument("--rig-dir", metavar="DIR", help="a rig directory on this machine: its token is used, and only "
                                                        "a coordinator of that rig (its id in rig.toml) is talked to")
    g.add_argument("--rig", metavar="NAME", help="the rig's name or id (with mDNS, only its coordinators are tried)")
    g.add_argument("--token-file", metavar="FILE", help="rig token (default: $SHADOWLESS_TOKEN_FILE or RIG_DIR/token)")
    g.add_argument("--mdns-interface", action="append", metavar="IP", help="browse mDNS on this IPv4 address only")
    g.add_argument("--tls-ca", metavar="PEM", help="use TLS, trusting this CA certificate")
    g.add_argument("--tls-server-name", metavar="NAME", help="expected name in the coordinator's certificate")
