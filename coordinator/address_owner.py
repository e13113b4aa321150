"""Whose limits a network address draws on, for the budgets that count per peer (calls before
authentication, console logins): an IPv4 address is its own; an IPv4-mapped IPv6 address
(``::ffff:a.b.c.d``) is that IPv4 peer; any other IPv6 address counts as its /64, since one host
or link commonly holds a whole /64 and per address would be no limit there (loopback stays itself)."""
from __future__ import annotations

import ipaddress

__all__ = ["address_owner"]


def address_owner(address: str) -> str:
    """The key ``address`` (an IP address without port, or any other text) is counted under:
    ``"10.0.0.5"``, ``"::ffff:10.0.0.5"`` -> ``"10.0.0.5"``, ``"2001:db8::1"`` -> ``"2001:db8::/64"``;
    text that is no IP address is returned unchanged."""
    try:
        ip = ipaddress.ip_address(address)
    except ValueError:
        return address
    if ip.version == 6:
        if ip.ipv4_mapped is not None:
            return str(ip.ipv4_mapped)
        if not ip.is_loopback:
            return str(ipaddress.ip_network(f"{ip}/64", strict=False))
    return str(ip)
