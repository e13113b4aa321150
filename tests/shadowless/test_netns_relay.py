"""The relay a venue runs inside a namespace (`shadowless/netns_relay.py`), here on loopback: it needs
no namespace to forward a Unix socket to a TCP port, so it is tested as a plain process."""
from __future__ import annotations

import signal
import socket
import subprocess
import threading

from waits import wait_until

from shadowless.netns_relay import relay_command


def _connects(path: str) -> bool:
    with socket.socket(socket.AF_UNIX) as s:
        try:
            s.connect(path)
        except OSError:
            return False
        return True


def _exchange(path: str, data: bytes) -> bytes:
    """Send ``data`` and read until as many bytes came back or the other side closed. (The relay
    ends a connection when either side ends it: no half-close, which gRPC never uses.)"""
    with socket.socket(socket.AF_UNIX) as c:
        c.settimeout(30)
        c.connect(path)
        c.sendall(data)
        got = b""
        while len(got) < len(data) and (chunk := c.recv(1 << 16)):
            got += chunk
        return got


def _refused(path: str, data: bytes) -> bytes:
    """What comes back when the relay cannot reach its target: it closes the connection, which the
    client sees as an empty read, or, when the close beats the send, as a broken pipe or a reset."""
    try:
        return _exchange(path, data)
    except (BrokenPipeError, ConnectionResetError):
        return b""


def test_the_relay_forwards_each_connection_both_ways_and_removes_its_socket_on_sigterm(tmp_path):
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]
    served: list[bytes] = []

    def echo() -> None:            # answers each connection with what it got, in capitals, until closed
        while True:
            try:
                c, _ = server.accept()
            except OSError:
                return
            with c:
                got = b""
                while chunk := c.recv(1 << 16):
                    got += chunk
                    c.sendall(chunk.upper())
                if got:             # (the probe that waits for the relay to listen sends nothing)
                    served.append(got)

    t = threading.Thread(target=echo, name="echo")
    t.start()
    path = str(tmp_path / "r.sock")
    relay = subprocess.Popen(relay_command(path, "127.0.0.1", port), stderr=subprocess.PIPE, text=True)
    try:
        wait_until(lambda: relay.poll() is None and _connects(path), what=f"the relay to listen on {path}",
                   timeout=30)
        assert _exchange(path, b"first") == b"FIRST"
        assert _exchange(path, b"second" * 1000) == b"SECOND" * 1000
        assert wait_until(lambda: list(served), lambda s: len(s) == 2, what="the server to see both connections end",
                          timeout=30) == [b"first", b"second" * 1000]
        relay.send_signal(signal.SIGTERM)
        assert relay.wait(30) == 0, relay.stderr.read()
        assert not (tmp_path / "r.sock").exists()
    finally:
        if relay.poll() is None:
            relay.kill()
            relay.wait()
        relay.stderr.close()
        server.shutdown(socket.SHUT_RDWR)  # ends the echo thread's accept()
        server.close()
        t.join(30)


def test_a_connection_to_a_port_nobody_listens_on_is_closed_and_the_relay_keeps_serving(tmp_path):
    free = socket.create_server(("127.0.0.1", 0))
    port = free.getsockname()[1]
    free.close()                    # nothing listens on it now
    path = str(tmp_path / "r.sock")
    relay = subprocess.Popen(relay_command(path, "127.0.0.1", port), stderr=subprocess.PIPE, text=True)
    try:
        wait_until(lambda: relay.poll() is None and _connects(path), what=f"the relay to listen on {path}",
                   timeout=30)
        assert _refused(path, b"anyone?") == b""
        assert relay.poll() is None, "the relay is still running"
        assert _refused(path, b"again") == b""
    finally:
        relay.terminate()
        relay.wait(30)
        relay.stderr.close()
