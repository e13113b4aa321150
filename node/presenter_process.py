"""The presenter's own process, and the node process's handle on it.

Why a process: the swap is a real-time deadline, and a Python thread that
wakes on time still needs the GIL. If the network thread held it and was then
descheduled on a busy machine, the swap would wait for it (tens of ms were
measured with 16 nodes on 2 cores). Alone in its process, the presenter's
single thread never waits for anyone's GIL.

Both directions are pipes of ``(kind, payload)`` tuples of plain data: in, what
:meth:`node.presenter.Presenter.handle` takes (the show's timeline and an asset's file
paths included: the presenter decodes the asset's frames itself, so decoded frames never
cross the pipe; an assignment crosses as its bytes, :class:`node.records.AssignmentBytes`, which
:class:`Inbox` decodes here: the node process holds no array and imports no numpy); out,
``("ready", (size, gl_info))``, ``("failed", text)``, ``("stats", PresenterStatus)``, ``("swap", SwapRecord)``,
``("drop", DropRecord)``, ``("preview", PreviewRecord)`` (a console thumbnail, when asked) and
``("alive", None)`` (every second while its loop runs).

The process is started as ``python -c ...`` with the two pipes' ends passed as file descriptors
(:func:`child_main`), not through :mod:`multiprocessing`'s spawn: that also starts its resource
tracker, a third Python process per node (13 MB resident) that the presenter never uses. The
settings are the pipe's first message. When the node process ends, however it ends, its end of
the pipe closes and the presenter's loop stops (EOF), as a daemon process of :mod:`multiprocessing`
did.
"""
from __future__ import annotations

import fcntl
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from collections import Counter, deque
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Callable

from node.clock import LocalClock, precise_timers
from node.records import AssignmentBytes, DropRecord, PresenterStatus, PreviewRecord, SwapRecord
from node.wire import assignment_from_bytes
from protos import logging_setup

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class PresenterSettings:
    slot: str
    output_spec: str
    clock_offset_ns: int
    clock_drift_ppm: float
    clock_anchor_ns: int
    snapshot_dir: Path | None = None
    realtime: bool = True
    log_level: int = logging.INFO
    log_name: str = "node"


#: how often the presenter's loop says it is alive (whatever else it sends)
ALIVE_EVERY_S = 1.0


