"""The virtual venue network (`shadowless/netns.py`, its relay `shadowless/netns_relay.py`) and a whole rig on it.

Everything is measured on real namespaces: a TCP transfer over a rate-limited link takes at
least bytes / rate (a lower bound only: a busy machine may be slower, never faster), multicast
sent in one namespace reaches two others, TCP crosses the bridge, and nothing is left behind:
not by ``close()`` when the body raises, not by a process killed with SIGKILL once
``cleanup_leftovers()`` ran. With ``CI=true`` these tests must run: they fail when namespaces
cannot be built; elsewhere they skip, saying why.
"""
from __future__ import annotations

import asyncio
import json
import signal
import subprocess
import sys
import socket
import textwrap
from pathlib import Path

import pytest
from waits import wait_until

from protos.version import SERVICE_TYPE
from shadowless import netns
from shadowless.netns import namespaces as netns_names
from shadowless.netns import (
    COORDINATOR,
    STATE_DIR,
    Venue,
    VenueError,
    cleanup_leftovers,
    parse_rate,
)

ROOT = Path(__file__).resolve().parents[2]


def named(prefix: str) -> set[str]:
    """The namespaces on the machine of the venue ``prefix`` (other venues, e.g. another test worker's
    or a benchmark's, may come and go meanwhile: the tests look at their own venues only)."""
    return {n for n in netns_names() if n.startswith(prefix + "-")}




def host_links() -> set[str]:
    out = subprocess.run(["ip", "-o", "link", "show"], capture_output=True, text=True, check=True).stdout
    return {line.split(":")[1].strip().split("@")[0] for line in out.splitlines()}


def py(code: str, *args) -> list[str]:
    return [sys.executable, "-c", textwrap.dedent(code), *map(str, args)]


def finish(proc: subprocess.Popen, timeout: float = 60.0) -> str:
    try:
        out, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        raise
    assert proc.returncode == 0, f"exit {proc.returncode}"
    return out


RECEIVER = """
    import json, socket, sys, time
    s = socket.socket()
    s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    s.bind((sys.argv[1], int(sys.argv[2])))
    s.listen(1)
    print("ready", flush=True)
    c, peer = s.accept()
    n, t0 = 0, None
    while True:
        d = c.recv(1 << 16)
        if not d:
            break
        if t0 is None:
            t0 = time.monotonic()
        n += len(d)
    seconds = time.monotonic() - t0
    c.sendall(b"k")
    c.close()
    print(json.dumps({"bytes": n, "seconds": seconds, "peer": peer[0]}), flush=True)
"""

SENDER = """
    import socket, sys
    # the receiver listens before this starts (transfer() reads its "ready"): one connection attempt
    c = socket.create_connection((sys.argv[1], int(sys.argv[2])), timeout=20)
    left, chunk = int(sys.argv[3]), b"x" * (1 << 16)
    while left > 0:
        c.sendall(chunk[:left])
        left -= len(chunk)
    c.shutdown(socket.SHUT_WR)
    assert c.recv(1) == b"k"
"""


def transfer(v: Venue, src: str, dst: str, nbytes: int, port: int = 5001) -> dict:
    """Send ``nbytes`` over TCP from ``src`` to ``dst``; the receiver's figures (first byte to EOF)."""
    rx = v.run(dst, py(RECEIVER, v.address(dst), port), stdout=subprocess.PIPE, text=True)
    assert rx.stdout.readline().strip() == "ready"
    tx = v.run(src, py(SENDER, v.address(dst), port, nbytes))
    out = finish(rx)
    finish(tx)
    return json.loads(out.strip().splitlines()[-1])


# ---------------------------------------------------------------- plain checks
def test_parse_rate():
    assert parse_rate("1gbit") == 1_000_000_000
    assert parse_rate("100mbit") == 100_000_000
    assert parse_rate("2.5Mbit") == 2_500_000
    assert parse_rate("1mbps") == 8_000_000          # tc: bps = bytes per second
    assert parse_rate(64_000) == 64_000
    for bad in ("fast", "-1mbit", "10"):
        with pytest.raises(ValueError):
            parse_rate(bad)


def test_clear_error_when_namespaces_cannot_be_built(monkeypatch):
    monkeypatch.setenv("PATH", "/nonexistent")
    ok, reason = netns._probe()
    assert not ok and "ip and tc not found" in reason and "iproute2" in reason
    monkeypatch.setattr(netns, "_AVAILABLE", (False, "creating network namespaces needs root"))
    with pytest.raises(VenueError, match="cannot build a venue network: creating network namespaces needs root"):
        Venue(["a"]).create()
    with pytest.raises(VenueError, match="needs root"), Venue(["a"]):
        pass


