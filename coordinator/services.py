"""The coordinator's gRPC services: NodeLink for nodes, RigControl for operators, plus the
standard health and reflection services.

This is the wire edge: requests are turned into plain types (:mod:`coordinator.wire`),
the :class:`~coordinator.server.Coordinator` acts, and results go back as messages.
Refusals and validation errors become gRPC statuses with messages an operator can act on.
The Frames RPC yields bytes serialized once for every node (an identity serializer).
"""
from __future__ import annotations

import asyncio
import contextlib
import errno
import functools
import inspect
import logging
import os
import socket
import traceback
from typing import TYPE_CHECKING, Any

import grpc
import numpy as np
from grpc_health.v1 import health, health_pb2, health_pb2_grpc
from grpc_reflection.v1alpha import reflection

from coordinator import content_service, wire
from coordinator.admission import MAX_MESSAGE_BYTES as MAX_PREAUTH_MESSAGE_BYTES
from coordinator.admission import READ_TIMEOUT_S, REFUSED_OVER_BUDGET, Ticket
from coordinator.api import Space
from coordinator.errors import OPERATOR_ERRORS, CoordinatorError
from coordinator.float_range import check_float_range
from coordinator.rig import Content
from coordinator.sessions import RpcRefusal
from coordinator.show import BEACON_S
from protos import codec, common_pb2, control_pb2, control_pb2_grpc, node_pb2
from protos.version import COORDINATOR_GRPC_OPTIONS, PROTOCOL_VERSION, SESSION_KEY

if TYPE_CHECKING:  # pragma: no cover - types only
    from coordinator.server import Coordinator

log = logging.getLogger(__name__)

SERVER_OPTIONS = COORDINATOR_GRPC_OPTIONS + [("grpc.so_reuseport", 0)]
#: set to "off", the server runs without the budget for calls before authentication: what
#: `shadowless bench preauth --compare` measures as "before" (never for a rig in use)
BUDGET_OFF_ENV = "SHADOWLESS_PREAUTH_BUDGET"


def _peer(context: Any) -> str:
    return context.peer() or "unknown"


def _session_id(context: Any) -> str:
    return dict(context.invocation_metadata() or ()).get(SESSION_KEY, "")


def _guard(fn):
    """Turn refusals and validation errors into gRPC statuses with clear messages."""

    @functools.wraps(fn)
    async def wrapper(self, request, context):
        try:
            return await fn(self, request, context)
        except RpcRefusal as exc:
            await context.abort(exc.code, exc.message)
        except (ValueError, codec.ImageCodecError) as exc:
            await context.abort(grpc.StatusCode.INVALID_ARGUMENT, str(exc))
        except OPERATOR_ERRORS as exc:
            await context.abort(grpc.StatusCode.FAILED_PRECONDITION, str(exc))

    return wrapper


def _decoded(image: Any) -> np.ndarray:
    img = codec.decode_image(image)
    img = img.astype(np.float32) if img.dtype == np.float16 else img
    return check_float_range(img, "the image", hint="clip it before sending (shadowless show/play --clip)")


class _Malformed:
    """A request that did not parse as its method's message (see :func:`_measured`): only the
    parser's words are kept (an exception would hold the raw bytes through its traceback)."""

    def __init__(self, error: str):
        self.error = error


def _measured(deserializer):
    """The request deserializer of an admitted call: ``raw -> (len(raw), message)``. A message that
    does not parse becomes a :class:`_Malformed`, refused by the handler in one line: raised in
    gRPC's deserializer it was an ERROR with a traceback per message. One larger than a call
    without a session needs (MAX_PREAUTH_MESSAGE_BYTES) is not parsed at all."""

    def parse(raw: bytes):
        if len(raw) > MAX_PREAUTH_MESSAGE_BYTES:
            return len(raw), _Malformed(f"larger than the {MAX_PREAUTH_MESSAGE_BYTES // 1024} KiB a call without "
                                        "a session may send")
        if deserializer is None:
            return len(raw), raw
        try:
            return len(raw), deserializer(raw)
        except Exception as exc:  # noqa: BLE001 - a protobuf DecodeError, or whatever a parser raises
            error = f"not the method's message: {type(exc).__name__}"
        return len(raw), _Malformed(error)

    return parse


