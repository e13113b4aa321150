"""The RigControl service: what the coordinator serves its operators.

Every call but the handshake needs an operator session (checked from the call's metadata before
any image byte is read), and every call that changes the rig is an entry of the rig's action log
(who: ``token``, the command line's login; the caller's address; ``cli <action>``; done or why
not). Requests become plain types (:mod:`coordinator.wire.control_messages`, images through
:mod:`coordinator.wire.image_parts`), the coordinator acts (seen as a
:class:`coordinator.ports.ServiceRig`), and results go back as messages.
"""
from __future__ import annotations

import asyncio
import contextlib
import logging
from typing import TYPE_CHECKING, Any

import grpc
import numpy as np

from coordinator.api import Space
from coordinator.cues import edge_logs
from coordinator.errors import OPERATOR_ERRORS, CoordinatorError, Refusal
from coordinator.float_range import check_float_range
from coordinator.rig import Content
from coordinator.users import TOKEN_WHO
from coordinator.wire import control_messages
from coordinator.wire.calls import abort, abort_for, guard, logged, record, record_failure, session_id
from coordinator.wire.handshake_service import HandshakeService
from coordinator.wire.image_parts import ImageParts, regions_from_request
from coordinator.wire.node_messages import space_from_message
from protos import codec, common_pb2, control_pb2
from protos.cues import CueList

if TYPE_CHECKING:  # pragma: no cover - types only
    from coordinator.console.audit import ActionLog

log = logging.getLogger(__name__)


class _Caller:
    """A call's caller as the action log names it, read as the call starts: the entry of a call its
    client cancelled may be written after gRPC let the call go (RunJob's, in the finally of a handler
    that yields), when the context's ``peer()`` reads freed memory: the coordinator died of a
    segmentation fault (tests/coordinator/test_cancel_operator_calls.py)."""

    def __init__(self, context: Any):
        self._peer = context.peer()

    def peer(self) -> str:
        return self._peer


def _decoded(image: Any) -> np.ndarray:
    img = codec.decode_image(image)
    img = img.astype(np.float32) if img.dtype == np.float16 else img
    return check_float_range(img, "the image", hint="clip it before sending (shadowless show/play --clip)")


def _show_params(request) -> dict[str, Any]:
    return {k: v for k, v in (("frame", request.frame), ("at_ns", request.at_ns), ("delay_ms", request.delay_ms)) if v}


def _show_result(request, state) -> str:
    return f"{state.name or state.asset_id[:12] or 'the show'} {state.state} at frame {state.frame}"