class Inbox:
    """The presenter process's end of the pipe in (``poll(timeout_s) -> bool``, ``recv() -> (kind,
    payload)``, as :attr:`node.presenter.Presenter.inbox` reads it), with each assignment that
    crosses as its bytes (:class:`node.records.AssignmentBytes`) decoded into the
    :class:`node.records.NodeAssignment` the presenter takes (:func:`node.wire.assignment_from_bytes`);
    a malformed one (the node process refuses them before: :attr:`node.records.AssignmentBytes.problem`)
    is logged and skipped. Every other message, and an assignment already decoded
    (a test's), passes as it is. The end of the pipe (EOFError) is raised by the :meth:`recv` after
    a :meth:`poll` that saw it, as a :class:`~multiprocessing.connection.Connection` does."""

    def __init__(self, conn: Connection):
        self._conn = conn
        self._ready: deque = deque()      # messages read and decoded, not yet received
        self._gone: BaseException | None = None

    def poll(self, timeout: float | None = 0.0) -> bool:
        """Whether :meth:`recv` returns at once (a message, or the pipe's end), waiting up to ``timeout`` s
        (None: until it does)."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while not self._ready and self._gone is None:
            if not self._conn.poll(None if deadline is None else max(0.0, deadline - time.monotonic())):
                return False
            try:
                self._take(self._conn.recv())
            except (EOFError, OSError) as exc:
                self._gone = exc
        return True

    def recv(self):
        while not self._ready:
            if self._gone is not None:
                raise self._gone
            self._take(self._conn.recv())
        return self._ready.popleft()

    def _take(self, msg) -> None:
        kind, payload = msg
        if kind == "assignment" and isinstance(payload, AssignmentBytes):
            try:
                payload = assignment_from_bytes(payload)
            except ValueError as exc:
                log.error("ignoring a malformed assignment r%d: %s", payload.revision, exc)
                return
            msg = (kind, payload)
        self._ready.append(msg)


def tune_process() -> None:
    """Let sleeps end close to their deadline (1 µs timer slack)."""
    precise_timers()


def presenter_main(conn_in, conn_out, settings: PresenterSettings) -> None:
    """Entry point of the presenter process."""
    # only this process renders and decodes: the node process, which imports this module to
    # start it, does not pay for the renderer, the outputs and PyAV at its start
    from node.outputs import open_output
    from node.presenter import Presenter

    signal.signal(signal.SIGINT, signal.SIG_IGN)   # the node process decides when we stop
    logging_setup.setup(settings.log_level, name=settings.log_name)
    tune_process()
    clock = LocalClock(offset_ns=settings.clock_offset_ns, drift_ppm=settings.clock_drift_ppm,
                       anchor_ns=settings.clock_anchor_ns)

    def report(kind: str, payload) -> None:
        conn_out.send((kind, payload))

    try:
        out = open_output(settings.output_spec, slot=settings.slot, snapshot_dir=settings.snapshot_dir)
        p = Presenter(slot=settings.slot, output=out, clock=clock, report=report, realtime=settings.realtime)
        p.open()
        p.inbox = conn_in         # blend switches reach a frame that waits for its time (Presenter.inbox)
    except Exception as exc:
        log.exception("cannot open output %r", settings.output_spec)
        conn_out.send(("failed", f"{type(exc).__name__}: {exc}"))
        return
    conn_out.send(("ready", (p.native_size, p.gl_info)))
    alive_at = time.monotonic()
    try:
        while True:
            now = time.monotonic()
            if now - alive_at >= ALIVE_EVERY_S:     # for the node's systemd watchdog (node.systemd)
                conn_out.send(("alive", None))
                alive_at = now
            # messages first (those read while a frame waited for its time before the pipe's); the
            # show's timeline is followed between them (see Presenter.timeline_wait)
            kept = p.next_deferred()
            if kept is not None:
                if kept[0] == "stop":
                    break
                p.handle(*kept)
                continue
            wait = p.timeline_wait()
            if not conn_in.poll(0.5 if wait is None else min(wait, 0.5)):
                if wait is not None and wait <= 0.5:    # its time came (else: idle, and ask again)
                    p.timeline_step()
                else:
                    p.idle()
                continue
            try:
                kind, payload = conn_in.recv()
            except EOFError:   # the node process is gone
                break
            if kind == "stop":
                break
            p.handle(kind, payload)
    except Exception as exc:
        log.exception("presenter failed")
        try:
            conn_out.send(("failed", f"{type(exc).__name__}: {exc}"))
        except OSError:
            pass
    finally:
        p.close()


#: a directory: each presenter process writes a cProfile of its life there (its main thread's CPU
#: time, ``presenter-<slot>-<pid>.prof``) when its loop ends; unset (the default), nothing is profiled
PROFILE_ENV = "SHADOWLESS_PROFILE_DIR"


def child_main() -> None:
    """The presenter process's entry point: ``python -c`` calls it with its two pipe ends'
    descriptors (in, out) as arguments; the settings are the first message in."""
    fd_in, fd_out = (int(v) for v in sys.argv[1:3])
    pipe_in, conn_out = Connection(fd_in, writable=False), Connection(fd_out, readable=False)
    try:
        settings = pipe_in.recv()
    except EOFError:     # the node process is gone
        return
    conn_in = Inbox(pipe_in)
    where = os.environ.get(PROFILE_ENV)
    if not where:
        presenter_main(conn_in, conn_out, settings)
        return
    import cProfile
    prof = cProfile.Profile(time.thread_time)      # CPU time of this (main) thread: waits count nothing
    prof.enable()
    try:
        presenter_main(conn_in, conn_out, settings)
    finally:
        prof.disable()
        prof.dump_stats(str(Path(where) / f"presenter-{settings.slot}-{os.getpid()}.prof"))


def _grow_pipe(fd: int, want: int = 8 * 2**20) -> None:
    """Make a pipe's kernel buffer as large as allowed (default 64 KiB holds one small frame)."""
    try:
        limit = int(Path("/proc/sys/fs/pipe-max-size").read_text())
        F_SETPIPE_SZ = getattr(fcntl, "F_SETPIPE_SZ", 1031)
        fcntl.fcntl(fd, F_SETPIPE_SZ, min(want, limit) if os.geteuid() else want)
    except (OSError, ValueError):  # pragma: no cover - not Linux, or not permitted
        pass


