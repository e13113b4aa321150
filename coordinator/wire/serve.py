"""The coordinator's gRPC server: NodeLink, RigControl and ContentStore on one port, with the
budget for calls before authentication in front (:mod:`coordinator.wire.admission_interceptor`)
and the standard health and reflection services beside them.

:func:`serve` is called by whoever composes the coordinator; the coordinator itself knows no
listening address.
"""
from __future__ import annotations

import errno
import logging
import os
import socket

import grpc
from grpc_health.v1 import health, health_pb2, health_pb2_grpc
from grpc_reflection.v1alpha import reflection

from coordinator.errors import CoordinatorError
from coordinator.ports import ServiceRig
from coordinator.wire import content_service
from coordinator.wire.admission_interceptor import Admission
from coordinator.wire.control_service import RigControlService
from coordinator.wire.node_service import NodeLinkService, add_node_link
from protos import control_pb2, control_pb2_grpc, node_pb2
from protos.version import COORDINATOR_GRPC_OPTIONS

log = logging.getLogger(__name__)

SERVER_OPTIONS = COORDINATOR_GRPC_OPTIONS + [("grpc.so_reuseport", 0)]
#: set to "off", the server runs without the budget for calls before authentication: what
#: `shadowless bench preauth --compare` measures as "before" (never for a rig in use)
BUDGET_OFF_ENV = "SHADOWLESS_PREAUTH_BUDGET"


def check_free(listen: str) -> None:
    """Refuse, in one line of ours, an address whose port another process holds: bound by gRPC,
    its C core logs its own error line first. A plain bind (with SO_REUSEADDR, as gRPC binds) on
    every address ``HOST`` resolves to, closed at once. Port 0 and unix sockets are not checked."""
    host, _, port = listen.rpartition(":")
    if listen.startswith("unix:") or not port.isdigit() or int(port) == 0:
        return
    host = host.strip("[]")
    try:
        infos = socket.getaddrinfo(host or None, int(port), type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except socket.gaierror as exc:
        raise CoordinatorError(f"cannot listen on {listen}: {host!r} is not an address of this host "
                               f"({exc.strerror}); give --listen HOST:PORT with one of its addresses") from None
    for family, kind, proto, _, addr in infos:
        with socket.socket(family, kind, proto) as sock:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                sock.bind(addr)
            except OSError as exc:
                if exc.errno == errno.EADDRINUSE:
                    raise CoordinatorError(f"cannot listen on {listen}: port {port} is in use (another coordinator? "
                                           "stop it, or give --listen HOST:PORT another port)") from None
                if exc.errno == errno.EADDRNOTAVAIL:
                    raise CoordinatorError(f"cannot listen on {listen}: {host} is not an address of this host; "
                                           "give --listen HOST:PORT with one of its addresses") from None
                raise CoordinatorError(f"cannot listen on {listen}: {exc.strerror}") from None


async def serve(coordinator: ServiceRig, listen: str, *, tls: tuple[bytes, bytes] | None = None):
    """Start the gRPC server for ``coordinator``; returns ``(server, health servicer, port)``."""
    interceptors = [Admission(coordinator)]
    if os.environ.get(BUDGET_OFF_ENV) == "off":     # bench preauth's "before" only
        log.warning("%s=off: calls before authentication have no budget (for measurements only)", BUDGET_OFF_ENV)
        interceptors = []
    server = grpc.aio.server(options=SERVER_OPTIONS, interceptors=interceptors)
    add_node_link(server, NodeLinkService(coordinator))
    control_pb2_grpc.add_RigControlServicer_to_server(RigControlService(coordinator), server)
    content_service.add_to_server(server, coordinator.asset_store, coordinator.handshake)
    health_servicer = health.aio.HealthServicer()
    health_pb2_grpc.add_HealthServicer_to_server(health_servicer, server)
    names = (
        node_pb2.DESCRIPTOR.services_by_name["NodeLink"].full_name,
        control_pb2.DESCRIPTOR.services_by_name["RigControl"].full_name,
        control_pb2.DESCRIPTOR.services_by_name["ContentStore"].full_name,
        health_pb2.DESCRIPTOR.services_by_name["Health"].full_name,
        reflection.SERVICE_NAME,
    )
    reflection.enable_server_reflection(names, server)
    check_free(listen)
    try:
        if tls:
            creds = grpc.ssl_server_credentials([(tls[1], tls[0])])
            port = server.add_secure_port(listen, creds)
        else:
            port = server.add_insecure_port(listen)
    except RuntimeError as exc:
        raise CoordinatorError(f"cannot listen on {listen}: {exc}") from exc
    if not port:
        raise CoordinatorError(f"cannot listen on {listen} (address in use or not on this host?)")
    await server.start()
    for name in names[:4]:
        await health_servicer.set(name, health_pb2.HealthCheckResponse.SERVING)
    await health_servicer.set("", health_pb2.HealthCheckResponse.SERVING)
    return server, health_servicer, port
