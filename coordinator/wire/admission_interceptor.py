"""Calls without a session pass the budget for calls before authentication before a byte of
their message is read (:class:`Admission`, a gRPC server interceptor).

The budget itself, what it counts and its limits, is :class:`coordinator.admission.Budget`; this is
how the gRPC server applies it: the handler of every call without a live session is wrapped so that
it asks the budget, reads its one message itself under a deadline and a size cap, and gives the
room back when it ends.
"""
from __future__ import annotations

import asyncio
import inspect
import traceback

import grpc

from coordinator.admission import MAX_MESSAGE_BYTES as MAX_PREAUTH_MESSAGE_BYTES
from coordinator.admission import READ_TIMEOUT_S, REFUSED_OVER_BUDGET, Ticket
from coordinator.errors import RefusalKind
from coordinator.ports import ServiceRig
from coordinator.wire.calls import abort, peer
from protos.version import SESSION_KEY


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

    def __init__(self, coordinator: ServiceRig):
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
        address = peer(context)
        ticket = await self.c.admission.enter(address)
        if ticket is None:
            exc = self.c.handshake.refuse(address, "", RefusalKind.RESOURCE_EXHAUSTED, REFUSED_OVER_BUDGET)
            await abort(context, exc)
        return ticket

    def _leave(self, ticket: Ticket) -> None:
        self.c.admission.release(ticket)

    async def _read_one(self, context, ticket: Ticket, method: str):
        """The call's one request message. Read with ``context.read()``: the request iterator is an
        async generator whose suspended frame would keep the last message (up to the size cap)
        alive in a reference cycle until a full garbage collection."""
        try:    # not wait_for: on 3.11 it drops a cancel (the call cancelled) that meets the message
            async with asyncio.timeout(READ_TIMEOUT_S):
                got = await context.read()
        except TimeoutError:
            exc = self.c.handshake.refuse(peer(context), "", RefusalKind.DEADLINE_EXCEEDED,
                                          f"{method} sent no request within {READ_TIMEOUT_S:.0f} s of its start")
            await abort(context, exc)
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
        refusal = self.c.handshake.refuse(peer(context), "", RefusalKind.INVALID,
                                          f"malformed {method} request ({error}): dropped")
        await abort(context, refusal)

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
