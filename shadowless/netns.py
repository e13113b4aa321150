"""A virtual venue network made of Linux network namespaces (standard library only).

A :class:`Venue` gives the coordinator and each node a network namespace, each joined by a veth
pair to one bridge that lives in a namespace of its own; every link is rate-limited with
``tc tbf`` in both directions (on the host's end and on the bridge's port), so multicast mDNS,
TCP and bandwidth behave as between machines on one switch::

    with Venue(["r0c0", "r0c1"], link="100mbit") as v:
        v.run("r0c0", ["python", "-m", "shadowless", "node", ..., "--mdns-interface", v.address("r0c0")])

* **Nothing in the caller's namespace.** Each veth pair is created inside the bridge's namespace
  with its peer born in the host's namespace (``ip -n BR link add P type veth peer name E netns
  HOST``); no interface, address or route of the namespace this runs in is created or changed.
  No ``netem``.
* **Names.** A venue draws the prefix ``sl`` + 6 hex digits. Namespaces: ``PREFIX-b`` (bridge),
  ``PREFIX-c`` (coordinator), ``PREFIX-nK`` (K-th node, from 0). Interfaces (inside them, at most
  12 characters): ``PREFIXbr`` (bridge), ``PREFIXpI`` (bridge port) and ``PREFIXeI`` (the host's
  end), I = 0 for the coordinator and K + 1 for node K.
* **Addresses.** ``10.77.0.0/16`` in every venue (venues are isolated from each other): the
  coordinator ``10.77.0.1``, nodes from ``10.77.0.10``.
* **Multicast.** ``mcast_snooping 0`` on the bridge (multicast is flooded to every port), loopback
  up and a ``224.0.0.0/4`` route on the venue interface in each host: zeroconf bound to the
  interface address (``--mdns-interface ADDR``) and plain senders to 224.0.0.251:5353 both work.
* **Bookkeeping.** Before anything is created, ``/run/shadowless-netns/PREFIX.json`` records the
  owner (pid and start time), the namespaces and each process :meth:`Venue.run` starts.
  :func:`cleanup_leftovers` (run by :meth:`Venue.create`) removes venues whose owner is gone:
  their recorded processes (pid and start time checked) and whatever else runs in their
  namespaces are killed, the namespaces (and with them veths and bridge) and files deleted. A
  namespace ``sl`` + 6 hex + ``-`` with no marker is a leftover too.
* **Reaching in from outside.** The caller's namespace has no route into a venue, by design.
  :meth:`Venue.unix_relay` runs a TCP relay (:mod:`shadowless.netns_relay`) inside a namespace that
  listens on a Unix socket *path*: filesystem sockets do not belong to a network namespace, so
  ``unix:/run/.../x.sock`` reaches e.g. the coordinator's gRPC port from anywhere on the machine.

``python -m shadowless.netns check|cleanup``: can venues be built here; remove crashed runs' leftovers.
"""
from __future__ import annotations

import argparse
import atexit
import ipaddress
import json
import os
import re
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterable, Sequence
from pathlib import Path

from shadowless import netns_relay

__all__ = ["COORDINATOR", "NAME_RE", "STATE_DIR", "Venue", "VenueError", "available", "cleanup_leftovers",
           "close_owned", "owned_namespaces", "parse_rate"]

COORDINATOR = "coordinator"
#: Every namespace a venue creates matches this (``sl`` + 6 hex digits + ``-``).
NAME_RE = re.compile(r"^(sl[0-9a-f]{6})-")
STATE_DIR = Path(os.environ.get("SHADOWLESS_NETNS_STATE", "/run/shadowless-netns"))
NETWORK = ipaddress.IPv4Network("10.77.0.0/16")
COORDINATOR_ADDRESS = NETWORK.network_address + 1
FIRST_NODE_ADDRESS = NETWORK.network_address + 10
CMD_TIMEOUT = 20.0


class VenueError(RuntimeError):
    """A venue cannot be built or used; the message says what is missing or what failed."""


