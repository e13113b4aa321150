"""The NodeLink service: what the coordinator serves its nodes.

Requests become plain types (:mod:`coordinator.wire.node_messages`), the coordinator acts (seen
as a :class:`coordinator.ports.ServiceRig`), and results go back as messages. The Frames RPC
yields bytes serialized once for every node (an identity serializer, see :func:`add_node_link`).
"""
from __future__ import annotations

import asyncio
import contextlib
import logging

import grpc

from coordinator.sessions import NodeSession
from coordinator.show import BEACON_S
from coordinator.wire import node_messages
from coordinator.errors import Refusal
from coordinator.wire.calls import abort, guard, peer, session_id
from coordinator.wire.handshake_service import HandshakeService
from protos import common_pb2, node_pb2

log = logging.getLogger(__name__)


class NodeLinkService(HandshakeService):
    """NodeLink: a node joins, then holds its streams (assignments, frames, wanted assets, the show,
    preview requests) and reports over one stream, which is its lifeline."""

    async def _session(self, context) -> NodeSession:
        """The node's session named by the call's metadata; the call is refused without one."""
        try:
            return self.c.node_session(session_id(context))
        except Refusal as exc:
            await abort(context, exc)

    @guard
    async def Join(self, request, context):
        self._check_login(request.login, context, "node")
        sess = self.c.join(slot=request.login.slot, info=node_messages.node_info_from_message(request.info),
                           peer=peer(context))
        return node_pb2.JoinReply(session=sess.session, slot=sess.slot, rig_id=self.c.rig.config.rig_id,
                                  instance_id=self.c.instance_id, heartbeat_interval_ms=self.c.rig.config.heartbeat_ms,
                                  clock_id=self.c.clock_id)

    async def Assignments(self, request, context):
        sess = await self._session(context)
        sent = -1
        while not sess.closed:
            # cleared before the slot is read, not after the message went: a change made while it is
            # written sets the event again and is sent next (cleared after, it waited for the next change)
            sess.assignment_event.clear()
            st = self.c.rig.slots[sess.slot]
            if st.revision != sent:
                sent = st.revision
                yield node_messages.assignment_message(st, content_size=self.c.content_size)
            if not sess.assignment_event.is_set():
                await sess.assignment_event.wait()

    async def Frames(self, request, context):
        sess = await self._session(context)
        self.c.on_frames_open(sess)
        try:
            while not sess.closed:
                while sess.packets:
                    data = sess.packets.popleft()
                    self.c.frame_packets_sent += 1
                    self.c.frame_bytes_sent += len(data)
                    yield data
                    if sess.closed:
                        return
                sess.packet_event.clear()
                if not sess.packets:
                    await sess.packet_event.wait()
        finally:
            sess.frames_open = False

    async def Report(self, request_iterator, context):
        sess = await self._session(context)
        closed = asyncio.Event()
        # a session the coordinator closes (it stops, the node was lost or replaced) ends the call at
        # once, not at the node's next report (a graceful stop waited up to a heartbeat for it)
        forget = sess.wake_on_close(closed)

        async def read() -> None:
            async for rep in request_iterator:
                if sess.closed:
                    return
                report = node_messages.report_from_message(rep)
                self.c.on_report(sess, report)
                if report.goodbye:     # it stops on purpose: left, not lost
                    self.c.mark_left(sess, report.goodbye)
                    return

        reader = asyncio.ensure_future(read())
        closing = asyncio.ensure_future(closed.wait())
        try:
            await asyncio.wait({reader, closing}, return_when=asyncio.FIRST_COMPLETED)
            if reader.done():
                reader.result()     # a broken call or a malformed report
        except (asyncio.CancelledError, grpc.aio.AioRpcError):
            pass
        except ValueError as exc:
            log.warning("node %s sent a malformed report (%s): its session ends", sess.slot, exc)
            await context.abort(grpc.StatusCode.INVALID_ARGUMENT, f"malformed report: {exc}")
        finally:
            for t in (reader, closing):
                t.cancel()
            await asyncio.gather(reader, closing, return_exceptions=True)
            forget()
            # the report stream is the node's lifeline: when it ends, the node is gone
            self.c.mark_lost(sess)
        return node_pb2.ReportAck()

    async def Ping(self, request, context):
        t1 = self.c.rig_now()
        # a session check keeps the clock service to members of the rig
        if session_id(context) not in self.c.sessions:
            await context.abort(grpc.StatusCode.UNAUTHENTICATED, "join before pinging")
        return node_pb2.PingReply(t0_local_ns=request.t0_local_ns, t1_rig_ns=t1, t2_rig_ns=self.c.rig_now(),
                                  instance_id=self.c.instance_id)

    # ---------------------------------------------------------------- assets fetched ahead
    async def Wanted(self, request, context):
        sess = await self._session(context)
        sent = -1
        while not sess.closed:
            # cleared before the list is read, as for the assignments: a change or the session's close
            # made while the list is written sets it again (cleared after, a close then was missed and
            # the stream held its call until the server's grace ran out)
            sess.wanted_event.clear()
            wanted = self.c.wanted
            if wanted.revision != sent:
                sent = wanted.revision
                yield node_messages.wanted_message(wanted)
            if not sess.wanted_event.is_set():
                await sess.wanted_event.wait()

    @guard
    async def GetManifest(self, request, context):
        self.c.node_session(session_id(context))
        return node_messages.manifest_reply(await self.c.manifest_bytes(request.asset_id))

    async def FetchBlob(self, request, context):
        # written with context.write (not yielded): a node that goes away mid-blob (killed, link
        # lost) ends the call quietly instead of as a servicer error
        try:
            sess = self.c.node_session(session_id(context))
            async with contextlib.aclosing(self.c.blob_chunks(request.sha256, request.offset)) as chunks:
                async for offset, data in chunks:
                    try:
                        await context.write(node_messages.blob_chunk_message(offset, data))
                    except Exception as exc:  # noqa: BLE001 - whatever the transport raises once the peer is gone
                        log.info("node %s stopped fetching blob %s… at byte %d (%s)", sess.slot, request.sha256[:12],
                                 offset, type(exc).__name__)
                        return
        except Refusal as exc:
            await abort(context, exc)

    async def Show(self, request, context):
        """The show's timeline: the state at once, every change, a beacon every BEACON_S; it ends
        when the session closes."""
        sess = await self._session(context)
        changed = asyncio.Event()
        unsubscribe = self.c.subscribe_show(changed)
        forget = sess.wake_on_close(changed)    # a close ends the stream now, not at its next beacon
        sent, beacon_due = -1, False
        try:
            while not sess.closed:
                # cleared before the show is read, not after the message went: a change made while it
                # is written sets it again and goes next (cleared after, it waited for the beacon)
                changed.clear()
                update = self.c.show_update(beacon=False)
                if update is not None and update.revision == sent and beacon_due:
                    update = self.c.show_update(beacon=True)    # nothing new for BEACON_S: a reminder
                if update is not None and (update.revision != sent or update.beacon):
                    sent = update.revision
                    msg = node_messages.show_update_message(update)
                    self.c.show_updates_sent += 1
                    self.c.show_bytes_sent += msg.ByteSize()
                    yield msg
                beacon_due = False
                if changed.is_set():
                    continue
                try:    # not wait_for: on 3.11 it drops a cancel that meets a set event
                    async with asyncio.timeout(BEACON_S):
                        await changed.wait()
                except TimeoutError:
                    beacon_due = True
        finally:
            forget()
            unsubscribe()

    async def Previews(self, request, context):
        """Preview requests for the node's console thumbnail, only while someone looks at it."""
        sess = await self._session(context)
        async for request_id in self.c.previews.asks(sess.slot, sess.preview_event, lambda: sess.closed):
            yield node_messages.preview_request_message(request_id)


