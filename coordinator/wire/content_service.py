"""The ContentStore service: the rig's assets listed, uploaded and removed from an operator's
machine (``shadowless content … --coordinator HOST:PORT``).

The wire edge of :mod:`coordinator.uploads` and :class:`coordinator.assets.AssetStore`: every
call needs an operator session (RigControl's Login); disk work runs in worker threads, so the
coordinator's event loop keeps serving nodes while a multi-GB upload is hashed. What the
coordinator adds here its distribution picks up like any other asset (it watches the store).
An asset added or removed is an entry of the rig's action log (``cli content add``/``remove``),
done or refused, as every command-line call that changes the rig (:mod:`coordinator.wire.calls`).
"""
from __future__ import annotations

import asyncio
import logging
from typing import Any

import grpc

from coordinator.assets import AssetStore
from coordinator.errors import AssetError, Refusal
from coordinator.sessions import Handshake
from coordinator.uploads import UploadFile, Uploads
from coordinator.wire.calls import abort, record, record_failure, session_id
from protos import control_pb2, control_pb2_grpc

log = logging.getLogger(__name__)

#: the most bytes one UploadFile message may carry
MAX_CHUNK_BYTES = 1 << 20


def _info(asset_id: str, manifest_bytes: bytes, *, existed: bool = False, notes=()) -> control_pb2.AssetInfo:
    return control_pb2.AssetInfo(asset_id=asset_id, manifest=manifest_bytes, existed=existed, notes=list(notes))


class ContentStoreService(control_pb2_grpc.ContentStoreServicer):
    """See the module docstring. ``handshake`` checks operator sessions."""

    def __init__(self, store: AssetStore, handshake: Handshake):
        self.store = store
        self.uploads = Uploads(store)
        self.handshake = handshake
        from coordinator.console.audit import ActionLog     # not at start: tests/coordinator/test_startup_imports.py
        self.action_log = ActionLog(store.rig_dir)
        swept = self.uploads.sweep()
        if swept:
            log.info("removed %d stale upload(s)", len(swept))

    async def _call(self, context: Any, fn, *args, logged: tuple[str, dict] | None = None, **kwargs):
        """Check the operator's session, run ``fn`` in a thread, turn errors into statuses;
        ``logged`` (action, params): a refusal is an entry of the action log too."""
        try:
            self.handshake.check_operator(session_id(context))
            return await asyncio.to_thread(fn, *args, **kwargs)
        except (Refusal, AssetError, ValueError) as exc:
            if logged is not None:
                await record_failure(self.action_log, context, logged[0], exc, logged[1])
            await self._abort(context, exc)

    async def _abort(self, context: Any, exc: Exception):
        if isinstance(exc, Refusal):
            await abort(context, exc)
        if isinstance(exc, AssetError):
            code = grpc.StatusCode.NOT_FOUND if str(exc).startswith("no asset") else grpc.StatusCode.FAILED_PRECONDITION
            await context.abort(code, str(exc))
        await context.abort(grpc.StatusCode.INVALID_ARGUMENT, str(exc))

    async def ListAssets(self, request, context):
        rows = await self._call(context, self.store.list)
        return control_pb2.AssetList(assets=[_info(aid, m.canonical()) for aid, m in rows])

    async def BeginUpload(self, request, context):
        files = [UploadFile(f.name, f.size, f.sha256) for f in request.files]
        uid, have = await self._call(context, self.uploads.begin, files)
        log.info("upload %s: %d file(s), %d of %d bytes held", uid[:12], len(files), sum(have),
                 sum(f.size for f in files))
        return control_pb2.UploadState(upload_id=uid, have=have)

    async def UploadFile(self, request_iterator, context):
        first, uid, index, offset = True, "", 0, 0
        async for msg in request_iterator:
            if first:
                uid, index, offset, first = msg.upload_id, msg.file, msg.offset, False
            if len(msg.data) > MAX_CHUNK_BYTES:
                await context.abort(grpc.StatusCode.INVALID_ARGUMENT,
                                    f"a chunk carries at most {MAX_CHUNK_BYTES} bytes, not {len(msg.data)}")
            if msg.data:
                offset = await self._call(context, self.uploads.append, uid, index, offset, msg.data)
        if first:
            await context.abort(grpc.StatusCode.INVALID_ARGUMENT, "an empty UploadFile call names no upload")
        have = await self._call(context, self.uploads.have, uid)
        return control_pb2.UploadState(upload_id=uid, have=have)

    async def FinishUpload(self, request, context):
        params = {"upload": request.upload_id[:12], "name": request.name, "fps": request.fps}
        added = await self._call(context, self.uploads.finish, request.upload_id, name=request.name or None,
                                 fps=request.fps or None, logged=("content add", params))
        m = added.manifest
        log.info("asset %s (%s %r) %s from an upload", m.asset_id[:12], m.kind, m.name,
                 "was already stored" if added.existed else "added")
        await record(self.action_log, context, "content add", ok=True, params=params,
                     result=f"asset {m.asset_id[:12]} ({m.kind} {m.name!r}) "
                            f"{'was already stored' if added.existed else 'added'}")
        return _info(m.asset_id, m.canonical(), existed=added.existed, notes=added.notes)

    async def RemoveAsset(self, request, context):
        def remove():
            aid = self.store.resolve(request.asset)
            data = self.store.manifest_path(aid).read_bytes()
            self.store.remove(aid)
            return aid, data

        aid, data = await self._call(context, remove, logged=("content remove", {"asset": request.asset}))
        log.info("asset %s removed by an operator", aid[:12])
        await record(self.action_log, context, "content remove", ok=True, params={"asset": request.asset},
                     result=f"asset {aid[:12]} removed")
        return _info(aid, data)


def add_to_server(server: grpc.aio.Server, store: AssetStore, handshake: Handshake) -> ContentStoreService:
    service = ContentStoreService(store, handshake)
    control_pb2_grpc.add_ContentStoreServicer_to_server(service, server)
    return service