def _forget_locals(exc: BaseException) -> None:
    """Drop the locals of the finished frames ``exc`` passed through. An abort's exception ends up
    in a reference cycle with the call's context, and its traceback's frames hold the request (up to
    the size cap each): without this, a burst of refused calls stayed resident until a full garbage
    collection."""
    traceback.clear_frames(exc.__traceback__)


class _BadStreamMessage(Exception):
    """A message of a request stream without a session that did not parse or was too large."""


def _strict(deserializer):
    """A request stream's deserializer for a call without a session: the same rule as
    :func:`_measured`, but a message over MAX_PREAUTH_MESSAGE_BYTES, or one that does not parse,
    raises :class:`_BadStreamMessage` (caught by the call's wrapper and refused in one line)
    instead of gRPC's traceback."""
    measured = _measured(deserializer)

    def parse(raw: bytes):
        _, message = measured(raw)
        if isinstance(message, _Malformed):
            raise _BadStreamMessage(message.error)
        return message

    return parse


class Admission(grpc.aio.ServerInterceptor):
    """Calls without a live session go through the coordinator's budget for calls before
    authentication (:class:`coordinator.admission.Budget`) before a byte of their message is read.

    gRPC reads a unary call's whole message before its handler runs; so such a call is served
    here by a request-streaming handler (the same on the wire), which asks the budget first and
    then reads the one message itself. Over the budget, the call is refused unread with
    RESOURCE_EXHAUSTED and counted in the rig's refusals (logged once per address a minute). Calls
    with a node's or an operator's session pass untouched.
    """

    def __init__(self, coordinator: "Coordinator"):
        self.c = coordinator

    async def intercept_service(self, continuation, handler_call_details):
        handler = await continuation(handler_call_details)
        if handler is None:
            return None
        session = dict(handler_call_details.invocation_metadata or ()).get(SESSION_KEY, "")
        if session and (session in self.c.sessions or session in self.c.handshake.operators):
            return handler
        return self._budgeted(handler, handler_call_details.method)

    async def _enter(self, context) -> Ticket:
        peer = _peer(context)
        ticket = await self.c.admission.enter(peer)
        if ticket is None:
            exc = self.c.handshake.refuse(peer, "", grpc.StatusCode.RESOURCE_EXHAUSTED, REFUSED_OVER_BUDGET)
            await context.abort(exc.code, exc.message)
        return ticket

    def _leave(self, ticket: Ticket) -> None:
        self.c.admission.release(ticket)

    async def _read_one(self, context, ticket: Ticket, method: str):
        """The call's one request message. Read with ``context.read()``: the request iterator is an
        async generator whose suspended frame would keep the last message (up to the size cap)
        alive in a reference cycle until a full garbage collection."""
        try:
            got = await asyncio.wait_for(context.read(), READ_TIMEOUT_S)
        except asyncio.TimeoutError:
            exc = self.c.handshake.refuse(_peer(context), "", grpc.StatusCode.DEADLINE_EXCEEDED,
                                          f"{method} sent no request within {READ_TIMEOUT_S:.0f} s of its start")
            await context.abort(exc.code, exc.message)
        if got is grpc.aio.EOF:
            await context.abort(grpc.StatusCode.INVALID_ARGUMENT, f"{method}: the call carried no request message")
        nbytes, request = got
        del got
        self.c.admission.received(ticket, nbytes)
        if isinstance(request, _Malformed):
            await self._malformed(context, method, request.error)
        return request

    def _budgeted(self, handler, method: str):
        ser = handler.response_serializer
        if handler.request_streaming:
            return self._budgeted_stream(handler, ser, method)
        deser = _measured(handler.request_deserializer)
        if not handler.response_streaming:
            inner = handler.unary_unary

            async def unary(request_iterator, context):
                ticket = await self._enter(context)
                request = None
                try:
                    request = await self._read_one(context, ticket, method)
                    return await inner(request, context)
                except BaseException as exc:
                    request = None
                    _forget_locals(exc)
                    raise
                finally:
                    self._leave(ticket)

            return grpc.stream_unary_rpc_method_handler(unary, request_deserializer=deser, response_serializer=ser)
        inner = handler.unary_stream

        async def first(request_iterator, context):   # the request is what the budget holds
            ticket = await self._enter(context)
            try:
                return await self._read_one(context, ticket, method)
            finally:
                self._leave(ticket)

        if inspect.isasyncgenfunction(inner):
            async def streamed(request_iterator, context):
                try:
                    async for reply in inner(await first(request_iterator, context), context):
                        yield reply
                except BaseException as exc:
                    _forget_locals(exc)
                    raise
        else:       # a handler that writes with context.write
            async def streamed(request_iterator, context):
                try:
                    await inner(await first(request_iterator, context), context)
                except BaseException as exc:
                    _forget_locals(exc)
                    raise

        return grpc.stream_stream_rpc_method_handler(streamed, request_deserializer=deser, response_serializer=ser)

    async def _malformed(self, context, method: str, error: str) -> None:
        """Count a request that did not parse (or was too large) and refuse its call in one line."""
        self.c.admission.malformed += 1
        refusal = self.c.handshake.refuse(_peer(context), "", grpc.StatusCode.INVALID_ARGUMENT,
                                          f"malformed {method} request ({error}): dropped")
        await context.abort(refusal.code, refusal.message)

    def _budgeted_stream(self, handler, ser, method: str):
        """A request stream is read by its handler (ours check the session first): the call holds
        a reservation while it lasts, and its messages are checked as they arrive (:func:`_strict`)."""
        deser = _strict(handler.request_deserializer)
        if not handler.response_streaming:
            inner = handler.stream_unary

            async def unary(request_iterator, context):
                ticket = await self._enter(context)
                try:
                    return await inner(request_iterator, context)
                except _BadStreamMessage as exc:
                    await self._malformed(context, method, str(exc))
                finally:
                    self._leave(ticket)

            return grpc.stream_unary_rpc_method_handler(unary, request_deserializer=deser, response_serializer=ser)
        inner = handler.stream_stream
        if inspect.isasyncgenfunction(inner):
            async def streamed(request_iterator, context):
                ticket = await self._enter(context)
                try:
                    async for reply in inner(request_iterator, context):
                        yield reply
                except _BadStreamMessage as exc:
                    await self._malformed(context, method, str(exc))
                finally:
                    self._leave(ticket)
        else:
            async def streamed(request_iterator, context):
                ticket = await self._enter(context)
                try:
                    await inner(request_iterator, context)
                except _BadStreamMessage as exc:
                    await self._malformed(context, method, str(exc))
                finally:
                    self._leave(ticket)

        return grpc.stream_stream_rpc_method_handler(streamed, request_deserializer=deser, response_serializer=ser)