class RigControlService(HandshakeService):
    """RigControl: an operator logs in, then asks for the rig's status, shows and plays, runs jobs,
    configures slots and drives the timeline show. Every call that changes the rig is an entry of
    the rig's action log (:func:`coordinator.wire.calls.logged`)."""

    _action_log: "ActionLog | None" = None

    @property
    def action_log(self) -> "ActionLog":
        """The rig's action log (the console's and OSC's too: one log per rig directory)."""
        if self._action_log is None:
            from coordinator.console.audit import ActionLog     # not at start: tests/coordinator/test_startup_imports.py
            self._action_log = ActionLog(self.c.rig.path)
        return self._action_log

    def _operator(self, context) -> None:
        self.c.handshake.check_operator(session_id(context))

    @guard
    async def Login(self, request, context):
        self._check_login(request, context, "operator")
        return common_pb2.LoginReply(session=self.c.handshake.open_operator_session(), rig_id=self.c.rig.config.rig_id,
                                     instance_id=self.c.instance_id)

    @guard
    async def Status(self, request, context):
        self._operator(context)
        return control_messages.status_message(self.c.status())

    @guard
    async def ListNodes(self, request, context):
        self._operator(context)
        return control_messages.nodes_message(self.c.status().nodes)

    async def Show(self, request_iterator, context):
        params: dict[str, Any] = {}
        try:
            self._operator(context)   # from the call's metadata, before any image byte is read
            first, image = None, ImageParts()
            async for part in request_iterator:
                if first is None:
                    first = part
                    image.start(part.image)
                else:
                    image.add(part.more)
            if first is None:
                raise ValueError("a Show call sent no image")
            params.update(name=first.name, space=first.space, persist=first.persist, fit=first.fit,
                          regions=len(first.slot_regions))
            space = space_from_message(first.space)
            img = image.finish()
            regions = regions_from_request(first)
            if regions and (first.persist or space != Space.CONTENT):
                raise ValueError("slot regions apply to a content-space show that is not persisted")

            def prepare():   # decoded, fitted, masked and packed for the nodes off the event loop
                content = self.c.prepare_still(Content(_decoded(img), name=first.name), space, fit=first.fit)
                return content, self.c.prepare_regions(content, regions) if regions else None

            content, slot_contents = await asyncio.to_thread(prepare)
            apply_lut = first.apply_lut or space == Space.CONTENT
            res = self.c.show(content, space=space, apply_lut=apply_lut, persist=first.persist,
                              slot_contents=slot_contents)
            await record(self.action_log, context, "show", ok=True, params=params, result=f"showing "
                         f"{first.name or 'an image'} (frame {res.frame_id}, content {res.content_id[:12]})")
            return control_messages.show_result_message(res)
        except (Refusal, ValueError, codec.ImageCodecError, *OPERATOR_ERRORS) as exc:
            await record_failure(self.action_log, context, "show", exc, params)
            await abort_for(context, exc)

    async def Play(self, request_iterator, context):
        params: dict[str, Any] = {}
        caller = _Caller(context)   # for the entry of a call cancelled by its client, written after its end
        try:
            self._operator(context)   # from the call's metadata, before any frame is read
            settings = None
            frames: list[Content] = []
            image = ImageParts()

            def take_frame() -> None:
                if image.started:
                    frames.append(Content(_decoded(image.finish())))

            async for item in request_iterator:
                kind = item.WhichOneof("item")
                if kind == "settings":
                    settings = control_messages.play_settings_from_message(item.settings)
                elif kind == "frame":
                    take_frame()
                    image.start(item.frame)
                elif kind == "more":
                    image.add(item.more)
            take_frame()
            if settings is None:
                raise ValueError("the first PlayItem must carry the settings")
            params.update(frames=len(frames), pattern=getattr(settings, "pattern", "") or "")
            try:
                result = await self.c.play_sequence(None if settings.pattern else frames, settings)
            except asyncio.CancelledError:
                # the operator went away (Ctrl-C): the sequence stops on the rig too
                log.info("play cancelled by its client: stopping the sequence")
                with contextlib.suppress(CoordinatorError):
                    self.c.stop_all()
                await asyncio.shield(record(self.action_log, caller, "play", ok=False, params=params,
                                            result="cancelled by its client: the sequence stopped"))
                raise
            await record(self.action_log, context, "play", ok=True, params=params,
                         result=f"{result.frames_shown} of {result.frames_sent} frames shown on {result.nodes} nodes")
            return control_messages.play_result_message(result)
        except (Refusal, ValueError, codec.ImageCodecError, *OPERATOR_ERRORS) as exc:
            await record_failure(self.action_log, context, "play", exc, params)
            await abort_for(context, exc)

    @guard
    @logged(lambda r: "blackout" if r.blackout else "stop", result=lambda r, reply: f"showing {reply.showing}")
    async def Stop(self, request, context):
        self._operator(context)
        return control_pb2.StopReply(showing=self.c.stop_all(blackout=request.blackout))

    async def RunJob(self, request, context):
        what = f"job {request.kind[:40]}"
        caller = _Caller(context)   # for the entry of a call cancelled by its client, written after its end
        try:
            self._operator(context)
            params = control_messages.job_params_from_request(request)
        except Refusal as exc:
            await record_failure(self.action_log, context, what, exc)
            await abort(context, exc)
        except ValueError as exc:
            await record_failure(self.action_log, context, what, ValueError(f"bad job parameters: {exc}"))
            await context.abort(grpc.StatusCode.INVALID_ARGUMENT, f"bad job parameters: {exc}")
        logged_params = {k: v for k, v in params.items() if isinstance(v, (str, int, float, bool))}
        events: asyncio.Queue = asyncio.Queue()
        task = asyncio.create_task(self.c.run_job(request.kind, params, events.put_nowait), name=f"job:{request.kind}")
        getter: asyncio.Future | None = None
        try:
            while True:
                getter = asyncio.ensure_future(events.get())
                done, _ = await asyncio.wait({getter, task}, return_when=asyncio.FIRST_COMPLETED)
                if getter in done:
                    yield control_messages.job_event_message(getter.result())
                    continue
                getter.cancel()
                while not events.empty():
                    yield control_messages.job_event_message(events.get_nowait())
                break
            try:
                result = task.result()
            except (*OPERATOR_ERRORS, ValueError, OSError) as exc:
                log.error("job %s failed: %s", request.kind, exc)
                await record_failure(self.action_log, context, what, exc, logged_params)
                await context.abort(grpc.StatusCode.FAILED_PRECONDITION, f"{request.kind}: {exc}")
            await record(self.action_log, context, what, ok=True, result=f"{request.kind} finished",
                         params=logged_params)
            yield control_messages.job_result_message(result)
        finally:
            if getter is not None and not getter.done():    # cancelled while waiting: no event will come for it
                getter.cancel()
            if not task.done():
                log.warning("job %s cancelled by its client", request.kind)
                task.cancel()
                await asyncio.gather(task, return_exceptions=True)
                await asyncio.shield(record(self.action_log, caller, what, ok=False, params=logged_params,
                                            result=f"{request.kind} cancelled by its client"))

    @guard
    @logged("configure", params=lambda r: {"slot": r.slot, "fields": sorted(f.name for f, _ in r.ListFields()
                                                                               if f.name != "slot")},
            result=lambda r, reply: f"slot {r.slot} at revision {reply.revision}")
    async def Configure(self, request, context):
        self._operator(context)
        changes = control_messages.slot_changes_from_message(request, mesh_lookup=self.c.rig.mesh)
        if not changes:
            raise ValueError(f"nothing to change on slot {request.slot!r}: give a homography or a projection pose, "
                             "a LUT, a gain, an output size or clear the pose")
        st = self.c.update_slot(request.slot, **changes)
        return control_pb2.ConfigureReply(revision=st.revision)

    # ---------------------------------------------------------------- timeline shows
    @guard
    @logged("play asset",
            params=lambda r: {"asset": r.asset, "loop": r.loop, "at_ns": r.at_ns, "delay_ms": r.delay_ms},
            result=lambda r, s: f"{s.state}: {s.name or s.asset_id[:12]} ({s.frames} frames"
                                f"{', looped' if r.loop else ''})")
    async def PlayAsset(self, request, context):
        self._operator(context)
        state = self.c.play_asset(request.asset, at_ns=request.at_ns or None,
                                  delay_ns=int(request.delay_ms * 1e6) or None, loop=request.loop,
                                  fps=request.fps or None, start_without=request.start_without)
        return control_messages.show_state_message(state)

    async def _control(self, action: str, request, context):
        self._operator(context)
        state = self.c.show_control(action, at_ns=request.at_ns or None, delay_ns=int(request.delay_ms * 1e6) or None,
                                    frame=request.frame)
        return control_messages.show_state_message(state)

    @guard
    @logged("pause", params=_show_params, result=_show_result)
    async def PauseShow(self, request, context):
        return await self._control("pause", request, context)

    @guard
    @logged("resume", params=_show_params, result=_show_result)
    async def ResumeShow(self, request, context):
        return await self._control("resume", request, context)

    @guard
    @logged("seek", params=_show_params, result=_show_result)
    async def SeekShow(self, request, context):
        return await self._control("seek", request, context)

    @guard
    @logged("stop show", params=_show_params, result=_show_result)
    async def StopShow(self, request, context):
        return await self._control("stop", request, context)

    # ---------------------------------------------------------------- the cue list (coordinator/cues.py)
    @guard
    async def GetCues(self, request, context):
        self._operator(context)
        return control_messages.cue_reply(self.c.cue_state())

    @guard
    @logged("cues", result=lambda r, reply: reply.result)
    async def SetCues(self, request, context):
        self._operator(context)
        result = self.c.set_cues(CueList.loads(request.cues_json), who=TOKEN_WHO)
        return control_messages.cue_reply(self.c.cue_state(), result)

    @guard
    @logged(lambda r: f"cue {r.action}"[:40], params=lambda r: {"id": r.cue_id} if r.cue_id else {},
            result=lambda r, reply: reply.result)
    async def FireCue(self, request, context):
        self._operator(context)
        with edge_logs():       # this call's entry is the fire's one
            result = self._fire(request)
        return control_messages.cue_reply(self.c.cue_state(), result)

    def _fire(self, request) -> str:
        who = TOKEN_WHO
        if request.action == "go":
            return self.c.cue_go(who=who)
        if request.action == "back":
            return self.c.cue_back(who=who)
        if request.action == "jump":
            return self.c.cue_jump(request.cue_id, who=who)
        raise ValueError(f"unknown cue action {request.action!r} (go, back or jump)")

    # ---------------------------------------------------------------- per-slot tools (coordinator/slot_tools.py)
    @guard
    @logged("pattern", params=lambda r: {"pattern": r.pattern, "slots": list(r.slots)},
            result=lambda r, reply: f"showing {reply.showing}")
    async def ShowTestPattern(self, request, context):
        self._operator(context)
        showing = await self.c.show_test_pattern(request.pattern, list(request.slots) or None)
        return control_pb2.StopReply(showing=showing)

    @guard
    @logged("solo", params=lambda r: {"slots": list(r.slots)}, result=lambda r, reply: f"showing {reply.showing}")
    async def Solo(self, request, context):
        self._operator(context)
        return control_pb2.StopReply(showing=self.c.solo(list(request.slots)))