def test_local_command_offers_the_venue():
    out = subprocess.run([sys.executable, "-m", "shadowless", "local", "--help"], capture_output=True, text=True,
                         timeout=60).stdout
    assert "--netns" in out and "--link RATE" in out and "--coordinator-link" in out


def test_names_addresses_and_nothing_in_the_host_namespace(ns):
    links_before = host_links()
    with Venue(["r0c0", "r0c1", "r1c0"]) as v:
        assert netns.NAME_RE.fullmatch(v.prefix + "-")
        assert v.address(COORDINATOR) == "10.77.0.1"
        assert [v.address(s) for s in v.nodes] == ["10.77.0.10", "10.77.0.11", "10.77.0.12"]
        assert set(v.namespaces) == named(v.prefix)
        assert all(n.startswith(v.prefix + "-") for n in v.namespaces)
        assert host_links() == links_before, "the host's namespace must not see a single venue interface"
        assert all(len(v.interface(h)) <= 15 for h in v.hosts)
        assert (STATE_DIR / f"{v.prefix}.json").exists()
        # loopback up everywhere, the venue address on the venue interface, multicast routed there
        out = v.check_output("r0c1", ["ip", "-br", "addr"])
        assert "lo" in out and "UNKNOWN" in out.splitlines()[0] and "10.77.0.11/16" in out
        assert "224.0.0.0/4 dev " + v.interface("r0c1") in v.check_output("r0c1", ["ip", "route"])
        # both directions shaped with tbf
        assert "tbf" in v.check_output("r0c0", ["tc", "qdisc", "show", "dev", v.interface("r0c0")])
        br = subprocess.run(["tc", "-n", v.bridge_namespace, "qdisc", "show"], capture_output=True, text=True).stdout
        assert br.count("qdisc tbf") == 4
        assert "mcast_snooping 0" in subprocess.run(["ip", "-n", v.bridge_namespace, "-d", "link", "show", v.prefix + "br"],
                                                    capture_output=True, text=True).stdout
        with pytest.raises(KeyError):
            v.address("nope")
    assert not named(v.prefix) and host_links() == links_before


# ---------------------------------------------------------------- traffic
def test_tcp_between_coordinator_and_node(ns):
    with Venue(["a", "b"]) as v:
        r = transfer(v, "a", COORDINATOR, 100_000)
        assert r["bytes"] == 100_000 and r["peer"] == v.address("a")
        r = transfer(v, COORDINATOR, "b", 100_000, port=5002)
        assert r["bytes"] == 100_000 and r["peer"] == v.address(COORDINATOR)


def test_rate_limit_holds(ns, record_property):
    """A 100 Mbit/s venue cannot move 10 MB faster than 0.8 s; a 20 Mbit/s coordinator link
    limits what goes into and out of the coordinator while the nodes keep 100 Mbit/s."""
    figures = {}
    with Venue(["a", "b"], link="100mbit", coordinator_link="20mbit") as v:
        for name, src, dst, nbytes, bps in [("node->node 100mbit", "a", "b", 10_000_000, 100e6),
                                            ("node->coordinator 20mbit", "a", COORDINATOR, 2_500_000, 20e6),
                                            ("coordinator->node 20mbit", COORDINATOR, "b", 2_500_000, 20e6)]:
            r = transfer(v, src, dst, nbytes)
            assert r["bytes"] == nbytes
            ideal = nbytes * 8 / bps
            figures[name] = {"seconds": round(r["seconds"], 3), "ideal_s": ideal,
                             "mbit_s": round(nbytes * 8 / r["seconds"] / 1e6, 1)}
            # the token bucket lets a few tens of kB through at once; 20 % margin covers that and more
            assert r["seconds"] >= 0.8 * ideal, (name, r)
    record_property("rate_limit", figures)
    print("rate limit:", json.dumps(figures))


MCAST_RECEIVER = """
    import socket, struct, sys
    group, port, iface = "224.0.0.251", 5353, sys.argv[1]
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM, socket.IPPROTO_UDP)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    s.bind(("", port))
    # join by interface address, or with INADDR_ANY through the venue's 224.0.0.0/4 route
    s.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP,
                 socket.inet_aton(group) + socket.inet_aton(iface if iface != "any" else "0.0.0.0"))
    s.settimeout(20)
    print("ready", flush=True)
    while True:
        data, (src, sport) = s.recvfrom(2048)
        if data.startswith(b"venue-hello"):
            s.sendto(b"heard", (src, sport))       # unicast back: the sender stops once all have heard
            print(src, data.decode(), flush=True)
            break
"""

