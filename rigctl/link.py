"""The operator's link to a running coordinator: RigControl and ContentStore over gRPC.

It proves knowledge of the rig token (the same handshake the nodes use), then speaks the
plain types of :mod:`coordinator.api`: callers never see a protobuf message, nor a gRPC error.
A call the coordinator refuses, or that fails on the way, raises
:class:`rigctl.client.CallRefused` (an :class:`~rigctl.client.OperatorError`) with the status's
name and the coordinator's words, as :mod:`node.link` raises ``LinkError`` for a node.

    async with await Client.connect("127.0.0.1:7600", token) as c:
        status = await c.status()          # a RigStatus dataclass
"""
from __future__ import annotations

import functools
from typing import AsyncIterator, Callable, Mapping, Sequence

import grpc
import numpy as np

from coordinator.api import PlayResult, PlaySettings, RigStatus, ShowResult, ShowState, Space
from coordinator.jobs.context import Event
from coordinator.wire import control_messages
from coordinator.wire.image_parts import play_frame_items, show_request_parts
from protos import auth, common_pb2, control_pb2, control_pb2_grpc
from protos.asset_manifest import Manifest
from protos.version import GRPC_OPTIONS, PROTOCOL_VERSION, SESSION_KEY
from rigctl.client import CallRefused, OperatorError


def refused(exc: grpc.RpcError) -> CallRefused:
    """``exc`` in the operator's terms: its status's name and the coordinator's words."""
    code = exc.code()
    return CallRefused(code.name if code is not None else "UNKNOWN", exc.details() or "")


def _translated(fn):
    """A call of :class:`Client` whose gRPC errors become :class:`CallRefused`."""

    @functools.wraps(fn)
    async def call(*args, **kwargs):
        try:
            return await fn(*args, **kwargs)
        except grpc.RpcError as exc:
            raise refused(exc) from exc

    return call