def regions_from_request(msg: control_pb2.ShowRequest) -> dict[str, list[tuple[int, int, int, int]]]:
    """A Show's per-slot regions, slot -> rectangles (x, y, width, height); checked by the playback."""
    return {slot: [(r.x, r.y, r.width, r.height) for r in e.rects] for slot, e in msg.slot_regions.items()}


class _Handshake:
    """The first half of the rig-token handshake, the same on both services."""

    def __init__(self, coord: "Coordinator"):
        self.c = coord

    @_guard
    async def Hello(self, request, context):
        r = self.c.handshake.hello(protocol_version=request.protocol_version, client_nonce=request.client_nonce,
                                   role=request.role, slot=request.slot, peer=_peer(context))
        return common_pb2.HelloReply(protocol_version=PROTOCOL_VERSION, rig_id=r.rig_id, rig_name=r.rig_name,
                                     server_nonce=r.server_nonce, server_proof=r.server_proof, instance_id=r.instance_id)

    def _check_login(self, login, context, role: str) -> None:
        self.c.handshake.check_login(protocol_version=login.protocol_version, role=login.role, slot=login.slot,
                                     client_nonce=login.client_nonce, server_nonce=login.server_nonce,
                                     client_proof=login.client_proof, peer=_peer(context), expected_role=role)


