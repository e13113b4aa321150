"""Find coordinators on the local network over mDNS (``_shadowless._tcp.local.``).

The browsing side of the rig's advertisement (the coordinator advertises, see
:data:`protos.version.SERVICE_TYPE`). It lives beside the wire definitions so that
every client of a rig may use it: the node and the operator's tools alike.

**Every answer counts, not every name.** Two responders may advertise one instance name: a
second coordinator that did not rename itself, or a hostile advertiser that skips conflict
probing (RFC 6762 §9) on purpose. A cache keyed by name keeps one of them (each answer's
cache-flush bit evicts the other's records), and a browser that resolves names sees only that
one. So this module does not resolve names: it listens to every response on the wire
(:class:`_Sightings`, a zeroconf record listener called once per received message) and keeps
every distinct ``(address, port)`` that an SRV record (with the A records and TXT of the same
message) ever named, until that SRV record's TTL runs out or its responder says goodbye. Callers
choose among them by the rig id and name in the TXT record and let the token handshake reject
impostors. Queries are sent as QM questions (answers multicast): a QU question's unicast answer
on a host where several processes share port 5353 reaches one of them at random.
"""
from __future__ import annotations

import asyncio
import ipaddress
import logging
import socket
import time
from dataclasses import dataclass

from zeroconf import (DNSAddress, DNSOutgoing, DNSPointer, DNSQuestion, DNSService, DNSText, InterfaceChoice,
                      IPVersion, RecordUpdateListener, Zeroconf, current_time_millis)
from zeroconf.asyncio import AsyncZeroconf
from zeroconf.const import _CLASS_IN, _FLAGS_QR_QUERY, _TYPE_A, _TYPE_PTR, _TYPE_TXT

from protos.version import SERVICE_TYPE

__all__ = ["Advertisement", "Discovery", "DiscoveryError", "NothingAdvertised", "check_interfaces", "names_in_use",
           "parse_txt"]

log = logging.getLogger(__name__)

#: most distinct (address, port) pairs kept (a flood of fake answers evicts the least recently seen)
MAX_SIGHTINGS = 256
#: shortest interval between two of our own queries (RFC 6762 §5.2: at least one second, then at
#: least doubling, here up to QUERY_MAX_INTERVAL_S; back to the shortest when what answers changes)
QUERY_INTERVAL_S = 1.0
QUERY_MAX_INTERVAL_S = 16.0


class DiscoveryError(RuntimeError):
    """mDNS cannot be used (e.g. no such interface); the message says where it was tried."""


class NothingAdvertised(DiscoveryError):
    """mDNS works but no coordinator (of the rig asked for) is advertised yet: a state to wait out,
    not a failure (a coordinator starting, a network still settling)."""


@dataclass(frozen=True)
class Advertisement:
    name: str          # rig name (TXT ``name``; the mDNS instance name without its type if absent)
    rig_id: str
    host: str
    port: int
    protocol: str
    instance: str
    service_name: str = ""   # the mDNS instance name that carried it (e.g. ``table-2._shadowless._tcp.local.``)

    @property
    def target(self) -> str:
        return f"{self.host}:{self.port}"


def parse_txt(data: bytes) -> dict[str, str]:
    """A TXT record's rdata (length-prefixed ``key=value`` strings, RFC 6763 §6) as a dict; the first
    occurrence of a key wins, keys are lower-cased, undecodable bytes are replaced; a truncated
    string ends the parse."""
    out: dict[str, str] = {}
    i = 0
    while i < len(data):
        n = data[i]
        item = data[i + 1:i + 1 + n]
        i += 1 + n
        if len(item) < n:
            break
        key, _, value = item.partition(b"=")
        k = key.decode("ascii", "replace").lower()
        if k and k not in out:
            out[k] = value.decode("utf-8", "replace")
    return out


@dataclass
class _Sighting:
    ad: Advertisement
    srv: tuple[str, str, int]   # (instance name, server, port), lower-cased: what a goodbye names
    expires_ms: float
    seen_ms: float