# ---------------------------------------------------------------- small helpers
def parse_rate(rate: str | float) -> int:
    """A link rate in bit/s: a number, or ``tc`` notation such as ``"100mbit"``, ``"1gbit"``, ``"500kbit"``."""
    if isinstance(rate, (int, float)):
        bits = float(rate)
    else:
        m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+)\s*([kmgt]?)(bit|bps)?\s*", str(rate).lower())
        if not m:
            raise ValueError(f"not a link rate: {rate!r} (use e.g. 100mbit, 1gbit, 500kbit)")
        scale = {"": 1, "k": 1e3, "m": 1e6, "g": 1e9, "t": 1e12}[m.group(2)]
        bits = float(m.group(1)) * scale * (8 if m.group(3) == "bps" else 1)   # tc: bps = bytes per second
    if not bits >= 8000:
        raise ValueError(f"link rate {rate!r} is below 8 kbit/s")
    return int(bits)


def _proc_start(pid: int) -> int | None:
    """The start time of ``pid`` (clock ticks since boot), or None if it is gone or a zombie."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = stat[stat.rfind(")") + 2:].split()
    if fields[0] in ("Z", "X"):
        return None
    return int(fields[19])


def _alive(pid: int, start: int | None) -> bool:
    now = _proc_start(pid)
    return now is not None and (start is None or now == start)


def _cmd(argv: Sequence[str], *, check: bool = True, timeout: float = CMD_TIMEOUT) -> subprocess.CompletedProcess:
    try:
        r = subprocess.run(list(argv), stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=timeout)
    except FileNotFoundError as exc:
        raise VenueError(f"`{argv[0]}` is not installed (iproute2 provides `ip` and `tc`)") from exc
    except subprocess.TimeoutExpired as exc:
        raise VenueError(f"`{' '.join(argv)}` did not finish in {timeout:.0f} s") from exc
    if check and r.returncode != 0:
        raise VenueError(f"`{' '.join(argv)}` failed: {(r.stderr or r.stdout).strip()}")
    return r


def namespaces() -> set[str]:
    """Every network namespace on this host (``ip netns list``), the venues' and others'."""
    r = _cmd(["ip", "netns", "list"], check=False)
    return {line.split()[0] for line in r.stdout.splitlines() if line.strip()}


def _kill_and_wait(pids: Iterable[tuple[int, int | None]], timeout: float = 5.0) -> None:
    """SIGTERM each (pid, start time) still alive, then SIGKILL what remains after ``timeout``."""
    todo = [(p, s) for p, s in pids if _alive(p, s)]
    for sig, wait in ((signal.SIGTERM, timeout), (signal.SIGKILL, 5.0)):
        for pid, _ in todo:
            try:
                os.kill(pid, sig)
            except (ProcessLookupError, PermissionError):
                pass
        deadline = time.monotonic() + wait
        while todo and time.monotonic() < deadline:
            todo = [(p, s) for p, s in todo if _alive(p, s)]
            if todo:
                time.sleep(0.05)
        if not todo:
            return


def _write_json(path: Path, data: dict) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(data, indent=1))
    os.replace(tmp, path)


_AVAILABLE: tuple[bool, str] | None = None
_AVAILABLE_LOCK = threading.Lock()


def available(*, refresh: bool = False) -> tuple[bool, str]:
    """Whether venues can be built here: ``(True, "")`` or ``(False, what is missing)``.

    Checks the platform, the tools, the privileges, and then really builds a tiny venue (a
    namespace with a bridge, a veth pair and a ``tbf`` qdisc) and removes it. Cached.
    """
    global _AVAILABLE
    with _AVAILABLE_LOCK:
        if _AVAILABLE is None or refresh:
            _AVAILABLE = _probe()
        return _AVAILABLE


def _probe() -> tuple[bool, str]:
    if not sys.platform.startswith("linux"):
        return False, f"network namespaces need Linux (this is {sys.platform})"
    missing = [t for t in ("ip", "tc") if shutil.which(t) is None]
    if missing:
        return False, f"{' and '.join(missing)} not found: install iproute2"
    if os.geteuid() != 0:
        return False, "creating network namespaces needs root (run as root, e.g. with sudo)"
    try:
        STATE_DIR.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        return False, f"cannot create the state directory {STATE_DIR}: {exc}"
    prefix = _new_prefix()
    ns = f"{prefix}-b"
    marker = STATE_DIR / f"{prefix}.json"
    try:
        _write_json(marker, {"prefix": prefix, "owner": os.getpid(), "owner_start": _proc_start(os.getpid()),
                             "namespaces": [ns], "processes": [], "probe": True})
        for step, argv in [
                ("create a network namespace", ["ip", "netns", "add", ns]),
                ("create a bridge in a namespace", ["ip", "-n", ns, "link", "add", f"{prefix}br", "type", "bridge"]),
                ("create a veth pair in a namespace",
                 ["ip", "-n", ns, "link", "add", f"{prefix}p0", "type", "veth", "peer", "name", f"{prefix}e0"]),
                ("add a tbf qdisc (sch_tbf)", ["tc", "-n", ns, "qdisc", "add", "dev", f"{prefix}p0", "root", "tbf",
                                               "rate", "100mbit", "burst", "32kb", "latency", "50ms"])]:
            _cmd(argv)
        return True, ""
    except VenueError as exc:
        return False, f"cannot {step}: {exc}"
    finally:
        _cmd(["ip", "netns", "del", ns], check=False)
        marker.unlink(missing_ok=True)


def _new_prefix() -> str:
    existing = {m.group(1) for n in namespaces() if (m := NAME_RE.match(n))}
    while True:
        prefix = "sl" + secrets.token_hex(3)
        if prefix not in existing and not (STATE_DIR / f"{prefix}.json").exists():
            return prefix


# ---------------------------------------------------------------- leftovers
def _read_marker(path: Path) -> dict | None:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def _remove_venue_state(prefix: str, marker: dict | None, namespaces: list[str]) -> list[str]:
    """Kill a dead venue's processes, delete its namespaces, its runtime directory and its marker."""
    procs = [(int(p["pid"]), p.get("start")) for p in (marker or {}).get("processes", [])]
    _kill_and_wait(procs, timeout=2.0)
    # whatever else still runs inside (children of those processes) keeps a namespace alive unseen
    pids = [int(x) for ns in namespaces for x in _cmd(["ip", "netns", "pids", ns], check=False).stdout.split()]
    stray = [(pid, _proc_start(pid)) for pid in pids if pid != os.getpid()]
    _kill_and_wait(stray, timeout=2.0)
    removed = []
    for ns in namespaces:
        if _cmd(["ip", "netns", "del", ns], check=False).returncode == 0:
            removed.append(ns)
    shutil.rmtree(STATE_DIR / prefix, ignore_errors=True)
    (STATE_DIR / f"{prefix}.json").unlink(missing_ok=True)
    return removed