class NodeLinkService(_Handshake):

    @_guard
    async def Join(self, request, context):
        self._check_login(request.login, context, "node")
        sess = self.c.join(slot=request.login.slot, info=wire.node_info_from_message(request.info), peer=_peer(context))
        return node_pb2.JoinReply(session=sess.session, slot=sess.slot, rig_id=self.c.rig.config.rig_id,
                                  instance_id=self.c.instance_id, heartbeat_interval_ms=self.c.rig.config.heartbeat_ms,
                                  clock_id=self.c.clock_id)

    async def Assignments(self, request, context):
        try:
            sess = self.c.node_session(_session_id(context))
        except RpcRefusal as exc:
            await context.abort(exc.code, exc.message)
        sent = -1
        while not sess.closed:
            st = self.c.rig.slots[sess.slot]
            if st.revision != sent:
                sent = st.revision
                yield wire.assignment_message(st, content_size=self.c.playback.content_size)
            sess.assignment_event.clear()
            await sess.assignment_event.wait()

    async def Frames(self, request, context):
        try:
            sess = self.c.node_session(_session_id(context))
        except RpcRefusal as exc:
            await context.abort(exc.code, exc.message)
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
        try:
            sess = self.c.node_session(_session_id(context))
        except RpcRefusal as exc:
            await context.abort(exc.code, exc.message)
        try:
            async for rep in request_iterator:
                if sess.closed:
                    break
                self.c.on_report(sess, wire.report_from_message(rep))
        except (asyncio.CancelledError, grpc.aio.AioRpcError):
            pass
        except ValueError as exc:
            log.warning("node %s sent a malformed report (%s): its session ends", sess.slot, exc)
            await context.abort(grpc.StatusCode.INVALID_ARGUMENT, f"malformed report: {exc}")
        finally:
            # the report stream is the node's lifeline: when it ends, the node is gone
            self.c.mark_lost(sess)
        return node_pb2.ReportAck()

    async def Ping(self, request, context):
        t1 = self.c.rig_now()
        # a session check keeps the clock service to members of the rig
        if _session_id(context) not in self.c.sessions:
            await context.abort(grpc.StatusCode.UNAUTHENTICATED, "join before pinging")
        return node_pb2.PingReply(t0_local_ns=request.t0_local_ns, t1_rig_ns=t1, t2_rig_ns=self.c.rig_now(),
                                  instance_id=self.c.instance_id)

    # ---------------------------------------------------------------- assets fetched ahead
    async def Wanted(self, request, context):
        try:
            sess = self.c.node_session(_session_id(context))
        except RpcRefusal as exc:
            await context.abort(exc.code, exc.message)
        sent = -1
        while not sess.closed:
            wanted = self.c.distribution.wanted
            if wanted.revision != sent:
                sent = wanted.revision
                yield wire.wanted_message(wanted)
            sess.wanted_event.clear()
            if self.c.distribution.wanted.revision == sent:
                await sess.wanted_event.wait()

    @_guard
    async def GetManifest(self, request, context):
        self.c.node_session(_session_id(context))
        return wire.manifest_reply(await self.c.distribution.manifest_bytes(request.asset_id))

    async def FetchBlob(self, request, context):
        # written with context.write (not yielded): a node that goes away mid-blob (killed, link
        # lost) ends the call quietly instead of as a servicer error
        try:
            sess = self.c.node_session(_session_id(context))
            async with contextlib.aclosing(self.c.distribution.blob_chunks(request.sha256, request.offset)) as chunks:
                async for offset, data in chunks:
                    try:
                        await context.write(wire.blob_chunk_message(offset, data))
                    except Exception as exc:  # noqa: BLE001 - whatever the transport raises once the peer is gone
                        log.info("node %s stopped fetching blob %s… at byte %d (%s)", sess.slot, request.sha256[:12],
                                 offset, type(exc).__name__)
                        return
        except RpcRefusal as exc:
            await context.abort(exc.code, exc.message)


    async def Show(self, request, context):
        """The show's timeline: the state at once, every change, a beacon every BEACON_S."""
        try:
            sess = self.c.node_session(_session_id(context))
        except RpcRefusal as exc:
            await context.abort(exc.code, exc.message)
        changed = asyncio.Event()
        unsubscribe = self.c.show_state.subscribe(changed)
        sent = -1
        try:
            while not sess.closed:
                update = self.c.show_state.update(beacon=False)
                if update is not None:
                    if update.revision == sent:
                        update = self.c.show_state.update(beacon=True)
                    sent = update.revision
                    msg = wire.show_update_message(update)
                    self.c.show_updates_sent += 1
                    self.c.show_bytes_sent += msg.ByteSize()
                    yield msg
                changed.clear()
                try:
                    await asyncio.wait_for(changed.wait(), BEACON_S)
                except asyncio.TimeoutError:
                    pass
        finally:
            unsubscribe()

    async def Previews(self, request, context):
        """Preview requests for the node's console thumbnail, only while someone looks at it."""
        try:
            sess = self.c.node_session(_session_id(context))
        except RpcRefusal as exc:
            await context.abort(exc.code, exc.message)
        async for request_id in self.c.previews.asks(sess.slot, sess.preview_event, lambda: sess.closed):
            yield wire.preview_request_message(request_id)


