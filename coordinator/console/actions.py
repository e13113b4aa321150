"""The console's actions: each POST endpoint calls the same :class:`Coordinator` method as its
gRPC handler (``coordinator/wire/control_service.py``), so nothing the console does skips validation.

Every action is logged (:mod:`coordinator.console.audit`) with its result or the reason it was
refused, one entry an action (a cue fired from here is not written again by the cue engine:
:func:`coordinator.cues.edge_logs`), and answers JSON: ``{"ok": true, "result": ...}`` or ``{"ok": false, "error": ...}``
with 400 (bad input), 409 (the rig refuses now, e.g. a job holds the projectors), the status
:data:`REFUSAL_STATUS` gives a :class:`~coordinator.errors.Refusal`'s kind, or 500.
The caller (``app.py``) has already checked the session, the CSRF token and the Origin.
"""
from __future__ import annotations

import asyncio
import json
import logging
import math
from typing import TYPE_CHECKING, Any, Awaitable, Callable

import numpy as np
from aiohttp import web

from coordinator.api import Space
from coordinator.cues import edge_logs
from coordinator.errors import OPERATOR_ERRORS, Refusal, RefusalKind
from coordinator.fit import FIT_MODES
from coordinator.float_range import check_float_range
from coordinator.image_decode import MAX_PIXELS, decode_image
from coordinator.jobs.registry import JOBS
from coordinator.rig import Content

if TYPE_CHECKING:  # pragma: no cover - types only
    from coordinator.console.audit import ActionLog
    from coordinator.console.auth import Session
    from coordinator.console.live import Live
    from coordinator.ports import ConsoleRig

log = logging.getLogger(__name__)

#: the largest image the console accepts (bytes of the uploaded file)
MAX_UPLOAD_BYTES = 200 * 1024 * 1024
#: the largest JSON body of an action
MAX_JSON_BYTES = 16 * 1024


#: the HTTP status of each kind of refusal (the gRPC edge has its own table of status codes)
REFUSAL_STATUS: dict[RefusalKind, int] = {
    RefusalKind.INVALID: 400,
    RefusalKind.NOT_FOUND: 404,
    RefusalKind.CONFLICT: 409,
    RefusalKind.UNAUTHENTICATED: 403,      # not 401: that is the console's own "log in again"
    RefusalKind.FAILED_PRECONDITION: 409,
    RefusalKind.RESOURCE_EXHAUSTED: 429,
    RefusalKind.DEADLINE_EXCEEDED: 408,
    RefusalKind.UNAVAILABLE: 503,
}


class BadRequest(ValueError):
    """The request itself is malformed (not the rig refusing it)."""


#: the largest upload the console decodes (the coordinator's one limit, see coordinator.image_decode)
MAX_UPLOAD_PIXELS = MAX_PIXELS


def decode_upload(data: bytes, filename: str) -> np.ndarray:
    """An uploaded file as an (H, W, C) RGB(A) array of uint8, uint16 or float32 (float in 0..1),
    decoded by :func:`coordinator.image_decode.decode_image` (its declared size checked first);
    ValueError naming the file for anything else."""
    name = filename or "the upload"
    img = decode_image(data, name)
    if img.dtype == np.float64:
        img = img.astype(np.float32)
    if img.dtype not in (np.uint8, np.uint16, np.float32):
        raise ValueError(f"{name} holds {img.dtype} pixels: give an 8- or 16-bit integer or a "
                         "32-bit float image")
    return check_float_range(img, name, hint="clip it first (`shadowless show FILE --clip` clips for you)")


async def _json_body(request: web.Request) -> dict[str, Any]:
    if request.content_length is not None and request.content_length > MAX_JSON_BYTES:
        raise BadRequest(f"the request body is larger than {MAX_JSON_BYTES} bytes")
    raw = await request.content.read(MAX_JSON_BYTES + 1)
    if len(raw) > MAX_JSON_BYTES:
        raise BadRequest(f"the request body is larger than {MAX_JSON_BYTES} bytes")
    try:
        doc = json.loads(raw or b"{}")
    except ValueError as exc:
        raise BadRequest(f"the request body is not JSON: {exc}") from None
    if not isinstance(doc, dict):
        raise BadRequest("the request body must be a JSON object")
    return doc