def cleanup_leftovers() -> list[str]:
    """Remove what crashed runs left: venues whose owner process is gone. Returns the namespaces removed.

    A venue is recognised by its marker ``STATE_DIR/PREFIX.json`` (owner pid and start time);
    a namespace matching :data:`NAME_RE` without any marker is a leftover too. Venues of live
    processes are never touched.
    """
    names = namespaces()        # before the markers: a venue's marker is written before its namespaces
    removed: list[str] = []
    live: set[str] = set()
    for path in sorted(STATE_DIR.glob("sl*.json")) if STATE_DIR.is_dir() else []:
        prefix = path.stem
        if not NAME_RE.fullmatch(prefix + "-"):
            continue
        marker = _read_marker(path)
        if marker is not None and _alive(int(marker.get("owner", 0)), marker.get("owner_start")):
            live.add(prefix)
            continue
        mine = [n for n in names if n.startswith(prefix + "-")]
        removed += _remove_venue_state(prefix, marker, mine)
    orphans: dict[str, list[str]] = {}
    for n in sorted(names):
        m = NAME_RE.match(n)
        if m and m.group(1) not in live and not (STATE_DIR / f"{m.group(1)}.json").exists():
            orphans.setdefault(m.group(1), []).append(n)
    for prefix, nss in orphans.items():
        removed += _remove_venue_state(prefix, None, nss)
    return removed


def owned_namespaces(pid: int | None = None) -> list[str]:
    """Namespaces that exist now and belong to a venue owned by ``pid`` (default: this process)."""
    pid = os.getpid() if pid is None else pid
    if not STATE_DIR.is_dir():
        return []
    recorded = []
    for path in STATE_DIR.glob("sl*.json"):
        marker = _read_marker(path)
        if marker and int(marker.get("owner", 0)) == pid and not marker.get("probe"):
            recorded += marker.get("namespaces", [])
    if not recorded:
        return []
    names = namespaces()
    return sorted(n for n in recorded if n in names)