class _Sightings(RecordUpdateListener):
    """Every ``(address, port)`` that a response on the wire named for ``service_type``.

    zeroconf calls :meth:`async_update_records` once per received message, with every record of
    it (answers and additionals), before its cache applies them; records of one message come from
    one responder, so an SRV record is paired with the A records and TXT of the same message (or,
    if the message lacks them, with what the cache holds for its server and name).
    """

    def __init__(self, service_type: str, on_change):
        super().__init__()
        self.suffix = "." + service_type.lower()
        self.on_change = on_change
        self.seen: dict[tuple[str, int], _Sighting] = {}
        #: every instance name a PTR or SRV record named (lower-cased) -> when it expires (ms)
        self.names: dict[str, float] = {}

    def async_update_records(self, zc, now: float, records) -> None:
        srvs: list[DNSService] = []
        txts: dict[str, DNSText] = {}
        addrs: dict[str, list[DNSAddress]] = {}
        for update in records:
            rec = update.new
            name = rec.name.lower()
            if isinstance(rec, DNSService) and name.endswith(self.suffix):
                srvs.append(rec)
            elif isinstance(rec, DNSText) and name.endswith(self.suffix):
                txts[name] = rec
            elif isinstance(rec, DNSAddress) and rec.type == _TYPE_A:
                addrs.setdefault(name, []).append(rec)
            elif isinstance(rec, DNSPointer) and rec.alias.lower().endswith(self.suffix):
                self._name(rec.alias.lower(), rec, now)
        changed = False
        # only an SRV record's goodbye ends a sighting: responders may share a host name and address
        # (two coordinators on one machine), and one's address goodbye says nothing of the other
        for srv in srvs:
            key = (srv.name.lower(), srv.server.lower(), srv.port)
            self._name(key[0], srv, now)
            if srv.ttl == 0 or srv.is_expired(now):
                changed |= self._drop(lambda s: s.srv == key)
                continue
            a_recs = addrs.get(key[1]) or self._cached(zc, srv.server, _TYPE_A, now)
            txt = txts.get(key[0]) or next(iter(self._cached(zc, srv.name, _TYPE_TXT, now)), None)
            props = parse_txt(txt.text) if txt is not None else {}
            for a in a_recs:
                ip = _ip(a)
                if ip is None or a.ttl == 0:
                    continue
                ad = Advertisement(name=props.get("name") or srv.name[:len(srv.name) - len(self.suffix)],
                                   rig_id=props.get("rig", ""), host=ip, port=srv.port,
                                   protocol=props.get("proto", ""), instance=props.get("instance", ""),
                                   service_name=srv.name)
                old = self.seen.pop((ip, srv.port), None)
                self.seen[(ip, srv.port)] = _Sighting(ad, key, now + srv.ttl * 1000.0, now)
                changed |= old is None or old.ad != ad
        while len(self.seen) > MAX_SIGHTINGS:   # dicts keep insertion order: the least recently seen first
            self.seen.pop(next(iter(self.seen)))
            changed = True
        if changed:
            self.on_change()

    def _name(self, name: str, rec, now: float) -> None:
        if rec.ttl == 0:
            self.names.pop(name, None)
        elif len(self.names) < MAX_SIGHTINGS or name in self.names:
            self.names[name] = max(self.names.get(name, 0.0), now + rec.ttl * 1000.0)

    @staticmethod
    def _cached(zc, name: str, type_: int, now: float) -> list:
        return [r for r in zc.cache.async_all_by_details(name, type_, _CLASS_IN) if not r.is_expired(now)]

    def _drop(self, match) -> bool:
        gone = [k for k, s in self.seen.items() if match(s)]
        for k in gone:
            del self.seen[k]
        return bool(gone)

    def current(self, now: float) -> list[Advertisement]:
        expired = [k for k, s in self.seen.items() if s.expires_ms <= now]
        for k in expired:
            del self.seen[k]
        if expired:
            self.on_change()
        return [s.ad for s in self.seen.values()]


def _ip(rec: DNSAddress) -> str | None:
    return socket.inet_ntoa(rec.address) if len(rec.address) == 4 else None


def check_interfaces(interfaces: list[str] | None) -> list[str] | None:
    """``interfaces`` if each is an IPv4 address in dotted form; DiscoveryError naming the first that is
    not (one line: what is wrong and what to pass instead)."""
    for ip in interfaces or ():
        try:
            ipaddress.IPv4Address(ip)
        except ValueError:
            raise DiscoveryError(f"--mdns-interface {ip!r} is not an IPv4 address: pass one of this machine's "
                                 "addresses (e.g. 192.168.1.20), or leave it out to use every interface") from None
    return interfaces


def _query_message(service_type: str) -> DNSOutgoing:
    """A QM question for the service's instances, no known answers: every responder answers, by
    multicast, with its SRV, TXT and A records as additionals."""
    out = DNSOutgoing(_FLAGS_QR_QUERY)
    out.add_question(DNSQuestion(service_type, _TYPE_PTR, _CLASS_IN))
    return out


async def names_in_use(zc: Zeroconf, service_type: str, *, wait_s: float = 1.0) -> set[str]:
    """The instance names of ``service_type`` (lower-cased, e.g. ``table._shadowless._tcp.local.``) that
    answer a query on ``zc``'s interfaces within ``wait_s`` seconds: what a responder about to claim a
    name must not take (RFC 6762 §9). Asks twice, at the start and half-way (an answer a responder
    sent less than a second before is delayed by up to a second, RFC 6762 §6)."""
    sightings = _Sightings(service_type, lambda: None)
    zc.async_add_listener(sightings, None)
    try:
        zc.async_send(_query_message(service_type))
        await asyncio.sleep(wait_s / 2)
        zc.async_send(_query_message(service_type))
        await asyncio.sleep(wait_s / 2)
    finally:
        zc.async_remove_listener(sightings)
    now = current_time_millis()
    return {n for n, exp in sightings.names.items() if exp > now}