MCAST_SENDER = """
    import socket, sys
    receivers = int(sys.argv[1])
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM, socket.IPPROTO_UDP)
    s.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 255)
    s.settimeout(0.2)                    # a datagram may be lost: say hello again when no answer came
    heard = set()
    for i in range(300):                 # no IP_MULTICAST_IF: the route picks the venue interface
        s.sendto(b"venue-hello %d" % i, ("224.0.0.251", 5353))
        try:
            while len(heard) < receivers:
                data, (src, _) = s.recvfrom(64)
                heard.add(src)
        except socket.timeout:
            continue
        break
    print(" ".join(sorted(heard)), flush=True)
"""


def test_multicast_reaches_every_other_namespace(ns):
    with Venue(["a", "b", "c"]) as v:
        rxs = {h: v.run(h, py(MCAST_RECEIVER, arg), stdout=subprocess.PIPE, text=True)
               for h, arg in (("a", v.address("a")), ("b", "any"), (COORDINATOR, v.address(COORDINATOR)))}
        for p in rxs.values():
            assert p.stdout.readline().strip() == "ready"
        tx = v.run("c", py(MCAST_SENDER, len(rxs)), stdout=subprocess.PIPE, text=True)
        got = {h: finish(p, timeout=30).split() for h, p in rxs.items()}
        answered = finish(tx, timeout=30).split()
    for h, (src, word, _) in got.items():
        assert src == v.address("c") and word == "venue-hello", (h, src, word)
    assert sorted(answered) == sorted(v.address(h) for h in rxs), answered


ECHO = """
    import socket, sys
    s = socket.socket()
    s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    s.bind((sys.argv[1], int(sys.argv[2])))
    s.listen(4)
    print("ready", flush=True)
    while True:
        c, _ = s.accept()
        with c:
            while data := c.recv(1 << 16):
                c.sendall(data.upper())
"""


def test_unix_relay_reaches_a_port_inside_the_venue(ns):
    """The relay's Unix socket reaches a port inside the venue (where the caller's namespace has no
    route), both ways, for one connection after another, and goes away with the venue."""
    with Venue(["a"]) as v:
        server = v.run(COORDINATOR, py(ECHO, v.address(COORDINATOR), 7611), stdout=subprocess.PIPE, text=True)
        assert server.stdout.readline().strip() == "ready"
        path = v.unix_relay(COORDINATOR, 7611)
        assert path.startswith(str(v.runtime_dir))
        for word in (b"venue", b"relay" * 4000):
            with socket.socket(socket.AF_UNIX) as c:
                c.settimeout(30)
                c.connect(path)
                c.sendall(word)
                got = b""
                while len(got) < len(word) and (chunk := c.recv(1 << 16)):
                    got += chunk
            assert got == word.upper()
    assert not Path(path).exists()


# ---------------------------------------------------------------- nothing left behind
def test_close_removes_everything_even_when_the_body_raises(ns):
    links_before = host_links()
    with pytest.raises(RuntimeError, match="boom"), Venue(["a", "b"]) as v:
        sleeper = v.run("a", ["sleep", "300"])
        assert len(named(v.prefix)) == 4
        raise RuntimeError("boom")
    assert sleeper.poll() is not None, "close() stops what the venue started"
    assert not named(v.prefix)
    assert host_links() == links_before
    assert not (STATE_DIR / f"{v.prefix}.json").exists() and not (STATE_DIR / v.prefix).exists()
    assert not netns.owned_namespaces()
    v.close()   # idempotent


def test_a_failed_create_removes_what_it_built(ns, monkeypatch):
    markers_before = set(STATE_DIR.glob("sl*.json"))

    def broken_tbf(self, ns, dev, bps):
        raise VenueError("tc refused (simulated)")

    monkeypatch.setattr(Venue, "_tbf", broken_tbf)
    venue = Venue(["a", "b"])
    with pytest.raises(VenueError, match="simulated"):
        venue.create()
    assert not named(venue.prefix)
    assert set(STATE_DIR.glob("sl*.json")) == markers_before


CRASHER = """
    import signal
    from shadowless.netns import Venue
    v = Venue(["x", "y"]).create()
    p = v.run("x", ["sleep", "300"])
    v.unix_relay("coordinator", 7600)
    print(v.prefix, p.pid, flush=True)
    signal.pause()                       # until the test kills this process
"""