def _add_node_link(server: grpc.aio.Server, svc: NodeLinkService) -> None:
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


class RigControlService(_Handshake):

    def _operator(self, context) -> None:
        self.c.handshake.check_operator(_session_id(context))

    @_guard
    async def Login(self, request, context):
        self._check_login(request, context, "operator")
        return common_pb2.LoginReply(session=self.c.handshake.open_operator_session(), rig_id=self.c.rig.config.rig_id,
                                     instance_id=self.c.instance_id)

    @_guard
    async def Status(self, request, context):
        self._operator(context)
        return wire.status_message(self.c.status())

    @_guard
    async def ListNodes(self, request, context):
        self._operator(context)
        return wire.nodes_message(self.c.status().nodes)

    async def Show(self, request_iterator, context):
        try:
            self._operator(context)   # from the call's metadata, before any image byte is read
            first, image = None, wire.ImageParts()
            async for part in request_iterator:
                if first is None:
                    first = part
                    image.start(part.image)
                else:
                    image.add(part.more)
            if first is None:
                raise ValueError("a Show call sent no image")
            space = wire.space_from_message(first.space)
            img = image.finish()
            regions = regions_from_request(first)
            if regions and (first.persist or space != Space.CONTENT):
                raise ValueError("slot regions apply to a content-space show that is not persisted")

            def prepare():   # decoded, fitted, masked and packed for the nodes off the event loop
                content = self.c.playback.prepare_still(Content(_decoded(img), name=first.name), space, fit=first.fit)
                return content, self.c.playback.prepare_regions(content, regions) if regions else None

            content, slot_contents = await asyncio.to_thread(prepare)
            apply_lut = first.apply_lut or space == Space.CONTENT
            return wire.show_result_message(self.c.show(content, space=space, apply_lut=apply_lut,
                                                        persist=first.persist, slot_contents=slot_contents))
        except RpcRefusal as exc:
            await context.abort(exc.code, exc.message)
        except (ValueError, codec.ImageCodecError) as exc:
            await context.abort(grpc.StatusCode.INVALID_ARGUMENT, str(exc))
        except OPERATOR_ERRORS as exc:
            await context.abort(grpc.StatusCode.FAILED_PRECONDITION, str(exc))

    async def Play(self, request_iterator, context):
        try:
            self._operator(context)   # from the call's metadata, before any frame is read
            settings = None
            frames: list[Content] = []
            image = wire.ImageParts()

            def take_frame() -> None:
                if image.started:
                    frames.append(Content(_decoded(image.finish())))

            async for item in request_iterator:
                kind = item.WhichOneof("item")
                if kind == "settings":
                    settings = wire.play_settings_from_message(item.settings)
                elif kind == "frame":
                    take_frame()
                    image.start(item.frame)
                elif kind == "more":
                    image.add(item.more)
            take_frame()
            if settings is None:
                raise ValueError("the first PlayItem must carry the settings")
            try:
                result = await self.c.play_sequence(None if settings.pattern else frames, settings)
            except asyncio.CancelledError:
                # the operator went away (Ctrl-C): the sequence stops on the rig too
                log.info("play cancelled by its client: stopping the sequence")
                with contextlib.suppress(CoordinatorError):
                    self.c.stop_all()
                raise
            return wire.play_result_message(result)
        except RpcRefusal as exc:
            await context.abort(exc.code, exc.message)
        except (ValueError, codec.ImageCodecError) as exc:
            await context.abort(grpc.StatusCode.INVALID_ARGUMENT, str(exc))
        except OPERATOR_ERRORS as exc:
            await context.abort(grpc.StatusCode.FAILED_PRECONDITION, str(exc))

    @_guard
    async def Stop(self, request, context):
        self._operator(context)
        return control_pb2.StopReply(showing=self.c.stop_all(blackout=request.blackout))

    async def RunJob(self, request, context):
        try:
            self._operator(context)
            params = wire.job_params_from_request(request)
        except RpcRefusal as exc:
            await context.abort(exc.code, exc.message)
        except ValueError as exc:
            await context.abort(grpc.StatusCode.INVALID_ARGUMENT, f"bad job parameters: {exc}")
        events: asyncio.Queue = asyncio.Queue()
        task = asyncio.create_task(self.c.run_job(request.kind, params, events.put_nowait), name=f"job:{request.kind}")
        try:
            while True:
                getter = asyncio.ensure_future(events.get())
                done, _ = await asyncio.wait({getter, task}, return_when=asyncio.FIRST_COMPLETED)
                if getter in done:
                    yield wire.job_event_message(getter.result())
                    continue
                getter.cancel()
                while not events.empty():
                    yield wire.job_event_message(events.get_nowait())
                break
            try:
                result = task.result()
            except (*OPERATOR_ERRORS, ValueError, OSError) as exc:
                log.error("job %s failed: %s", request.kind, exc)
                await context.abort(grpc.StatusCode.FAILED_PRECONDITION, f"{request.kind}: {exc}")
            yield wire.job_result_message(result)
        finally:
            if not task.done():
                log.warning("job %s cancelled by its client", request.kind)
                task.cancel()
                await asyncio.gather(task, return_exceptions=True)

    @_guard
    async def Configure(self, request, context):
        self._operator(context)
        changes = wire.slot_changes_from_message(request, mesh_lookup=self.c.rig.mesh)
        if not changes:
            raise ValueError(f"nothing to change on slot {request.slot!r}: give a homography or a projection pose, "
                             "a LUT, a gain, an output size or clear the pose")
        st = self.c.update_slot(request.slot, **changes)
        return control_pb2.ConfigureReply(revision=st.revision)


    # ---------------------------------------------------------------- timeline shows
    @_guard
    async def PlayAsset(self, request, context):
        self._operator(context)
        state = self.c.play_asset(request.asset, at_ns=request.at_ns or None,
                                  delay_ns=int(request.delay_ms * 1e6) or None, loop=request.loop,
                                  fps=request.fps or None, start_without=request.start_without)
        return wire.show_state_message(state)

    async def _control(self, action: str, request, context):
        self._operator(context)
        state = self.c.show_control(action, at_ns=request.at_ns or None, delay_ns=int(request.delay_ms * 1e6) or None,
                                    frame=request.frame)
        return wire.show_state_message(state)

    @_guard
    async def PauseShow(self, request, context):
        return await self._control("pause", request, context)

    @_guard
    async def ResumeShow(self, request, context):
        return await self._control("resume", request, context)

    @_guard
    async def SeekShow(self, request, context):
        return await self._control("seek", request, context)

    @_guard
    async def StopShow(self, request, context):
        return await self._control("stop", request, context)


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


async def serve(coordinator: "Coordinator", listen: str, *, tls: tuple[bytes, bytes] | None = None):
    """Start the gRPC server for ``coordinator``; returns ``(server, health servicer, port)``."""
    interceptors = [Admission(coordinator)]
    if os.environ.get(BUDGET_OFF_ENV) == "off":     # bench preauth's "before" only
        log.warning("%s=off: calls before authentication have no budget (for measurements only)", BUDGET_OFF_ENV)
        interceptors = []
    server = grpc.aio.server(options=SERVER_OPTIONS, interceptors=interceptors)
    _add_node_link(server, NodeLinkService(coordinator))
    control_pb2_grpc.add_RigControlServicer_to_server(RigControlService(coordinator), server)
    content_service.add_to_server(server, coordinator.distribution.store, coordinator.handshake)
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