class Discovery:
    """A long-lived mDNS browser; :meth:`find` returns the coordinators currently advertised, one
    :class:`Advertisement` per distinct ``(address, port)`` that answered.

    ``interfaces``: IPv4 addresses to browse on (e.g. ``["127.0.0.1"]``); None = every interface.
    ``service_type``: the service browsed (default :data:`protos.version.SERVICE_TYPE`).
    """

    def __init__(self, *, interfaces: list[str] | None = None, service_type: str | None = None):
        self.interfaces = interfaces
        self.service_type = service_type or SERVICE_TYPE
        self._azc: AsyncZeroconf | None = None
        self._sightings = _Sightings(self.service_type, self._bump)
        self._changed = asyncio.Event()
        self._last_query = -1e9
        self._interval = QUERY_INTERVAL_S
        #: counts the advertisements' comings and goings (see :meth:`wait_change`)
        self.generation = 0

    def nothing_found(self, timeout: float, rig: str | None = None) -> str:
        """The one line that says nothing was found: the service, where, and for how long."""
        return (f"no coordinator advertised {self.service_type}{f' for rig {rig!r}' if rig else ''} on "
                f"{', '.join(self.interfaces) if self.interfaces else 'any interface'} within {timeout:g} s")

    async def start(self) -> None:
        check_interfaces(self.interfaces)
        try:
            self._azc = AsyncZeroconf(interfaces=self.interfaces or InterfaceChoice.All, ip_version=IPVersion.V4Only)
            await self._azc.zeroconf.async_wait_for_start()
        except OSError as exc:
            where = ", ".join(self.interfaces) if self.interfaces else "every interface"
            raise DiscoveryError(f"cannot browse {self.service_type} over mDNS on {where}: "
                                 f"{exc.strerror or exc} (is it an address of this machine? see `ip -4 addr`)") from exc
        self._azc.zeroconf.async_add_listener(self._sightings, None)
        self._query()

    def _bump(self) -> None:
        self.generation += 1
        self._interval = QUERY_INTERVAL_S
        self._changed.set()

    def _query(self) -> None:
        """Ask every responder for the service's instances (QM: the answers come by multicast, with
        the SRV, TXT and A records as additionals), at intervals from QUERY_INTERVAL_S doubling to
        QUERY_MAX_INTERVAL_S (a coordinator that starts announces itself meanwhile)."""
        now = time.monotonic()
        gap = now - self._last_query
        if self._azc is None or gap < self._interval:
            return
        # after a long quiet spell (a node that was joined for hours) the next ones come quickly again
        self._interval = QUERY_INTERVAL_S if gap > 2 * QUERY_MAX_INTERVAL_S else min(QUERY_MAX_INTERVAL_S,
                                                                                      2 * self._interval)
        self._last_query = now
        self._azc.zeroconf.async_send(_query_message(self.service_type))

    async def wait_change(self, since: int, timeout: float) -> bool:
        """Wait up to ``timeout`` seconds for an advertisement to come or go after ``generation``
        was ``since``; True if one did."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        while self.generation == since:
            left = deadline - loop.time()
            if left <= 0:
                return False
            self._changed.clear()
            try:    # not wait_for: on 3.11 it drops a cancel that meets a sighting, and the caller ran on
                async with asyncio.timeout(left):
                    await self._changed.wait()
            except TimeoutError:
                return self.generation != since
        return True

    async def close(self) -> None:
        if self._azc is not None:
            self._azc.zeroconf.async_remove_listener(self._sightings)
            await self._azc.async_close()
        self._azc = None

    def current(self, rig: str | None = None) -> list[Advertisement]:
        """What answered and has not expired or said goodbye (matching ``rig``: name or id)."""
        ads = self._sightings.current(current_time_millis())
        return [a for a in ads if rig is None or rig in (a.name, a.rig_id)]

    async def find(self, *, rig: str | None = None, timeout: float = 3.0, settle: float = 0.0) -> list[Advertisement]:
        """Advertised coordinators matching ``rig`` (name or id), waiting up to ``timeout`` for a first
        one, then ``settle`` seconds more for the others to answer (so a caller choosing among them sees
        them all, not just the quickest). Asks the network again while it waits (see :meth:`_query`)."""
        assert self._azc is not None, "call start() first"
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        settled_at: float | None = None
        self._query()
        while True:
            found = self.current(rig)
            now = loop.time()
            if found and settled_at is None:
                settled_at = now + settle
            if (found and now >= settled_at) or now >= deadline:
                return found
            self._changed.clear()
            until = min(deadline, settled_at) if settled_at is not None else deadline
            until = min(until, now + QUERY_INTERVAL_S)
            try:    # not wait_for: on 3.11 it drops a cancel that meets a sighting
                async with asyncio.timeout(max(0.05, until - now)):
                    await self._changed.wait()
            except TimeoutError:
                pass
            self._query()
