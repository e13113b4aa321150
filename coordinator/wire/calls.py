"""How the coordinator's gRPC services read a call and refuse it.

The core refuses in its own terms (:class:`coordinator.errors.Refusal`, with a
:class:`~coordinator.errors.RefusalKind`); :data:`STATUS_CODES` is the one table that says which
gRPC status each kind becomes. :func:`guard` turns a handler's refusals and validation errors
into statuses with the core's message, which an operator can act on.
"""
from __future__ import annotations

import functools
from typing import Any, NoReturn

import grpc

from coordinator.errors import OPERATOR_ERRORS, Refusal, RefusalKind
from protos import codec
from protos.version import SESSION_KEY

#: the gRPC status of each kind of refusal (the console has its own table of HTTP statuses)
STATUS_CODES: dict[RefusalKind, grpc.StatusCode] = {
    RefusalKind.INVALID: grpc.StatusCode.INVALID_ARGUMENT,
    RefusalKind.NOT_FOUND: grpc.StatusCode.NOT_FOUND,
    RefusalKind.CONFLICT: grpc.StatusCode.ALREADY_EXISTS,
    RefusalKind.UNAUTHENTICATED: grpc.StatusCode.UNAUTHENTICATED,
    RefusalKind.FAILED_PRECONDITION: grpc.StatusCode.FAILED_PRECONDITION,
    RefusalKind.RESOURCE_EXHAUSTED: grpc.StatusCode.RESOURCE_EXHAUSTED,
    RefusalKind.DEADLINE_EXCEEDED: grpc.StatusCode.DEADLINE_EXCEEDED,
    RefusalKind.UNAVAILABLE: grpc.StatusCode.UNAVAILABLE,
}


def peer(context: Any) -> str:
    """The calling peer as gRPC names it (``ipv4:ADDR:PORT``, ...)."""
    return context.peer() or "unknown"


def session_id(context: Any) -> str:
    """The session the call's metadata carries ("" for none)."""
    return dict(context.invocation_metadata() or ()).get(SESSION_KEY, "")


async def abort(context: Any, refusal: Refusal) -> NoReturn:
    """End the call with ``refusal``'s status and message."""
    await context.abort(STATUS_CODES[refusal.kind], refusal.message)
    raise AssertionError("context.abort returned")   # pragma: no cover - it always raises


async def abort_for(context: Any, exc: Exception) -> NoReturn:
    """End the call for an error a handler raised: a refusal with its own status, a malformed
    request (ValueError, an image that does not decode) with INVALID_ARGUMENT, any other error of
    the coordinator with FAILED_PRECONDITION; anything else is raised again."""
    if isinstance(exc, Refusal):
        await abort(context, exc)
    if isinstance(exc, (ValueError, codec.ImageCodecError)):
        await context.abort(grpc.StatusCode.INVALID_ARGUMENT, str(exc))
    if isinstance(exc, OPERATOR_ERRORS):
        await context.abort(grpc.StatusCode.FAILED_PRECONDITION, str(exc))
    raise exc


def guard(fn):
    """A handler whose refusals and validation errors become statuses (:func:`abort_for`)."""

    @functools.wraps(fn)
    async def wrapper(self, request, context):
        try:
            return await fn(self, request, context)
        except (Refusal, ValueError, codec.ImageCodecError, *OPERATOR_ERRORS) as exc:
            await abort_for(context, exc)

    return wrapper
