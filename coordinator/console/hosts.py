"""Which ``Host`` a request to the console may name: an address the console listens on, or a
name the operator allowed.

A DNS-rebinding page (``evil.example`` first resolving to the attacker, then to the console's
address) makes the victim's browser send ``Host: evil.example:7680`` and ``Origin:
http://evil.example:7680``: the two agree, so comparing them proves nothing. The console
therefore checks the Host against what it knows of itself (:class:`HostCheck`):

* each IP address and port it is bound to; bound to a wildcard (``0.0.0.0``, ``::``), any
  address of this machine of that family on its port (an address is this machine's when a
  socket can bind to it: no interface list to go stale);
* ``localhost`` when it listens on loopback (or a wildcard, which includes loopback);
* the host name it was told to listen on (``--console NAME:PORT``);
* the allow-list (``--console-host NAME`` or ``NAME:PORT``): names a browser may use for it,
  e.g. ``console.venue.lan``, or a reverse proxy's name and port.

The Origin of a POST must then equal the console's own origin for that Host (checked in
:mod:`coordinator.console.app`).
"""
from __future__ import annotations

import argparse
import ipaddress
import re
import socket
from typing import Callable, Iterable

#: a DNS name: dot-separated labels of letters, digits and inner hyphens (a final dot allowed)
_LABEL = re.compile(r"^[a-z0-9]([a-z0-9-]{0,61}[a-z0-9])?$")
DEFAULT_PORTS = {"http": 80, "https": 443}


def _port(text: str, value: str) -> int:
    if not text.isdigit() or len(text) > 5 or not 1 <= int(text) <= 65535:
        raise ValueError(f"{value.strip()!r}: port {text!r} is not a number 1..65535")
    return int(text)


def normal_host(host: str) -> str:
    """A host name or IP address as compared: lower case, no final dot, IPs in their short
    form (``::0001`` -> ``::1``); ValueError when it is neither a DNS name nor an IP address."""
    h = host.strip().lower()
    try:
        return ipaddress.ip_address(h).compressed
    except ValueError:
        pass
    name = h[:-1] if h.endswith(".") else h
    if not name or len(name) > 253 or not all(_LABEL.match(label) for label in name.split(".")):
        raise ValueError(f"{host!r} is not a host name or IP address")
    if name.replace(".", "").isdigit():
        raise ValueError(f"{host!r} is not a host name or IP address")
    return name


def split_host(value: str) -> tuple[str, int | None]:
    """A ``Host`` header or allow-list entry -> (normal host, port or None).

    ``name``, ``name:port``, ``1.2.3.4:port``, ``[v6]`` and ``[v6]:port`` (RFC 7230's Host);
    ValueError otherwise.
    """
    v = value.strip()
    if not v or len(v) > 300 or any(c.isspace() for c in v):
        raise ValueError(f"{value!r} is not a host name or IP address")
    if v.startswith("["):
        inner, sep, rest = v[1:].partition("]")
        if not sep or ":" not in inner or "%" in inner:     # no zone ids: browsers send none
            raise ValueError(f"{value!r} is not a host name or IP address")
        try:
            host = ipaddress.IPv6Address(inner).compressed
        except ValueError:
            raise ValueError(f"{value!r} is not a host name or IP address") from None
        if not rest:
            return host, None
        if not rest.startswith(":"):
            raise ValueError(f"{value!r} is not a host name or IP address")
        return host, _port(rest[1:], value)
    if v.count(":") > 1:        # an IPv6 address must be in brackets (RFC 3986's IP-literal)
        raise ValueError(f"{value!r} is not a host name or IP address (an IPv6 address goes in brackets: "
                         "[fd00::1])")
    host, sep, port = v.partition(":")
    return normal_host(host), (_port(port, value) if sep else None)