def close_owned(namespaces: Iterable[str] | None = None) -> None:
    """Close the venues of this process that are still open (all of them, as the atexit hook
    does, or those holding one of ``namespaces``)."""
    _close_all(None if namespaces is None else set(namespaces))


# ---------------------------------------------------------------- process-wide safety net
_OPEN: set[Venue] = set()        # strong references: an unreferenced open venue is still closed at exit
_HOOKS_INSTALLED = False


def _close_all(namespaces: set[str] | None = None) -> None:
    for v in list(_OPEN):
        if namespaces is not None and not namespaces & set(v.namespaces):
            continue
        try:
            v.close()
        except Exception:   # noqa: BLE001 - best effort at exit
            pass


def _on_signal(signum, frame) -> None:
    _close_all()
    signal.signal(signum, signal.SIG_DFL)     # then die of the signal, as without us
    os.kill(os.getpid(), signum)


def _install_hooks() -> None:
    """atexit always; SIGTERM/SIGHUP only from the main thread and only over a default handler."""
    global _HOOKS_INSTALLED
    if _HOOKS_INSTALLED:
        return
    _HOOKS_INSTALLED = True
    atexit.register(_close_all)
    if threading.current_thread() is not threading.main_thread():
        return
    for sig in (signal.SIGTERM, signal.SIGHUP):
        if signal.getsignal(sig) == signal.SIG_DFL:
            signal.signal(sig, _on_signal)


