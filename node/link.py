"""The node's gRPC client of the coordinator's ``NodeLink`` service.

:class:`CoordinatorLink` wraps one channel and speaks :mod:`node.records` dataclasses:
the messages are built and parsed by :mod:`node.wire`, and every failed call raises
:class:`LinkError` (never a gRPC exception), so the rest of the node knows nothing of
gRPC or protobuf.
"""
from __future__ import annotations

import asyncio
import logging
import os
import re
from collections.abc import AsyncIterable, AsyncIterator
from contextlib import contextmanager

import grpc

from node import wire
from node.errors import NodeError
from node.records import (AssignmentBytes, BlobChunkData, HelloReply, JoinReply, JoinRequest, PingReply, ReportBatch,
                          ShowUpdateData, WantedAssets)
from protos import node_pb2, node_pb2_grpc
from protos.version import GRPC_OPTIONS, SESSION_KEY

log = logging.getLogger("node")

#: status codes by which a coordinator refuses a node (it will not change its mind on a retry)
REFUSAL_CODES = frozenset({grpc.StatusCode.FAILED_PRECONDITION, grpc.StatusCode.UNAUTHENTICATED,
                           grpc.StatusCode.NOT_FOUND, grpc.StatusCode.INVALID_ARGUMENT,
                           grpc.StatusCode.PERMISSION_DENIED, grpc.StatusCode.ALREADY_EXISTS})


#: a link first opens a bare TCP connection to its target (and closes it), within this long: a
#: coordinator that is down costs a refused connect (about 0.2 ms of CPU) instead of a gRPC
#: channel built, tried and torn down (about 2 ms), once a second on every node playing on alone
PROBE_TIMEOUT_S = 2.5
#: the targets probed so: HOST:PORT or [IPV6]:PORT (other gRPC target forms go to gRPC untried)
_HOST_PORT = re.compile(r"^(\[[0-9A-Fa-f:.]+\]|[^:/\[\]]+):(\d{1,5})$")


class LinkError(NodeError):
    """A call to the coordinator failed: ``code`` (a gRPC status name) and ``details``."""

    def __init__(self, code: str, details: str, *, refused: bool = False):
        super().__init__(f"{code}: {details}")
        self.code = code
        self.details = details
        #: the coordinator refused (protocol, token, slot): retrying soon will not help
        self.refused = refused


async def probe(target: str, timeout: float = PROBE_TIMEOUT_S) -> None:
    """Open a TCP connection to ``target`` (HOST:PORT) and close it at once; LinkError ``UNAVAILABLE``
    when it is refused or not taken within ``timeout`` seconds (a target of another form passes)."""
    m = _HOST_PORT.match(target)
    if m is None:
        return
    host, port = m.group(1).strip("[]"), int(m.group(2))
    try:
        async with asyncio.timeout(timeout):    # not wait_for: on 3.11 it drops a cancel that meets the connect
            _, writer = await asyncio.open_connection(host, port)
    except (asyncio.TimeoutError, TimeoutError):
        raise LinkError("UNAVAILABLE", f"{target} took no connection within {timeout:g} s") from None
    except OSError as exc:
        why = os.strerror(exc.errno).lower() if exc.errno else str(exc)
        raise LinkError("UNAVAILABLE", f"cannot connect to {target}: {why}") from None
    writer.close()
    try:
        await writer.wait_closed()
    except OSError:
        pass


@contextmanager
def _translated():
    try:
        yield
    except grpc.aio.AioRpcError as exc:
        code = exc.code()
        raise LinkError(code.name, exc.details() or "", refused=code in REFUSAL_CODES) from exc