class Actions:
    """The POST endpoints. ``run`` performs one action and logs it."""

    def __init__(self, coord: "ConsoleRig", audit: "ActionLog", live: "Live"):
        self.coord, self.audit, self.live = coord, audit, live

    async def run(self, request: web.Request, session: "Session", action: str,
                  act: Callable[[dict[str, Any]], Awaitable[str]]) -> web.Response:
        """Perform ``act(params)`` (it fills ``params`` for the log and returns the result text)."""
        params: dict[str, Any] = {}
        status, ok = 200, False
        try:
            with edge_logs():       # this entry is the action's one: a cue fired here is not logged twice
                result = await act(params)
            ok = True
        except (BadRequest, ValueError) as exc:
            status, result = 400, str(exc)
        except Refusal as exc:
            status, result = REFUSAL_STATUS[exc.kind], exc.message
        except OPERATOR_ERRORS as exc:
            status, result = 409, str(exc)
        except web.HTTPException:
            raise
        except Exception as exc:  # noqa: BLE001 - the operator sees that it failed, the log says why
            log.exception("console action %s failed", action)
            status, result = 500, f"internal error ({type(exc).__name__}): {exc}; see the coordinator's log"
        entry = await self.audit.record(who=session.who, address=session.address, action=action, ok=ok,
                                        result=result, params=params)
        self.live.poke()
        body = {"ok": ok, "result" if ok else "error": result, "entry": entry}
        return web.json_response(body, status=status)

    # ------------------------------------------------------------------ the endpoints
    async def stop(self, request: web.Request, session: "Session") -> web.Response:
        async def act(params):
            return f"showing {self.coord.stop_all(blackout=False)}"
        return await self.run(request, session, "stop", act)

    async def blackout(self, request: web.Request, session: "Session") -> web.Response:
        async def act(params):
            return f"showing {self.coord.stop_all(blackout=True)}"
        return await self.run(request, session, "blackout", act)

    async def identify(self, request: web.Request, session: "Session") -> web.Response:
        async def act(params):
            return f"showing {await self.coord.identify()}"
        return await self.run(request, session, "identify", act)

    async def gain(self, request: web.Request, session: "Session") -> web.Response:
        async def act(params):
            doc = await _json_body(request)
            slot, gain = doc.get("slot"), doc.get("gain")
            params.update(slot=slot, gain=gain)
            if not isinstance(slot, str) or not slot:
                raise BadRequest("name the slot whose gain to set")
            if isinstance(gain, str):
                try:
                    gain = float(gain)
                except ValueError:
                    raise BadRequest(f"gain must be a number, got {gain!r}") from None
            if isinstance(gain, bool) or not isinstance(gain, (int, float)) or not math.isfinite(gain):
                raise BadRequest(f"gain must be a number, got {gain!r}")
            st = self.coord.update_slot(slot, gain=float(gain))
            return f"slot {slot} gain {st.gain:g} (revision {st.revision})"
        return await self.run(request, session, "gain", act)

    async def show(self, request: web.Request, session: "Session") -> web.Response:
        async def act(params):
            fields = await _multipart(request)
            data, filename = fields.get("image", (b"", ""))
            fit = fields.get("fit", (b"", ""))[0].decode(errors="replace").strip()
            persist = fields.get("persist", (b"", ""))[0].decode(errors="replace").strip() in ("1", "on", "true")
            params.update(file=filename, bytes=len(data), fit=fit, persist=persist)
            if fit and fit not in FIT_MODES:
                raise BadRequest(f"unknown fit {fit!r}: choose one of {', '.join(FIT_MODES)}")
            img = await asyncio.to_thread(decode_upload, data, filename)
            params["size"] = f"{img.shape[1]}x{img.shape[0]}"
            # fitted and packed for the nodes in a worker thread, as the gRPC Show does
            content = await asyncio.to_thread(
                lambda: self.coord.prepare_still(Content(img, name=filename), Space.CONTENT, fit=fit))
            res = self.coord.show(content, space=Space.CONTENT, apply_lut=True, persist=persist)
            return f"showing {filename or 'the upload'} (frame {res.frame_id}, content {res.content_id[:12]})"
        return await self.run(request, session, "show", act)

    async def play(self, request: web.Request, session: "Session") -> web.Response:
        async def act(params):
            doc = await _json_body(request)
            key, loop = doc.get("asset"), doc.get("loop", False)
            params.update(asset=key, loop=loop)
            if not isinstance(key, str) or not key.strip():
                raise BadRequest("name the asset to play (its id, an id prefix or its name)")
            if not isinstance(loop, bool):
                raise BadRequest("loop must be true or false")
            st = self.coord.play_asset(key.strip(), loop=loop)
            return f"{st.state}: {st.name or st.asset_id[:12]} ({st.frames} frames at {st.fps:g} fps{', looped' if loop else ''})"
        return await self.run(request, session, "play", act)


    async def job(self, request: web.Request, session: "Session") -> web.Response:
        """Start a job (``{"kind": ..., "params": {...}}``); it runs on after the answer, and its
        stage, progress, time left and log reach the page through the live view."""
        async def act(params):
            doc = await _json_body(request)
            kind, opts = doc.get("kind"), doc.get("params", {})
            params.update(kind=kind, params=opts)
            if not isinstance(kind, str) or kind not in JOBS:
                raise BadRequest(f"unknown job {kind!r}: choose one of {', '.join(JOBS)}")
            if not isinstance(opts, dict):
                raise BadRequest("the job's options must be a JSON object")
            task = self.coord.start_job(kind, dict(opts))       # refused at once while a job holds the rig
            task.add_done_callback(_job_finished)
            await asyncio.sleep(0)      # let it take the job lock, so a second start is refused at once
            return f"{kind} started"
        return await self.run(request, session, "job", act)

    async def cancel_job(self, request: web.Request, session: "Session") -> web.Response:
        async def act(params):
            return f"{self.coord.cancel_job()} cancelled"
        return await self.run(request, session, "cancel job", act)


def _job_finished(task: asyncio.Task) -> None:
    """A console-started job ended: its outcome is in the tracker; an error is logged here too."""
    if task.cancelled():
        return
    exc = task.exception()
    if exc is not None:
        log.warning("console job failed: %s", exc)


async def _multipart(request: web.Request) -> dict[str, tuple[bytes, str]]:
    """The form's fields as name -> (bytes, file name); BadRequest past MAX_UPLOAD_BYTES."""
    if not request.content_type.startswith("multipart/"):
        raise BadRequest("send the image as a multipart form (field `image`)")
    reader = await request.multipart()
    out: dict[str, tuple[bytes, str]] = {}
    total = 0
    while True:
        part = await reader.next()
        if part is None:
            break
        if not hasattr(part, "read_chunk") or not part.name:
            continue
        chunks = []
        while True:
            chunk = await part.read_chunk(1 << 20)
            if not chunk:
                break
            total += len(chunk)
            if total > MAX_UPLOAD_BYTES:
                raise BadRequest(f"the upload is larger than {MAX_UPLOAD_BYTES >> 20} MiB")
            chunks.append(chunk)
        out[part.name] = (b"".join(chunks), part.filename or "")
    return out