# ---------------------------------------------------------------- the venue
class Venue:
    """A venue network: a coordinator namespace, one namespace per node, one bridge.

    ``nodes``: node host names (e.g. slot names), unique, not ``"coordinator"``. ``link``: every
    link's rate in ``tc`` notation (default ``"1gbit"``; ``"100mbit"`` for a Wi-Fi-class venue) or
    bit/s; ``coordinator_link``: the coordinator's (default ``link``); ``latency_ms``: ``tbf``'s
    queue, as the time a full queue takes to drain. A context manager, or :meth:`create` then
    :meth:`close` (idempotent; also run at interpreter exit and on SIGTERM/SIGHUP).
    """

    def __init__(self, nodes: Iterable[str] = (), *, link: str | int = "1gbit", coordinator_link: str | int | None = None,
                 latency_ms: float = 20.0):
        self.nodes = [str(n) for n in nodes]
        if len(set(self.nodes)) != len(self.nodes) or COORDINATOR in self.nodes:
            raise ValueError(f"node names must be unique and not {COORDINATOR!r}: {self.nodes}")
        if len(self.nodes) > NETWORK.num_addresses - 12:
            raise ValueError(f"too many nodes for {NETWORK}")
        self.link_bps = parse_rate(link)
        self.coordinator_link_bps = parse_rate(coordinator_link) if coordinator_link is not None else self.link_bps
        self.latency_ms = float(latency_ms)
        self.hosts = [COORDINATOR, *self.nodes]
        self.prefix: str | None = None
        self._procs: list[subprocess.Popen] = []
        self._proc_meta: list[dict] = []
        self._created = False
        self._closed = False
        self._lock = threading.RLock()

    # ---------------------------------------------------------------- naming
    def _index(self, host: str) -> int:
        try:
            return self.hosts.index(host)
        except ValueError:
            raise KeyError(f"no host {host!r} in this venue (hosts: {', '.join(self.hosts)})") from None

    @property
    def _p(self) -> str:
        if self.prefix is None:
            raise VenueError("the venue is not created yet (use it as a context manager or call create())")
        return self.prefix

    def namespace(self, host: str) -> str:
        """The namespace of ``host`` (``"coordinator"`` or a node name)."""
        i = self._index(host)
        return f"{self._p}-c" if i == 0 else f"{self._p}-n{i - 1}"

    @property
    def bridge_namespace(self) -> str:
        return f"{self._p}-b"

    @property
    def namespaces(self) -> list[str]:
        return [self.bridge_namespace] + [self.namespace(h) for h in self.hosts]

    def interface(self, host: str) -> str:
        """The name of ``host``'s venue interface inside its namespace."""
        return f"{self._p}e{self._index(host)}"

    def address(self, host: str) -> str:
        """``host``'s IPv4 address on the venue network."""
        i = self._index(host)
        return str(COORDINATOR_ADDRESS if i == 0 else FIRST_NODE_ADDRESS + (i - 1))

    def link_rate(self, host: str) -> int:
        """``host``'s link rate in bit/s."""
        return self.coordinator_link_bps if self._index(host) == 0 else self.link_bps

    @property
    def runtime_dir(self) -> Path:
        """A directory for this venue's sockets and files, removed by :meth:`close`."""
        return STATE_DIR / self._p

    # ---------------------------------------------------------------- life cycle
    def __enter__(self) -> Venue:
        return self if self._created else self.create()

    def __exit__(self, *exc) -> None:
        self.close()

    def create(self) -> Venue:
        """Build the namespaces, the bridge, the links and their rate limits."""
        with self._lock:
            if self._created:
                raise VenueError("this venue was already created")
            ok, reason = available()
            if not ok:
                raise VenueError(f"cannot build a venue network: {reason}")
            cleanup_leftovers()
            self.prefix = _new_prefix()
            self._created = True
            _install_hooks()
            _OPEN.add(self)
            try:
                self._save_marker()
                self._build()
            except BaseException:
                self.close()
                raise
            return self

    def _save_marker(self) -> None:
        _write_json(STATE_DIR / f"{self.prefix}.json", {
            "prefix": self.prefix, "owner": os.getpid(), "owner_start": _proc_start(os.getpid()),
            "created": time.time(), "namespaces": self.namespaces, "hosts": self.hosts,
            "processes": self._proc_meta})

    def _tbf(self, ns: str, dev: str, bps: int) -> None:
        burst = max(int(bps / 8 * 0.002), 16 * 1024)          # ~2 ms of traffic, at least 16 KiB
        _cmd(["tc", "-n", ns, "qdisc", "replace", "dev", dev, "root", "tbf", "rate", f"{bps}bit",
              "burst", str(burst), "latency", f"{self.latency_ms:g}ms"])

    def _build(self) -> None:
        br_ns, p = self.bridge_namespace, self._p
        bridge = f"{p}br"
        for ns in self.namespaces:
            _cmd(["ip", "netns", "add", ns])
            _cmd(["ip", "-n", ns, "link", "set", "lo", "up"])
        _cmd(["ip", "-n", br_ns, "link", "add", bridge, "type", "bridge", "stp_state", "0", "forward_delay", "0",
              "mcast_snooping", "0"])
        _cmd(["ip", "-n", br_ns, "link", "set", bridge, "up"])
        for i, host in enumerate(self.hosts):
            ns, port, end = self.namespace(host), f"{p}p{i}", f"{p}e{i}"
            # both ends are born inside venue namespaces: nothing appears in the caller's namespace
            _cmd(["ip", "-n", br_ns, "link", "add", port, "type", "veth", "peer", "name", end, "netns", ns])
            _cmd(["ip", "-n", br_ns, "link", "set", port, "master", bridge])
            _cmd(["ip", "-n", br_ns, "link", "set", port, "up"])
            _cmd(["ip", "-n", ns, "addr", "add", f"{self.address(host)}/{NETWORK.prefixlen}", "dev", end])
            _cmd(["ip", "-n", ns, "link", "set", end, "up"])
            _cmd(["ip", "-n", ns, "route", "add", "224.0.0.0/4", "dev", end])
            bps = self.link_rate(host)
            self._tbf(ns, end, bps)        # host -> bridge
            self._tbf(br_ns, port, bps)    # bridge -> host
        self.runtime_dir.mkdir(parents=True, exist_ok=True)

    def run(self, host: str, argv: Sequence[str], **popen_kwargs) -> subprocess.Popen:
        """Start ``argv`` in ``host``'s namespace (``ip netns exec`` execs it: the pid is argv's own);
        :meth:`close` stops it by that pid."""
        with self._lock:
            if not self._created or self._closed:
                raise VenueError("the venue is not open")
            proc = subprocess.Popen(["ip", "netns", "exec", self.namespace(host), *argv], **popen_kwargs)
            self._procs.append(proc)
            self._proc_meta.append({"pid": proc.pid, "start": _proc_start(proc.pid), "host": host})
            self._save_marker()
            return proc

    def check_output(self, host: str, argv: Sequence[str], *, timeout: float = 60.0, **kw) -> str:
        """Run ``argv`` in ``host``'s namespace to completion and return its stdout (text)."""
        proc = self.run(host, argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kw)
        try:
            out, err = proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()
            raise VenueError(f"{' '.join(argv)} in {host} did not finish in {timeout:.0f} s") from None
        if proc.returncode != 0:
            raise VenueError(f"{' '.join(argv)} in {host} exited with {proc.returncode}: {err.strip()[-2000:]}")
        return out

    def unix_relay(self, host: str, port: int, *, target: str | None = None, path: str | Path | None = None,
                   timeout: float = 10.0) -> str:
        """Make ``target:port`` inside ``host``'s namespace reachable from anywhere on this machine.

        Starts a relay process in ``host``'s namespace that accepts connections on the Unix socket
        ``path`` (default: in :attr:`runtime_dir`) and forwards each to ``target`` (default: the
        host's venue address) on ``port``. Returns the socket path; gRPC channels take
        ``"unix:" + path``. The relay runs until :meth:`close`.
        """
        target = target or self.address(host)
        path = Path(path) if path is not None else self.runtime_dir / f"{host}-{port}.sock"
        if len(str(path)) > 100:
            raise VenueError(f"Unix socket path too long: {path}")
        path.unlink(missing_ok=True)
        proc = self.run(host, netns_relay.relay_command(path, target, port), stdin=subprocess.DEVNULL,
                        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True)
        deadline = time.monotonic() + timeout
        while True:
            if proc.poll() is not None:
                err = proc.stderr.read().decode(errors="replace") if proc.stderr else ""
                raise VenueError(f"the relay in {host} exited with {proc.returncode}: {err.strip()[-2000:]}")
            try:
                with socket.socket(socket.AF_UNIX) as s:
                    s.connect(str(path))
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise VenueError(f"the relay in {host} did not listen on {path} in {timeout:.0f} s") from None
                time.sleep(0.05)
        return str(path)

    def close(self, timeout: float = 5.0) -> None:
        """Stop every process :meth:`run` started (by pid: SIGTERM, then SIGKILL after ``timeout``),
        delete every namespace (with them the veths and the bridge) and this venue's files."""
        with self._lock:
            if self._closed or not self._created:
                self._closed = True
                return
            self._closed = True
            _OPEN.discard(self)
            _kill_and_wait([(m["pid"], m["start"]) for p, m in zip(self._procs, self._proc_meta) if p.poll() is None],
                           timeout=timeout)
            for p in self._procs:
                p.poll()       # reap
                for f in filter(None, (p.stdin, p.stdout, p.stderr)):
                    f.close()
            errors = []
            for ns in reversed(self.namespaces):
                r = _cmd(["ip", "netns", "del", ns], check=False)
                if r.returncode != 0 and "No such file" not in r.stderr:
                    errors.append(f"{ns}: {r.stderr.strip()}")
            shutil.rmtree(self.runtime_dir, ignore_errors=True)
            if not errors:
                (STATE_DIR / f"{self.prefix}.json").unlink(missing_ok=True)
            else:   # leave the marker so that cleanup_leftovers() retries
                raise VenueError("could not delete every namespace: " + "; ".join(errors))

    def describe(self) -> str:
        """One line per host: namespace, address and link rate."""
        lines = [f"venue {self.prefix}: bridge in {self.bridge_namespace}, {NETWORK}"]
        for h in self.hosts:
            lines.append(f"  {h:<12} {self.namespace(h):<14} {self.address(h):<12} {self.link_rate(h) / 1e6:g} Mbit/s")
        return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m shadowless.netns", description="Virtual venue networks (namespaces).")
    sub = p.add_subparsers(dest="cmd", required=True)
    sub.add_parser("check", help="say whether venues can be built here")
    sub.add_parser("cleanup", help="remove the namespaces of crashed runs")
    netns_relay.add_arguments(sub.add_parser("relay", help="(internal) Unix socket -> TCP relay, run inside a namespace"))
    args = p.parse_args(argv)
    if args.cmd == "check":
        ok, reason = available()
        print("venues can be built here" if ok else f"venues cannot be built here: {reason}")
        return 0 if ok else 1
    if args.cmd == "cleanup":
        print("removed:", " ".join(cleanup_leftovers()) or "nothing")
        return 0
    return netns_relay.serve(args)


if __name__ == "__main__":
    sys.exit(main())