class CoordinatorLink:
    """One connection to a coordinator (``async with``): handshake, streams and pings.

    Parameters
    ----------
    target : str
        ``HOST:PORT``.
    tls_ca : bytes, optional
        PEM of the CA to trust; None connects without TLS.
    tls_server_name : str, optional
        The name expected in the coordinator's certificate (if not the host).
    own_connection : bool
        Give this link's channel a TCP connection of its own. gRPC lets channels of one process to
        one target share a connection; real nodes, one process each, do not, and a coordinator
        serving 256 connections works more (reads, wake-ups) than one serving 256 nodes multiplexed
        on one, so the swarm's links take this to load a coordinator as real nodes do. (The bulk
        channel always has a connection of its own.)
    """

    def __init__(self, target: str, *, tls_ca: bytes | None = None, tls_server_name: str | None = None,
                 own_connection: bool = False):
        self.target = target
        self._settings = (tls_ca, tls_server_name, own_connection)
        self._md: tuple = ()

    def _open(self) -> None:
        """The channels (made once the target took a TCP connection: see :func:`probe`)."""
        tls_ca, tls_server_name, own_connection = self._settings
        target = self.target
        options = list(GRPC_OPTIONS)
        if tls_ca is not None and tls_server_name:
            options.append(("grpc.ssl_target_name_override", tls_server_name))
        own = [("grpc.use_local_subchannel_pool", 1)]

        def channel(opts: list) -> grpc.aio.Channel:
            if tls_ca is not None:
                return grpc.aio.secure_channel(target, grpc.ssl_channel_credentials(root_certificates=tls_ca), options=opts)
            return grpc.aio.insecure_channel(target, options=opts)

        self._channel = channel(options + own if own_connection else options)
        self._stub = node_pb2_grpc.NodeLinkStub(self._channel)
        # Asset downloads travel on a connection of their own (a channel connects on first use):
        # megabytes of blob chunks never queue in front of a frame packet on the frames' connection.
        self._bulk_channel = channel(options + own)
        self._bulk = node_pb2_grpc.NodeLinkStub(self._bulk_channel)
        # Frames, delivered as serialized FramePackets: the presenter process parses them
        self._frames_raw = self._channel.unary_stream(
            "/shadowless.v1.NodeLink/Frames", request_serializer=node_pb2.StreamRequest.SerializeToString,
            response_deserializer=None)

    async def __aenter__(self) -> "CoordinatorLink":
        """Probe the target (LinkError ``UNAVAILABLE`` when it takes no TCP connection), then open."""
        await probe(self.target)
        self._open()
        await self._channel.__aenter__()
        return self

    async def __aexit__(self, *exc) -> None:
        try:
            await self._bulk_channel.close()
        finally:
            await self._channel.__aexit__(*exc)

    # ---------------------------------------------------------------- handshake
    async def hello(self, *, protocol_version: int, client_nonce: bytes, slot: str, timeout: float = 5.0) -> HelloReply:
        """The coordinator's half of the handshake (``timeout``: seconds; screening several advertised
        coordinators at once uses a shorter one, so that one that never answers costs little)."""
        with _translated():
            reply = await self._stub.Hello(wire.hello_request(protocol_version=protocol_version,
                                                              client_nonce=client_nonce, slot=slot), timeout=timeout)
        return wire.hello_reply_from_message(reply)

    async def join(self, request: JoinRequest) -> JoinReply:
        """Join; every later call carries the session this returns."""
        with _translated():
            reply = await self._stub.Join(wire.join_request(request), timeout=5)
        joined = wire.join_reply_from_message(reply)
        self._md = ((SESSION_KEY, joined.session),)
        return joined

    # ---------------------------------------------------------------- session calls
    async def ping(self, t0_local_ns: int) -> PingReply:
        with _translated():
            reply = await self._stub.Ping(wire.ping_request(t0_local_ns), metadata=self._md, timeout=2)
        return wire.ping_reply_from_message(reply)

    async def assignments(self) -> AsyncIterator[AssignmentBytes]:
        """The node's assignments as they change, as their bytes, each with why the presenter process
        could not decode it (:func:`node.wire.assignment_problem`: the session refuses such a one)."""
        with _translated():
            async for msg in self._stub.Assignments(wire.stream_request(), metadata=self._md):
                yield wire.assignment_bytes(msg)

    async def frame_packets(self) -> AsyncIterator[bytes]:
        """The Frames stream as received bytes (see :func:`node.wire.packet_from_bytes`)."""
        with _translated():
            async for data in self._frames_raw(wire.stream_request(), metadata=self._md):
                yield data

    async def show(self) -> AsyncIterator[ShowUpdateData]:
        """The show's timeline: the current state at once, every change, and beacons (malformed
        updates are logged and skipped)."""
        call = self._stub.Show(wire.stream_request(), metadata=self._md)
        try:
            with _translated():
                async for msg in call:
                    try:
                        update = wire.show_update_from_message(msg)
                    except ValueError as exc:
                        log.error("ignoring a malformed show update: %s", exc)
                        continue
                    yield update
        finally:
            call.cancel()

    async def previews(self) -> AsyncIterator[int]:
        """The coordinator's preview requests, as their ids (answered in a report's ``preview``)."""
        call = self._stub.Previews(wire.stream_request(), metadata=self._md)
        try:
            with _translated():
                async for msg in call:
                    yield wire.preview_request_from_message(msg)
        finally:
            call.cancel()

    async def report(self, batches: AsyncIterable[ReportBatch]) -> None:
        """Stream reports until ``batches`` ends or the call breaks.

        The batches are written by a task of this call's own, ended with it. (Given them as an
        iterator, gRPC reads them in a task of its own that outlives a call the coordinator ended:
        it waits for the next batch, up to a heartbeat, and is still pending when the loop closes.)"""
        call = self._stub.Report(metadata=self._md)

        async def write() -> None:
            async for batch in batches:
                await call.write(wire.report_message(batch))
            await call.done_writing()

        writer = asyncio.ensure_future(write())
        # batches that fail end the call, as gRPC's own reader did (a write on an ended call fails too: the
        # call's end says why)
        writer.add_done_callback(lambda t: t.cancelled() or t.exception() is None or call.cancel())
        try:
            with _translated():
                await call
        finally:
            writer.cancel()
            await asyncio.gather(writer, return_exceptions=True)
            call.cancel()

    # ---------------------------------------------------------------- assets fetched ahead
    async def wanted(self) -> AsyncIterator[WantedAssets]:
        """The assets this node must hold: the list at once, then again on every change."""
        call = self._stub.Wanted(wire.stream_request(), metadata=self._md)
        try:
            with _translated():
                async for msg in call:
                    yield wire.wanted_from_message(msg)
        finally:
            call.cancel()

    async def get_manifest(self, asset_id: str, *, timeout: float = 30.0) -> bytes:
        """An asset's canonical manifest bytes (the caller checks they hash to ``asset_id``)."""
        with _translated():
            reply = await self._bulk.GetManifest(wire.manifest_request(asset_id), metadata=self._md, timeout=timeout)
        return reply.manifest

    async def fetch_blob(self, sha256: str, offset: int) -> AsyncIterator[BlobChunkData]:
        """A blob's bytes from ``offset`` to its end, chunk by chunk (on the bulk connection)."""
        call = self._bulk.FetchBlob(wire.blob_request(sha256, offset), metadata=self._md)
        try:
            with _translated():
                async for msg in call:
                    yield wire.blob_chunk_from_message(msg)
        finally:
            call.cancel()   # the caller stopped early: the coordinator stops reading
