"""Advertise the coordinator as ``_shadowless._tcp.local.`` (zeroconf)."""
from __future__ import annotations

import logging
import socket

from zeroconf import InterfaceChoice, IPVersion, NonUniqueNameException
from zeroconf.asyncio import AsyncServiceInfo, AsyncZeroconf

from coordinator.errors import CoordinatorError
from protos.version import PROTOCOL_VERSION, SERVICE_TYPE

log = logging.getLogger(__name__)


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
    tests), or None for every interface.
    """

    def __init__(self, *, rig_name: str, rig_id: str, instance_id: str, port: int, interfaces: list[str] | None):
        self.rig_name, self.rig_id, self.instance_id, self.port = rig_name, rig_id, instance_id, port
        self.interfaces = interfaces
        self._azc: AsyncZeroconf | None = None
        self._info: AsyncServiceInfo | None = None

    @property
    def name(self) -> str:
        return self._info.name if self._info else ""

    async def start(self) -> None:
        addresses = self.interfaces or _local_ipv4_addresses()
        try:
            self._azc = AsyncZeroconf(interfaces=self.interfaces or InterfaceChoice.All, ip_version=IPVersion.V4Only)
        except OSError as exc:
            raise CoordinatorError(f"cannot start mDNS on {self.interfaces or 'all interfaces'}: {exc}") from exc
        host = socket.gethostname().split(".")[0] or "coordinator"
        self._info = AsyncServiceInfo(
            SERVICE_TYPE,
            f"{self.rig_name}.{SERVICE_TYPE}",
            addresses=[socket.inet_aton(a) for a in addresses],
            port=self.port,
            properties={"rig": self.rig_id, "proto": str(PROTOCOL_VERSION), "instance": self.instance_id, "name": self.rig_name},
            server=f"{host}-{self.rig_id}.local.",
        )
        try:
            await self._azc.async_register_service(self._info, allow_name_change=True)
        except NonUniqueNameException as exc:  # pragma: no cover - allow_name_change avoids it
            raise CoordinatorError(f"another service already uses the mDNS name {self._info.name}") from exc
        log.info("advertising %s on %s port %d", self._info.name, ", ".join(addresses), self.port)

    async def stop(self) -> None:
        if self._azc is None:
            return
        try:
            if self._info is not None:
                await self._azc.async_unregister_service(self._info)
        finally:
            await self._azc.async_close()
            self._azc = None
