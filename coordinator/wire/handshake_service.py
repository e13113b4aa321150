"""The first half of the rig-token handshake, served the same on NodeLink and RigControl.

:class:`HandshakeService` answers Hello (the coordinator proves the token) and checks a Join's
or a Login's proof; :mod:`coordinator.sessions` holds the handshake itself.
"""
from __future__ import annotations

from coordinator.ports import ServiceRig
from coordinator.wire.calls import guard, peer
from protos import common_pb2
from protos.version import PROTOCOL_VERSION


class HandshakeService:
    """The base of both services: ``self.c`` is the coordinator as the services see it."""

    def __init__(self, coord: ServiceRig):
        self.c = coord

    @guard
    async def Hello(self, request, context):
        r = self.c.handshake.hello(protocol_version=request.protocol_version, client_nonce=request.client_nonce,
                                   role=request.role, slot=request.slot, peer=peer(context))
        return common_pb2.HelloReply(protocol_version=PROTOCOL_VERSION, rig_id=r.rig_id, rig_name=r.rig_name,
                                     server_nonce=r.server_nonce, server_proof=r.server_proof, instance_id=r.instance_id)

    def _check_login(self, login, context, role: str) -> None:
        self.c.handshake.check_login(protocol_version=login.protocol_version, role=login.role, slot=login.slot,
                                     client_nonce=login.client_nonce, server_nonce=login.server_nonce,
                                     client_proof=login.client_proof, peer=peer(context), expected_role=role)
