"""Advertise the coordinator as ``_shadowless._tcp.local.`` (zeroconf).

The instance name is the rig's name, unless another responder already answers for it: then the
coordinator takes ``NAME-2`` (``-3``, ...), as RFC 6762 §9 asks, and says so in its log. Before
claiming a name it asks the network which instances of the service exist (QM questions, so the
answers come by multicast: on one host several processes share port 5353, and the unicast answer
to zeroconf's own QU probe reaches one of them at random), then zeroconf probes the chosen name
(``allow_name_change=True`` renames it again if a late answer shows a conflict). The TXT record
keeps the rig's own name and id, by which nodes and operators find it whatever the instance name.

A responder that claims the name later, without probing (a hostile advertiser, or a program that
ignores RFC 6762), is logged once per address it points at (:mod:`coordinator.mdns_squatters`); the coordinator
keeps its name rather than renaming after it (an advertiser that follows every rename would keep it
renaming forever, and nodes find the rig by its id and token all the same).
"""
from __future__ import annotations

import logging
import socket
from typing import Any

from coordinator.errors import CoordinatorError
from protos.version import PROTOCOL_VERSION, SERVICE_TYPE

log = logging.getLogger(__name__)

#: how long the coordinator listens for other instances of the service before it claims a name
PROBE_WAIT_S = 1.0


def free_instance_name(base: str, service_type: str, taken: set[str]) -> str:
    """``base`` if ``BASE.SERVICE_TYPE`` is not in ``taken`` (lower-cased full names), else the first of
    ``base-2``, ``base-3``, ... that is not (python-zeroconf's and Apple's renaming scheme)."""
    name, k = base, 2
    while f"{name}.{service_type}".lower() in taken:
        name, k = f"{base}-{k}", k + 1
    return name


def _local_ipv4_addresses() -> list[str]:
    import ifaddr  # a dependency of zeroconf

    addrs = []
    for adapter in ifaddr.get_adapters():
        for ip in adapter.ips:
            if isinstance(ip.ip, str) and not ip.ip.startswith("127."):
                addrs.append(ip.ip)
    return addrs or ["127.0.0.1"]


class Advertiser:
    """Registers the rig on the chosen interfaces; unregisters on :meth:`stop`.

    ``interfaces``: IPv4 addresses to advertise on (e.g. ``["127.0.0.1"]`` in
    tests), or None for every interface; one that is no IPv4 address is refused here, so a
    coordinator makes its Advertiser before it listens. The port comes with :meth:`start`.
    """

    def __init__(self, *, rig_name: str, rig_id: str, instance_id: str, interfaces: list[str] | None):
        from protos.discovery import DiscoveryError, check_interfaces   # zeroconf: only when advertising
        try:
            check_interfaces(interfaces)
        except DiscoveryError as exc:
            raise CoordinatorError(str(exc)) from None
        self.rig_name, self.rig_id, self.instance_id, self.port = rig_name, rig_id, instance_id, 0
        self.interfaces = interfaces
        self._azc: Any = None          # zeroconf.asyncio.AsyncZeroconf, once started
        self._info: Any = None         # zeroconf.asyncio.AsyncServiceInfo
        self._squatters: Any = None    # coordinator.mdns_squatters.Squatters, once started

    @property
    def name(self) -> str:
        return self._info.name if self._info else ""

    async def start(self, port: int) -> None:
        """Claim a free instance name and advertise the coordinator's gRPC ``port``."""
        from zeroconf import InterfaceChoice, IPVersion, NonUniqueNameException
        from zeroconf.asyncio import AsyncServiceInfo, AsyncZeroconf

        from coordinator.mdns_squatters import Squatters
        from protos.discovery import names_in_use
        self.port = port
        addresses = self.interfaces or _local_ipv4_addresses()
        try:
            self._azc = AsyncZeroconf(interfaces=self.interfaces or InterfaceChoice.All, ip_version=IPVersion.V4Only)
        except OSError as exc:
            raise CoordinatorError(f"cannot advertise {SERVICE_TYPE} over mDNS on "
                                   f"{', '.join(self.interfaces) if self.interfaces else 'every interface'}: "
                                   f"{exc.strerror or exc} (is it an address of this machine? see `ip -4 addr`)") from exc
        host = socket.gethostname().split(".")[0] or "coordinator"
        await self._azc.zeroconf.async_wait_for_start()
        taken = await names_in_use(self._azc.zeroconf, SERVICE_TYPE, wait_s=PROBE_WAIT_S)
        instance = free_instance_name(self.rig_name, SERVICE_TYPE, taken)
        self._info = AsyncServiceInfo(
            SERVICE_TYPE,
            f"{instance}.{SERVICE_TYPE}",
            addresses=[socket.inet_aton(a) for a in addresses],
            port=self.port,
            properties={"rig": self.rig_id, "proto": str(PROTOCOL_VERSION), "instance": self.instance_id, "name": self.rig_name},
            server=f"{host}-{self.rig_id}.local.",
        )
        try:
            await self._azc.async_register_service(self._info, allow_name_change=True)
        except NonUniqueNameException as exc:  # pragma: no cover - allow_name_change avoids it
            raise CoordinatorError(f"another service already uses the mDNS name {self._info.name}") from exc
        wanted = f"{self.rig_name}.{SERVICE_TYPE}"
        if self._info.name != wanted:
            log.warning("the mDNS name %s is already answered for on %s (another rig of that name, or an "
                        "advertiser that did not probe for it): advertising as %s instead (RFC 6762 section 9); "
                        "nodes and operators find this rig by its id %s all the same", wanted,
                        ", ".join(addresses), self._info.name, self.rig_id)
        log.info("advertising %s on %s port %d", self._info.name, ", ".join(addresses), self.port)
        self._squatters = Squatters(self._info.name, self._info.server, self.port)
        self._azc.zeroconf.async_add_listener(self._squatters, None)

    async def stop(self) -> None:
        if self._azc is None:
            return
        try:
            if self._squatters is not None:
                self._azc.zeroconf.async_remove_listener(self._squatters)
                self._squatters = None
            if self._info is not None:
                await self._azc.async_unregister_service(self._info)
        finally:
            await self._azc.async_close()
            self._azc = None