def add_node_link(server: grpc.aio.Server, svc: NodeLinkService) -> None:
    """Register NodeLink; Frames yields pre-serialized bytes (identity serializer)."""
    handlers = {
        "Hello": grpc.unary_unary_rpc_method_handler(
            svc.Hello, request_deserializer=common_pb2.HelloRequest.FromString,
            response_serializer=common_pb2.HelloReply.SerializeToString),
        "Join": grpc.unary_unary_rpc_method_handler(
            svc.Join, request_deserializer=node_pb2.JoinRequest.FromString,
            response_serializer=node_pb2.JoinReply.SerializeToString),
        "Assignments": grpc.unary_stream_rpc_method_handler(
            svc.Assignments, request_deserializer=node_pb2.StreamRequest.FromString,
            response_serializer=node_pb2.Assignment.SerializeToString),
        "Frames": grpc.unary_stream_rpc_method_handler(
            svc.Frames, request_deserializer=node_pb2.StreamRequest.FromString, response_serializer=None),
        "Report": grpc.stream_unary_rpc_method_handler(
            svc.Report, request_deserializer=node_pb2.NodeReport.FromString,
            response_serializer=node_pb2.ReportAck.SerializeToString),
        "Ping": grpc.unary_unary_rpc_method_handler(
            svc.Ping, request_deserializer=node_pb2.PingRequest.FromString,
            response_serializer=node_pb2.PingReply.SerializeToString),
        "Wanted": grpc.unary_stream_rpc_method_handler(
            svc.Wanted, request_deserializer=node_pb2.StreamRequest.FromString,
            response_serializer=node_pb2.WantedAssets.SerializeToString),
        "GetManifest": grpc.unary_unary_rpc_method_handler(
            svc.GetManifest, request_deserializer=node_pb2.ManifestRequest.FromString,
            response_serializer=node_pb2.ManifestReply.SerializeToString),
        "FetchBlob": grpc.unary_stream_rpc_method_handler(
            svc.FetchBlob, request_deserializer=node_pb2.BlobRequest.FromString,
            response_serializer=node_pb2.BlobChunk.SerializeToString),
        "Show": grpc.unary_stream_rpc_method_handler(
            svc.Show, request_deserializer=node_pb2.StreamRequest.FromString,
            response_serializer=node_pb2.ShowUpdate.SerializeToString),
        "Previews": grpc.unary_stream_rpc_method_handler(
            svc.Previews, request_deserializer=node_pb2.StreamRequest.FromString,
            response_serializer=node_pb2.PreviewRequest.SerializeToString),
    }
    server.add_generic_rpc_handlers((grpc.method_handlers_generic_handler("shadowless.v1.NodeLink", handlers),))