class PresenterProcess:
    """The node process's handle on its presenter process.

    :meth:`submit` writes to a pipe with a large kernel buffer (no thread, so no
    GIL contention in the node process); reports arrive on the event loop
    through :meth:`attach`.
    """

    def __init__(self, settings: PresenterSettings):
        from multiprocessing import Pipe

        child_in, self._to_child = Pipe(duplex=False)      # (reader, writer)
        self._from_child, child_out = Pipe(duplex=False)
        self._settings = settings
        self._process: subprocess.Popen | None = None
        self._child_ends = (child_in, child_out)
        _grow_pipe(self._to_child.fileno())
        _grow_pipe(self._from_child.fileno())   # the presenter's reports never wait for the (lower-priority) node side
        self.native_size: tuple[int, int] | None = None
        self.gl_info = ""            # what the presenter renders with, once ready
        self.failed: str | None = None
        self.stats = PresenterStatus()
        self._ready = threading.Event()
        self._on_report: Callable[[SwapRecord | DropRecord | PreviewRecord], None] | None = None
        #: called when the presenter's stats name other blend maps on screen (the node's heartbeat goes at once)
        self.on_blend_change: Callable[[], None] | None = None
        self._alive_at = time.monotonic()
        #: messages received from the presenter, by kind ("stats", "swap", "alive", ...)
        self.received: Counter[str] = Counter()

    def start(self) -> None:
        child_in, child_out = self._child_ends
        # the node's own package first on the path, wherever the node process was started from
        root = str(Path(__file__).resolve().parent.parent)
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in (root, os.environ.get("PYTHONPATH")) if p))
        self._process = subprocess.Popen(
            [sys.executable, "-c", "from node.presenter_process import child_main; child_main()",
             str(child_in.fileno()), str(child_out.fileno())],
            pass_fds=(child_in.fileno(), child_out.fileno()), env=env, stdin=subprocess.DEVNULL)
        for end in self._child_ends:
            end.close()
        try:
            self._to_child.send(self._settings)     # the pipe's first message (child_main)
        except (OSError, ValueError):
            self.failed = "the presenter process exited"

    @property
    def pid(self) -> int | None:
        """The presenter process's id (None before :meth:`start`)."""
        return self._process.pid if self._process is not None else None

    def submit(self, kind: str, payload=None) -> None:
        """Send to the presenter. The pipe is grown to megabytes so this does not block
        for frames; a very large still may wait while the presenter reads it."""
        try:
            self._to_child.send((kind, payload))
        except (OSError, ValueError):   # the presenter is gone; the node notices and exits
            self.failed = self.failed or "the presenter process exited"

    def attach(self, loop, on_report: Callable[[SwapRecord | DropRecord | PreviewRecord], None]) -> None:
        """Deliver swap and drop records, and previews, to ``on_report`` on ``loop``."""
        self._on_report = on_report
        loop.add_reader(self._from_child.fileno(), self._readable)

    def detach(self, loop) -> None:
        try:
            loop.remove_reader(self._from_child.fileno())
        except (ValueError, OSError):
            pass

    def _readable(self) -> None:
        while self._from_child.poll():
            try:
                kind, payload = self._from_child.recv()
            except (EOFError, OSError):
                self.failed = self.failed or "the presenter process exited"
                self._ready.set()
                return
            self._dispatch(kind, payload)

    def seconds_since_alive(self) -> float:
        """Seconds since the presenter process last sent anything (it says "alive" every
        ALIVE_EVERY_S while its loop runs)."""
        return time.monotonic() - self._alive_at

    def _dispatch(self, kind: str, payload) -> None:
        self._alive_at = time.monotonic()
        self.received[kind] += 1
        if kind == "ready":
            size, self.gl_info = payload
            self.native_size = tuple(size) if size else None
            self._ready.set()
        elif kind == "failed":
            self.failed = payload
            self._ready.set()
        elif kind == "stats":
            before = (self.stats.blend_id, self.stats.blend_since_rig_ns)
            self.stats = payload
            if (payload.blend_id, payload.blend_since_rig_ns) != before and self.on_blend_change is not None:
                self.on_blend_change()
        elif kind in ("swap", "drop", "preview") and self._on_report:
            self._on_report(payload)

    def wait_ready(self, timeout: float = 60.0) -> bool:
        """Block until the presenter reports ready or failed (reads the pipe itself)."""
        deadline = time.monotonic() + timeout
        while not self._ready.is_set() and time.monotonic() < deadline:
            if self._from_child.poll(0.1):
                self._readable()
            elif not self._running():
                self.failed = self.failed or f"the presenter process exited with {self._process.returncode}"
                break
        return self._ready.is_set() and self.failed is None

    def is_alive(self) -> bool:
        return self._running() and self.failed is None

    def _running(self) -> bool:
        return self._process is not None and self._process.poll() is None

    def stop(self, timeout: float = 5.0) -> None:
        self.submit("stop")
        if self._process is not None:
            try:
                self._process.wait(timeout)
            except subprocess.TimeoutExpired:
                self._process.terminate()
                try:
                    self._process.wait(2.0)
                except subprocess.TimeoutExpired:
                    self._process.kill()
                    self._process.wait()
        self._to_child.close()
        self._from_child.close()