def check_allowed(text: str) -> str:
    """A name the console may be reached by (``--console-host``): ``NAME`` or ``NAME:PORT`` (IPv6 in
    brackets), returned stripped once valid; ValueError with one line saying what to give otherwise."""
    try:
        scheme, sep, rest = text.strip().partition("://")
        if sep:
            raise ValueError(f"{text.strip()!r} is a URL, not a name (give {rest.split('/')[0] or 'the name'!r} "
                             "alone)")
        split_host(text)
    except ValueError as exc:
        raise ValueError(f"{exc}; give a name a browser uses for the console, e.g. console.venue.lan, 10.0.0.2 or "
                         "proxy.lan:443") from None
    return text.strip()


def allowed_host(text: str) -> str:
    """``argparse`` type of ``--console-host`` (:func:`check_allowed`)."""
    try:
        return check_allowed(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def is_local_address(ip: str) -> bool:
    """Whether ``ip`` is an address of this machine: a socket can bind to it."""
    addr = ipaddress.ip_address(ip)
    if addr.is_unspecified or addr.is_multicast or (addr.version == 4 and ip == "255.255.255.255"):
        return False
    family = socket.AF_INET if addr.version == 4 else socket.AF_INET6
    try:
        with socket.socket(family, socket.SOCK_STREAM) as s:
            s.bind((ip, 0))
    except OSError:
        return False
    return True


class HostCheck:
    """The Hosts a console answers to.

    Parameters
    ----------
    bound : iterable of (ip, port)
        The sockets the console listens on (``runner.addresses``).
    scheme : str
        ``http`` or ``https`` (a Host without a port means this scheme's default port).
    names : iterable of str
        Host names it also answers to on its own ports: the ``--console`` host when it is a name.
    allowed : iterable of str
        The allow-list: ``NAME`` (on the console's ports) or ``NAME:PORT``; ValueError if one is malformed.
    is_local : callable
        Whether an IP address is this machine's (injectable; :func:`is_local_address`).
    """

    def __init__(self, bound: Iterable[tuple[str, int]], *, scheme: str = "http", names: Iterable[str] = (),
                 allowed: Iterable[str] = (), is_local: Callable[[str], bool] = is_local_address):
        self.scheme = scheme
        self.default_port = DEFAULT_PORTS[scheme]
        self.bound = [(ipaddress.ip_address(ip.split("%")[0]), int(port)) for ip, port in bound]
        self.ports = {port for _, port in self.bound}
        self.names = set()
        for n in names:
            try:
                self.names.add(normal_host(n))
            except ValueError:      # a listen name no browser can send (e.g. with "_"): only its addresses
                pass
        if any(a.is_loopback or a.is_unspecified for a, _ in self.bound):
            self.names.add("localhost")
        self.allowed: set[tuple[str, int | None]] = {split_host(a) for a in allowed}
        self.is_local = is_local

    def _ip_ok(self, host: str, port: int) -> bool:
        try:
            addr = ipaddress.ip_address(host)
        except ValueError:
            return False
        if addr.is_unspecified:     # http://0.0.0.0:port reaches this machine, but names no address of it
            return False
        for b, bport in self.bound:
            if bport != port or b.version != addr.version:
                continue
            if b == addr:
                return True
            if b.is_unspecified and self.is_local(addr.compressed):
                return True
        return False

    def ok(self, value: str | None) -> bool:
        """Whether a request whose Host header is ``value`` is for this console."""
        if not value:
            return False
        try:
            host, port = split_host(value)
        except ValueError:
            return False
        port = self.default_port if port is None else port
        if (host, port) in self.allowed or ((host, None) in self.allowed and port in self.ports):
            return True
        if host in self.names and port in self.ports:
            return True
        return self._ip_ok(host, port)

    def refusal(self, value: str | None, url: str) -> str:
        """The one line a request with a foreign Host gets (``url``: where the console is)."""
        if not value:
            return f"refused: the request has no Host header; open {url} in a browser"
        try:
            name = split_host(value)[0]
            allow = f"--console-host {name}" if not name.replace(".", "").isdigit() and ":" not in name else None
        except ValueError:
            allow = None
        return (f"refused: Host {value[:100]!r} is not an address of this console (a page of another site may be "
                f"trying to reach it); open {url}, or if that name is this machine's, start the coordinator with "
                f"{allow or '--console-host NAME'}")
