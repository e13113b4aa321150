"""Find coordinators on the local network over mDNS (``_shadowless._tcp.local.``).

The browsing side of the rig's advertisement (the coordinator advertises, see
:data:`protos.version.SERVICE_TYPE`). It lives beside the wire definitions so that
every client of a rig may use it: the node and the operator's tools alike.
"""
from __future__ import annotations

import asyncio
import logging
from dataclasses import dataclass

from zeroconf import InterfaceChoice, IPVersion, ServiceStateChange
from zeroconf.asyncio import AsyncServiceBrowser, AsyncServiceInfo, AsyncZeroconf

from protos.version import SERVICE_TYPE

__all__ = ["Advertisement", "Discovery", "DiscoveryError", "NothingAdvertised"]

log = logging.getLogger(__name__)


class DiscoveryError(RuntimeError):
    """mDNS cannot be used (e.g. no such interface); the message says where it was tried."""


class NothingAdvertised(DiscoveryError):
    """mDNS works but no coordinator (of the rig asked for) is advertised yet: a state to wait out,
    not a failure (a coordinator starting, a network still settling)."""


@dataclass(frozen=True)
class Advertisement:
    name: str          # rig name (mDNS instance)
    rig_id: str
    host: str
    port: int
    protocol: str
    instance: str

    @property
    def target(self) -> str:
        return f"{self.host}:{self.port}"


class Discovery:
    """A long-lived mDNS browser; :meth:`find` returns the rigs currently advertised.

    ``interfaces``: IPv4 addresses to browse on (e.g. ``["127.0.0.1"]``); None = every interface.
    """

    def __init__(self, *, interfaces: list[str] | None = None):
        self.interfaces = interfaces
        self._azc: AsyncZeroconf | None = None
        self._browser: AsyncServiceBrowser | None = None
        self._names: set[str] = set()
        self._changed = asyncio.Event()
        #: counts the advertisements' comings and goings (see :meth:`wait_change`)
        self.generation = 0

    async def start(self) -> None:
        try:
            self._azc = AsyncZeroconf(interfaces=self.interfaces or InterfaceChoice.All, ip_version=IPVersion.V4Only)
        except OSError as exc:
            raise DiscoveryError(f"cannot start mDNS on {self.interfaces or 'all interfaces'}: {exc}") from exc
        self._browser = AsyncServiceBrowser(self._azc.zeroconf, SERVICE_TYPE, handlers=[self._on_change])

    def _on_change(self, zeroconf, service_type: str, name: str, state_change: ServiceStateChange) -> None:
        if state_change is ServiceStateChange.Removed:
            self._names.discard(name)
        else:
            self._names.add(name)
        self.generation += 1
        self._changed.set()

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
            try:
                await asyncio.wait_for(self._changed.wait(), left)
            except asyncio.TimeoutError:
                return self.generation != since
        return True

    async def close(self) -> None:
        if self._browser is not None:
            await self._browser.async_cancel()
        if self._azc is not None:
            await self._azc.async_close()
        self._browser = self._azc = None

    async def _resolve(self, name: str) -> Advertisement | None:
        info = AsyncServiceInfo(SERVICE_TYPE, name)
        if not await info.async_request(self._azc.zeroconf, 1500):
            return None
        props = {k.decode(): (v or b"").decode() for k, v in info.properties.items()}
        addrs = info.parsed_addresses(IPVersion.V4Only)
        if not addrs or not info.port:
            return None
        return Advertisement(name=props.get("name") or name.removesuffix("." + SERVICE_TYPE), rig_id=props.get("rig", ""),
                             host=addrs[0], port=info.port, protocol=props.get("proto", ""),
                             instance=props.get("instance", ""))

    async def find(self, *, rig: str | None = None, timeout: float = 3.0, settle: float = 0.0) -> list[Advertisement]:
        """Advertised rigs matching ``rig`` (name or id), waiting up to ``timeout`` for a first one,
        then ``settle`` seconds more for the others to answer (so a caller choosing among them sees
        them all, not just the quickest)."""
        assert self._azc is not None, "call start() first"
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        settled_at: float | None = None
        while True:
            # resolved at once: an advertiser that never answers costs one resolve timeout, not one each
            ads = await asyncio.gather(*(self._resolve(name) for name in sorted(self._names)))
            found = [ad for ad in ads if ad is not None and (rig is None or rig in (ad.name, ad.rig_id))]
            if found and settled_at is None:
                settled_at = loop.time() + settle
            now = loop.time()
            if (found and now >= settled_at) or now >= deadline:
                return found
            self._changed.clear()
            until = min(deadline, settled_at) if settled_at is not None else deadline
            try:
                await asyncio.wait_for(self._changed.wait(), max(0.05, until - now))
            except asyncio.TimeoutError:
                pass
