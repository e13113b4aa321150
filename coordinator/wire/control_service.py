"""The RigControl service: what the coordinator serves its operators.

Every call but the handshake needs an operator session (checked from the call's metadata before
any image byte is read). Requests become plain types (:mod:`coordinator.wire.control_messages`,
images through :mod:`coordinator.wire.image_parts`), the coordinator acts (seen as a
:class:`coordinator.ports.ServiceRig`), and results go back as messages.
"""
from __future__ import annotations

import asyncio
import contextlib
import logging
from typing import Any

import grpc
import numpy as np

from coordinator.api import Space
from coordinator.errors import OPERATOR_ERRORS, CoordinatorError, Refusal
from coordinator.float_range import check_float_range
from coordinator.rig import Content
from coordinator.wire import control_messages
from coordinator.wire.calls import abort, abort_for, guard, session_id
from coordinator.wire.handshake_service import HandshakeService
from coordinator.wire.image_parts import ImageParts, regions_from_request
from coordinator.wire.node_messages import space_from_message
from protos import codec, common_pb2, control_pb2
from protos.cues import CueList

log = logging.getLogger(__name__)


def _decoded(image: Any) -> np.ndarray:
    img = codec.decode_image(image)
    img = img.astype(np.float32) if img.dtype == np.float16 else img
    return check_float_range(img, "the image", hint="clip it before sending (shadowless show/play --clip)")


class RigControlService(HandshakeService):
    """RigControl: an operator logs in, then asks for the rig's status, shows and plays, runs jobs,
    configures slots and drives the timeline show."""

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
            return control_messages.show_result_message(self.c.show(content, space=space, apply_lut=apply_lut,
                                                        persist=first.persist, slot_contents=slot_contents))
        except (Refusal, ValueError, codec.ImageCodecError, *OPERATOR_ERRORS) as exc:
            await abort_for(context, exc)

    async def Play(self, request_iterator, context):
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
            try:
                result = await self.c.play_sequence(None if settings.pattern else frames, settings)
            except asyncio.CancelledError:
                # the operator went away (Ctrl-C): the sequence stops on the rig too
                log.info("play cancelled by its client: stopping the sequence")
                with contextlib.suppress(CoordinatorError):
                    self.c.stop_all()
                raise
            return control_messages.play_result_message(result)
        except (Refusal, ValueError, codec.ImageCodecError, *OPERATOR_ERRORS) as exc:
            await abort_for(context, exc)

    @guard
    async def Stop(self, request, context):
        self._operator(context)
        return control_pb2.StopReply(showing=self.c.stop_all(blackout=request.blackout))

    async def RunJob(self, request, context):
        try:
            self._operator(context)
            params = control_messages.job_params_from_request(request)
        except Refusal as exc:
            await abort(context, exc)
        except ValueError as exc:
            await context.abort(grpc.StatusCode.INVALID_ARGUMENT, f"bad job parameters: {exc}")
        events: asyncio.Queue = asyncio.Queue()
        task = asyncio.create_task(self.c.run_job(request.kind, params, events.put_nowait), name=f"job:{request.kind}")
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
                await context.abort(grpc.StatusCode.FAILED_PRECONDITION, f"{request.kind}: {exc}")
            yield control_messages.job_result_message(result)
        finally:
            if not task.done():
                log.warning("job %s cancelled by its client", request.kind)
                task.cancel()
                await asyncio.gather(task, return_exceptions=True)

    @guard
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
    async def PauseShow(self, request, context):
        return await self._control("pause", request, context)

    @guard
    async def ResumeShow(self, request, context):
        return await self._control("resume", request, context)

    @guard
    async def SeekShow(self, request, context):
        return await self._control("seek", request, context)

    @guard
    async def StopShow(self, request, context):
        return await self._control("stop", request, context)

    # ---------------------------------------------------------------- the cue list (coordinator/cues.py)
    @guard
    async def GetCues(self, request, context):
        self._operator(context)
        return control_messages.cue_reply(self.c.cue_state())

    @guard
    async def SetCues(self, request, context):
        self._operator(context)
        result = self.c.set_cues(CueList.loads(request.cues_json), who=control_messages.cli_who(context.peer()))
        return control_messages.cue_reply(self.c.cue_state(), result)

    @guard
    async def FireCue(self, request, context):
        self._operator(context)
        who = control_messages.cli_who(context.peer())
        if request.action == "go":
            result = self.c.cue_go(who=who)
        elif request.action == "back":
            result = self.c.cue_back(who=who)
        elif request.action == "jump":
            result = self.c.cue_jump(request.cue_id, who=who)
        else:
            raise ValueError(f"unknown cue action {request.action!r} (go, back or jump)")
        return control_messages.cue_reply(self.c.cue_state(), result)

    # ---------------------------------------------------------------- per-slot tools (coordinator/slot_tools.py)
    @guard
    async def ShowTestPattern(self, request, context):
        self._operator(context)
        showing = await self.c.show_test_pattern(request.pattern, list(request.slots) or None)
        return control_pb2.StopReply(showing=showing)

    @guard
    async def Solo(self, request, context):
        self._operator(context)
        return control_pb2.StopReply(showing=self.c.solo(list(request.slots)))
