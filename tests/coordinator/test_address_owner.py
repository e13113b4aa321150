"""Whose per-peer limits an address draws on: checked against the standard library's own network
arithmetic (ipaddress.ip_network) on generated addresses, and on the forms gRPC and aiohttp give."""
from __future__ import annotations

import ipaddress
import random

from coordinator.address_owner import address_owner
from coordinator.admission import budget_key


def test_ipv4_is_its_own_mapped_ipv4_is_that_peer_and_ipv6_counts_per_64():
    assert address_owner("10.0.0.5") == "10.0.0.5"
    assert address_owner("::ffff:10.0.0.5") == "10.0.0.5"
    assert address_owner("2001:db8::1") == address_owner("2001:db8::ffff:1") == "2001:db8::/64"
    assert address_owner("2001:db8:0:1::1") == "2001:db8:0:1::/64"
    assert address_owner("::1") == "::1"
    assert address_owner("unix:/run/x.sock") == "unix:/run/x.sock"


def test_two_ipv6_addresses_share_an_owner_exactly_when_they_share_a_64():
    rng = random.Random(35)
    for _ in range(2000):
        a = ipaddress.IPv6Address(rng.getrandbits(128) | (0x2000 << 112))
        b = ipaddress.IPv6Address(int(a) ^ rng.choice([0, 1 << rng.randrange(0, 64), 1 << rng.randrange(64, 110)]))
        same_64 = ipaddress.ip_network(f"{a}/64", strict=False) == ipaddress.ip_network(f"{b}/64", strict=False)
        assert (address_owner(str(a)) == address_owner(str(b))) is same_64, (a, b)


def test_the_budget_reads_grpc_peer_strings():
    assert budget_key("ipv4:10.0.0.5:51234") == "10.0.0.5"
    assert budget_key("ipv6:[2001:db8::7]:5000") == "2001:db8::/64"
    assert budget_key("ipv6:[::ffff:10.0.0.5]:5000") == "10.0.0.5"
