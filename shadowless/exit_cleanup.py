"""Children a process started are stopped when it ends, however it ends short of SIGKILL.

`shadowless local`, the demo and the tests start coordinators, nodes and rooms in sessions of
their own (so a terminal's Ctrl-C reaches only the parent, which stops them in order). If the
parent is then terminated (SIGTERM, SIGHUP: a CI timeout, a closed terminal, a service stop), no
``finally`` runs and the children would live on, orphaned. :func:`register` adds a closer that
runs at interpreter exit and on SIGTERM/SIGHUP (installed from the main thread, and only over the
default handler, so a command with handlers of its own keeps them); then the process dies of the
signal as it would have. The venue network (:mod:`shadowless.netns`) has its own, older, net of
the same kind for its namespaces.
"""
from __future__ import annotations

import atexit
import os
import signal
import threading
from collections.abc import Callable

__all__ = ["register", "unregister"]

_CLOSERS: list[Callable[[], None]] = []
_AT_EXIT = False
_ON_SIGNALS = False
_LOCK = threading.Lock()


def _close_all() -> None:
    with _LOCK:
        closers = list(reversed(_CLOSERS))
        _CLOSERS.clear()
    for close in closers:
        try:
            close()
        except Exception:   # noqa: BLE001 - best effort on the way out
            pass


def _on_signal(signum, frame) -> None:
    _close_all()
    signal.signal(signum, signal.SIG_DFL)     # then die of the signal, as without us
    os.kill(os.getpid(), signum)


def register(close: Callable[[], None]) -> None:
    """Run ``close()`` at exit or on SIGTERM/SIGHUP unless :func:`unregister` came first."""
    global _AT_EXIT, _ON_SIGNALS
    with _LOCK:
        if close not in _CLOSERS:
            _CLOSERS.append(close)
        at_exit, _AT_EXIT = not _AT_EXIT, True
        # signal handlers can only be set from the main thread: a first registration from another
        # thread (a rig started by a worker) leaves them to the next one from the main thread
        on_signals = not _ON_SIGNALS and threading.current_thread() is threading.main_thread()
        _ON_SIGNALS = _ON_SIGNALS or on_signals
    if at_exit:
        atexit.register(_close_all)
    if on_signals:
        for sig in (signal.SIGTERM, signal.SIGHUP):
            if signal.getsignal(sig) == signal.SIG_DFL:
                signal.signal(sig, _on_signal)


def unregister(close: Callable[[], None]) -> None:
    """Forget ``close`` (it ran, or its owner closed otherwise)."""
    with _LOCK:
        if close in _CLOSERS:
            _CLOSERS.remove(close)