class Client:
    """An authenticated RigControl client. ``async with await Client.connect(...) as c: await c.status()``."""

    def __init__(self, channel: grpc.aio.Channel, stub: control_pb2_grpc.RigControlStub, session: str):
        self.channel, self.stub, self.session = channel, stub, session
        self.md = ((SESSION_KEY, session),)

    @classmethod
    async def connect(cls, target: str, token: bytes, *, tls_ca: bytes | None = None,
                      tls_server_name: str | None = None, rig_id: str = "", token_source: str = "") -> "Client":
        """Prove the token to the coordinator at ``target`` (and it to us) and log in. With
        ``rig_id``, a coordinator of another rig is refused before anything is sent to it
        (OperatorError naming both ids); ``token_source`` names the token file in errors."""
        options = list(GRPC_OPTIONS)
        if tls_ca is not None:
            if tls_server_name:
                options.append(("grpc.ssl_target_name_override", tls_server_name))
            channel = grpc.aio.secure_channel(target, grpc.ssl_channel_credentials(tls_ca), options=options)
        else:
            channel = grpc.aio.insecure_channel(target, options=options)
        stub = control_pb2_grpc.RigControlStub(channel)
        try:
            cn = auth.new_nonce()
            hello = await stub.Hello(common_pb2.HelloRequest(protocol_version=PROTOCOL_VERSION, client_nonce=cn,
                                                             role="operator"), timeout=10)
            if rig_id and hello.rig_id != rig_id:
                raise OperatorError(f"the coordinator at {target} serves rig {hello.rig_name!r} (id {hello.rig_id}), "
                                    f"not rig id {rig_id}: another rig's coordinator")
            if not auth.verify(auth.coordinator_proof(token, hello.rig_id, cn, hello.server_nonce), hello.server_proof):
                raise OperatorError(f"the coordinator at {target} (rig {hello.rig_name!r}) could not prove it knows "
                                    f"the token{' in ' + token_source if token_source else ''}: another rig's "
                                    "coordinator with the same id, or the wrong token file")
            proof = auth.client_proof(token, "operator", hello.rig_id, "", cn, hello.server_nonce)
            reply = await stub.Login(common_pb2.LoginRequest(protocol_version=PROTOCOL_VERSION, role="operator",
                                                             client_nonce=cn, server_nonce=hello.server_nonce,
                                                             client_proof=proof), timeout=10)
        except grpc.aio.AioRpcError as exc:
            await channel.close()
            raise OperatorError(f"coordinator at {target}: {exc.details() or exc.code().name}") from exc
        except BaseException:
            await channel.close()
            raise
        return cls(channel, stub, reply.session)

    async def __aenter__(self) -> "Client":
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    async def close(self) -> None:
        await self.channel.close()

    @_translated
    async def status(self) -> RigStatus:
        return control_messages.status_from_message(await self.stub.Status(control_pb2.StatusRequest(), metadata=self.md, timeout=10))

    @_translated
    async def show(self, image: np.ndarray, *, name: str = "", persist: bool = False, space: Space = Space.CONTENT,
                   apply_lut: bool = True, fit: str = "",
                   slot_regions: Mapping[str, Sequence[tuple[int, int, int, int]]] | None = None) -> ShowResult:
        """Show ``image`` on every node and hold it. ``fit``: how an image of another aspect than
        the content area is fitted ("stretch", "contain", "cover"); "" refuses it (CallRefused,
        INVALID_ARGUMENT, naming both sizes and the choices). ``slot_regions``: slot -> rectangles
        ``(x, y, width, height)`` of the fitted content, the only parts that slot shows (none: black;
        slots not named show all; see :mod:`coordinator.slot_regions`)."""
        parts = show_request_parts(image, name=name, persist=persist, space=space, apply_lut=apply_lut, fit=fit,
                                        slot_regions=slot_regions)

        async def items():
            for part in parts:
                yield part

        return control_messages.show_result_from_message(await self.stub.Show(items(), metadata=self.md, timeout=120))

    @_translated
    async def play(self, settings: PlaySettings, frames: Sequence[np.ndarray] = ()) -> PlayResult:
        """Play ``frames`` (or the settings' pattern); with ``settings.wait`` the figures once played.
        Cancelling the call (Ctrl-C) stops the sequence on the rig."""
        async def items():
            yield control_pb2.PlayItem(settings=control_messages.play_settings_message(settings))
            for f in frames:
                for part in play_frame_items(f):
                    yield part

        return control_messages.play_result_from_message(await self.stub.Play(items(), metadata=self.md))

    @_translated
    async def stop(self, *, blackout: bool = False) -> str:
        """Stop a sequence or a timeline show: the rig's content comes back (black with
        ``blackout``). Returns what the rig shows now."""
        reply = await self.stub.Stop(control_pb2.StopRequest(blackout=blackout), metadata=self.md, timeout=10)
        return reply.showing

    # ---------------------------------------------------------------- timeline shows
    @_translated
    async def play_asset(self, asset: str, *, delay_s: float = 0.0, at_ns: int = 0, loop: bool = False,
                         fps: float = 0.0, start_without: bool = False) -> ShowState:
        """Play asset ``asset`` (id, prefix or name) from the rig's store on every node, ``delay_s``
        from now (0: the coordinator's lead) or at rig time ``at_ns``; the resulting show state."""
        req = control_messages.play_asset_request(asset, at_ns=at_ns, delay_ms=delay_s * 1e3, loop=loop, fps=fps,
                                      start_without=start_without)
        return control_messages.show_state_from_message(await self.stub.PlayAsset(req, metadata=self.md, timeout=10))

    @_translated
    async def _show_control(self, rpc, *, delay_s: float = 0.0, at_ns: int = 0, frame: int = 0) -> ShowState:
        req = control_messages.show_control_request(at_ns=at_ns, delay_ms=delay_s * 1e3, frame=frame)
        return control_messages.show_state_from_message(await rpc(req, metadata=self.md, timeout=10))

    async def pause_show(self, *, delay_s: float = 0.0, at_ns: int = 0) -> ShowState:
        return await self._show_control(self.stub.PauseShow, delay_s=delay_s, at_ns=at_ns)

    async def resume_show(self, *, delay_s: float = 0.0, at_ns: int = 0) -> ShowState:
        return await self._show_control(self.stub.ResumeShow, delay_s=delay_s, at_ns=at_ns)

    async def seek_show(self, frame: int, *, delay_s: float = 0.0, at_ns: int = 0) -> ShowState:
        return await self._show_control(self.stub.SeekShow, delay_s=delay_s, at_ns=at_ns, frame=frame)

    async def stop_show(self, *, delay_s: float = 0.0, at_ns: int = 0) -> ShowState:
        return await self._show_control(self.stub.StopShow, delay_s=delay_s, at_ns=at_ns)

    # ---------------------------------------------------------------- per-slot tools
    @_translated
    async def show_test_pattern(self, pattern: str, slots: list[str] | None = None) -> str:
        """Test pattern ``pattern`` on ``slots`` (None: every slot), the others black; what the rig shows now."""
        req = control_pb2.SlotToolRequest(pattern=pattern, slots=list(slots or ()))
        return (await self.stub.ShowTestPattern(req, metadata=self.md, timeout=30)).showing

    @_translated
    async def solo(self, slots: list[str]) -> str:
        """Only ``slots`` go on showing the still on screen, the others black (``[]``: the solo ends)."""
        req = control_pb2.SlotToolRequest(slots=list(slots))
        return (await self.stub.Solo(req, metadata=self.md, timeout=10)).showing

    # ---------------------------------------------------------------- the cue list
    @_translated
    async def cues(self) -> tuple[dict, str]:
        """The cue state as JSON (cues, current, next, fired_at, fading, follow_at) and ""."""
        reply = await self.stub.GetCues(control_pb2.StatusRequest(), metadata=self.md, timeout=10)
        return control_messages.cue_reply_from_message(reply)

    @_translated
    async def set_cues(self, cues_json: str) -> tuple[dict, str]:
        """Replace the cue list (protos/cues.py's JSON); the new state and the coordinator's line."""
        reply = await self.stub.SetCues(control_pb2.CueListRequest(cues_json=cues_json), metadata=self.md, timeout=10)
        return control_messages.cue_reply_from_message(reply)

    @_translated
    async def fire_cue(self, action: str, cue_id: str = "") -> tuple[dict, str]:
        """``go``, ``back`` or ``jump`` (to ``cue_id``); the new state and what fired."""
        reply = await self.stub.FireCue(control_pb2.CueActionRequest(action=action, cue_id=cue_id), metadata=self.md,
                                        timeout=10)
        return control_messages.cue_reply_from_message(reply)

    @_translated
    async def configure(self, slot: str, *, homography: np.ndarray | None = None, lut: np.ndarray | None = None,
                        gain: float | None = None, size: tuple[int, int] | None = None,
                        clear_pose: bool = False, projection: np.ndarray | None = None,
                        mesh: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None, mesh_id: str = "") -> int:
        """Set a slot's pose/LUT/gain/size by hand; returns the slot's new revision. ``projection``:
        a (3, 4) pose on ``mesh`` (vertices, uvs, faces) or on the rig's mesh ``mesh_id``."""
        req = control_messages.configure_request(slot, homography=homography, lut=lut, gain=gain, size=size, clear_pose=clear_pose,
                                     projection=projection, mesh=mesh, mesh_id=mesh_id)
        return (await self.stub.Configure(req, metadata=self.md, timeout=10)).revision

    @_translated
    async def run_job(self, kind: str, params: dict, *, on_event: Callable[[Event], None] | None = None) -> dict:
        """Run job ``kind`` on the coordinator; progress and log lines go to ``on_event``; its result."""
        result: dict = {}
        call = self.stub.RunJob(control_messages.job_request(kind, params), metadata=self.md)
        async for msg in call:
            ev = control_messages.job_event_from_message(msg)
            if isinstance(ev, dict):
                result = ev
            elif on_event is not None:
                on_event(ev)
        return result

    # ---------------------------------------------------------------- the rig's content assets
    @property
    def content(self) -> control_pb2_grpc.ContentStoreStub:
        return control_pb2_grpc.ContentStoreStub(self.channel)

    @_translated
    async def list_assets(self) -> list[tuple[str, Manifest]]:
        reply = await self.content.ListAssets(control_pb2.StatusRequest(), metadata=self.md, timeout=30)
        return [(a.asset_id, Manifest.from_bytes(a.manifest, asset_id=a.asset_id)) for a in reply.assets]

    @_translated
    async def begin_upload(self, files: Sequence[tuple[str, int, str]]) -> tuple[str, list[int]]:
        """Announce an upload of ``files`` ``(name, size, sha256)``: its id and the bytes of each
        the coordinator already holds (resume from there)."""
        spec = control_pb2.UploadSpec(files=[control_pb2.UploadFileSpec(name=n, size=s, sha256=h) for n, s, h in files])
        reply = await self.content.BeginUpload(spec, metadata=self.md, timeout=60)
        return reply.upload_id, list(reply.have)

    @_translated
    async def upload_file(self, upload_id: str, index: int, offset: int, chunks: AsyncIterator[bytes]) -> list[int]:
        """Send file ``index`` of an upload from ``offset``, ``chunks`` of at most 1 MiB; bytes held after."""
        async def items():
            first = True
            async for data in chunks:
                if first:
                    yield control_pb2.UploadChunk(upload_id=upload_id, file=index, offset=offset, data=data)
                    first = False
                else:
                    yield control_pb2.UploadChunk(data=data)
            if first:
                yield control_pb2.UploadChunk(upload_id=upload_id, file=index, offset=offset)

        return list((await self.content.UploadFile(items(), metadata=self.md)).have)

    @_translated
    async def finish_upload(self, upload_id: str, *, name: str = "", fps: float = 0.0
                            ) -> tuple[Manifest, bool, list[str]]:
        """Add a complete upload as an asset: its manifest, whether the store had it, notes."""
        req = control_pb2.FinishUploadRequest(upload_id=upload_id, name=name, fps=fps)
        a = await self.content.FinishUpload(req, metadata=self.md, timeout=3600)
        return Manifest.from_bytes(a.manifest, asset_id=a.asset_id), a.existed, list(a.notes)

    @_translated
    async def remove_asset(self, key: str) -> tuple[str, Manifest | None]:
        """Remove asset ``key`` (id, unique prefix or name): its id and manifest (None if damaged)."""
        a = await self.content.RemoveAsset(control_pb2.AssetRef(asset=key), metadata=self.md, timeout=60)
        try:
            return a.asset_id, Manifest.from_bytes(a.manifest, asset_id=a.asset_id)
        except ValueError:
            return a.asset_id, None