def test_cleanup_leftovers_removes_what_a_killed_process_left(ns):
    with Venue(["z"]) as mine:                 # a live venue of this process is never a leftover
        child = subprocess.Popen(py(CRASHER), cwd=ROOT, stdout=subprocess.PIPE, text=True)
        try:
            prefix, sleeper = child.stdout.readline().split()
        finally:
            child.kill()
            child.wait()
            child.stdout.close()
        sleeper = int(sleeper)
        left = named(prefix)
        assert len(left) == 4
        assert netns._proc_start(sleeper) is not None, "the crashed venue's process is still running"
        assert (STATE_DIR / f"{prefix}.json").exists()
        removed = cleanup_leftovers()
        assert left <= set(removed) and not named(prefix)
        assert set(mine.namespaces) <= netns_names()
    assert not named(mine.prefix)
    # killed by cleanup_leftovers(); gone from /proc once its new parent has reaped it
    wait_until(lambda: netns._proc_start(sleeper), lambda start: start is None,
               what=f"the leftover's process {sleeper} to be stopped")
    assert not (STATE_DIR / f"{prefix}.json").exists() and not (STATE_DIR / prefix).exists()
    assert cleanup_leftovers() == []


FORGETFUL = """
    import signal, sys
    from shadowless.netns import Venue
    v = Venue(["x"]).create()
    p = v.run("x", ["sleep", "300"])
    print(v.prefix, p.pid, flush=True)
    if sys.argv[1] == "wait":
        signal.pause()                   # until the test's SIGTERM
"""


@pytest.mark.parametrize("how", ["exit", "sigterm"])
def test_exit_and_sigterm_close_a_forgotten_venue(ns, how):
    child = subprocess.Popen(py(FORGETFUL, "exit" if how == "exit" else "wait"), cwd=ROOT, stdout=subprocess.PIPE,
                             text=True)
    try:
        prefix, sleeper = child.stdout.readline().split()
        if how == "sigterm":
            child.send_signal(signal.SIGTERM)
        # closing takes up to 10 s of stopping processes and two `ip netns del` of up to CMD_TIMEOUT each: a
        # loaded machine may need most of that, so wait for the outcome rather than race a deadline
        assert child.wait(10 + 2 * netns.CMD_TIMEOUT + 60) == (-signal.SIGTERM if how == "sigterm" else 0)
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
        child.stdout.close()
    assert not named(prefix)
    assert netns._proc_start(int(sleeper)) is None
    assert not (STATE_DIR / f"{prefix}.json").exists()


# ---------------------------------------------------------------- a whole rig on a venue
@pytest.mark.slow
def test_rig_of_three_nodes_on_a_gigabit_venue(ns, tmp_path):
    from coordinator.api import NodeState, PlaySettings
    from shadowless.local import LocalRig

    slots = ["r0c0", "r0c1", "r1c0"]
    with LocalRig(slots, tmp_path, output_size=(64, 48), content_size=(64, 48), netns=True, link="1gbit") as rig:
        v = rig.venue
        assert rig.target.startswith("unix:") and rig.coordinator_target == "10.77.0.1:7600"
        for s in slots:     # discovery only: no node is told where the coordinator is
            args = rig.node_args(s)
            assert "--coordinator" not in args and args[args.index("--mdns-interface") + 1] == v.address(s)

        async def go():
            async with await rig.client() as c:
                await rig.wait_live(c, timeout=120)
                # an operator on a node's host, over the venue network
                st = json.loads(rig.run_cli(["status", "--json"], host="r1c0"))
                assert {n["slot"]: n["state"] for n in st["nodes"]} == {s: NodeState.LIVE.value for s in slots}
                return await c.play(PlaySettings(fps=20, pattern="counter", frames=30, wait=True, latency_ms=150))

        r = asyncio.run(go())
        assert r.nodes == 3 and r.frames_sent == 30 and r.sync.out_of_order == 0
        st = json.loads(rig.run_cli(["status", "--json"]))
        for n in st["nodes"]:
            assert n["shown"] > 0 and n["last_swap_frame"], n
        log = rig.log("coordinator")
        assert f"advertising {rig.rig_name}.{SERVICE_TYPE} on 10.77.0.1" in log
        for s in slots:     # each node came over its own link of the bridge
            assert f"node {s} joined from ipv4:{v.address(s)}:" in log, log[-2000:]
    assert not named(v.prefix)
