"""How the coordinator's gRPC services read a call and refuse it.

The core refuses in its own terms (:class:`coordinator.errors.Refusal`, with a
:class:`~coordinator.errors.RefusalKind`); :data:`STATUS_CODES` is the one table that says which
gRPC status each kind becomes. :func:`guard` turns a handler's refusals and validation errors
into statuses with the core's message, which an operator can act on. :func:`logged` writes a
call that changes the rig to the action log (:mod:`coordinator.console.audit`), as the console and
OSC write theirs: who (``token``: the command line logs in with the rig token), the caller's
address, ``cli <action>``, the parameters, and the result or the refusal. A call refused for
want of a session writes nothing (whoever lacks the token must not fill the rig's disk).
"""
from __future__ import annotations

import functools
from typing import TYPE_CHECKING, Any, Callable, NoReturn

import grpc

from coordinator.errors import OPERATOR_ERRORS, Refusal, RefusalKind
from coordinator.users import TOKEN_WHO
from protos import codec
from protos.version import SESSION_KEY

if TYPE_CHECKING:  # pragma: no cover - types only (the console package is loaded when first served)
    from coordinator.console.audit import ActionLog

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


def peer_host(context: Any) -> str:
    """The caller's address without its port (``ipv4:10.0.0.5:41234`` -> ``10.0.0.5``)."""
    kind, _, rest = peer(context).partition(":")
    if kind == "ipv6":
        return rest.rpartition(":")[0].strip("[]") or rest
    if kind == "ipv4":
        return rest.rpartition(":")[0] or rest
    return kind or "unknown"


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


def _why(exc: BaseException) -> str:
    return " ".join((exc.message if isinstance(exc, Refusal) else str(exc)).split())


async def record(log: "ActionLog", context: Any, action: str, *, ok: bool, result: str,
                 params: dict[str, Any] | None = None) -> None:
    """One entry of the action log for a call of the command line (the module docstring)."""
    await log.record(who=TOKEN_WHO, address=peer_host(context), action=f"cli {action}", ok=ok, result=result,
                     params=params)


async def record_failure(log: "ActionLog", context: Any, action: str, exc: BaseException,
                         params: dict[str, Any] | None = None) -> None:
    """The entry of a refused or failed call; none for a call without a session."""
    if isinstance(exc, Refusal) and exc.kind == RefusalKind.UNAUTHENTICATED:
        return
    await record(log, context, action, ok=False, result=_why(exc), params=params)


def logged(action: str | Callable[[Any], str], *, params: Callable[[Any], dict] = lambda request: {},
           result: Callable[[Any, Any], str] = lambda request, reply: "done"):
    """A unary handler whose every call (done or refused, unless for want of a session) is an entry of
    the service's ``self.action_log``: ``action`` (or ``action(request)``), ``params(request)`` and
    ``result(request, reply)``. Goes under :func:`guard` (it sees the handler's own errors)."""

    def deco(fn):
        @functools.wraps(fn)
        async def wrapper(self, request, context):
            what = action(request) if callable(action) else action
            try:
                reply = await fn(self, request, context)
            except (Refusal, ValueError, codec.ImageCodecError, *OPERATOR_ERRORS) as exc:
                await record_failure(self.action_log, context, what, exc, params(request))
                raise
            await record(self.action_log, context, what, ok=True, result=result(request, reply),
                         params=params(request))
            return reply

        return wrapper

    return deco
