"""Bad network messages: every one gets a gRPC status that names what is wrong (never UNKNOWN
or INTERNAL), the coordinator logs no traceback and stores nothing."""
from __future__ import annotations

import asyncio
import hashlib
import json
import math
import os
from pathlib import Path

import grpc
import numpy as np
import pytest

from coordinator.wire import image_parts
from coordinator.api import Space
from protos import auth, codec, common_pb2, control_pb2, control_pb2_grpc, node_pb2, node_pb2_grpc
from protos.version import MAX_REQUEST_BYTES, PROTOCOL_VERSION, SESSION_KEY
from shadowless.local import LocalRig

S = grpc.StatusCode


def _hello(**kw):
    args = dict(protocol_version=PROTOCOL_VERSION, client_nonce=auth.new_nonce(), role="node", slot="r0c0")
    args.update(kw)
    return common_pb2.HelloRequest(**args)


async def _login(stub, token: bytes, *, role="node", slot="r0c0", tamper=False, reuse=None):
    """A LoginRequest after a real Hello (``tamper``: a wrong proof; ``reuse``: an old login)."""
    if reuse is not None:
        return reuse
    cn = auth.new_nonce()
    hello = await stub.Hello(_hello(client_nonce=cn, role=role, slot=slot))
    proof = auth.client_proof(token, role, hello.rig_id, slot, cn, hello.server_nonce)
    if tamper:
        proof = bytes(b ^ 1 for b in proof)
    return common_pb2.LoginRequest(protocol_version=PROTOCOL_VERSION, role=role, slot=slot, client_nonce=cn,
                                   server_nonce=hello.server_nonce, client_proof=proof)


def _image(shape=(32, 32, 3), dtype=np.uint8):
    return np.random.default_rng(0).integers(0, 200, shape).astype(dtype)


def _show_parts(img=None, **kw):
    args = dict(name="t", persist=False, space=Space.CONTENT, apply_lut=True, fit="")
    args.update(kw)
    return image_parts.show_request_parts(_image() if img is None else img, **args)


async def _stream(*items):
    for it in items:
        yield it


def _corrupt_image() -> common_pb2.Image:
    msg = codec.encode_image(_image(), compress=True)
    msg.data = msg.data[:10] + b"\x00" * 40
    return msg


def _node_cases(token):
    """(name, coroutine factory taking a NodeLink stub, expected code, words in the message)."""
    async def join(stub, **kw):
        login = await _login(stub, token, **{k: v for k, v in kw.items() if k in ("slot", "tamper", "role")})
        return await stub.Join(node_pb2.JoinRequest(login=login, info=node_pb2.NodeInfo(hostname="t")))

    async def replayed_join(stub):
        login = await _login(stub, token, slot="r0c1")
        await stub.Join(node_pb2.JoinRequest(login=login, info=node_pb2.NodeInfo(hostname="t")))
        return await stub.Join(node_pb2.JoinRequest(login=login, info=node_pb2.NodeInfo(hostname="t")))

    async def forged_nonce(stub):
        login = await _login(stub, token)
        login.server_nonce = os.urandom(32)
        return await stub.Join(node_pb2.JoinRequest(login=login))

    async def report_unequal(stub):
        login = await _login(stub, token, slot="r0c0")
        reply = await stub.Join(node_pb2.JoinRequest(login=login, info=node_pb2.NodeInfo(hostname="t")))
        rep = node_pb2.NodeReport(swaps=node_pb2.Swaps(frame_id=[1, 1], swap_rig_ns=[5], host_monotonic_ns=[5, 5]))
        return await stub.Report(_stream(rep), metadata=((SESSION_KEY, reply.session),))

    async def frames_without_session(stub):
        async for _ in stub.Frames(node_pb2.StreamRequest()):
            pass

    return [
        ("Hello of protocol 99", lambda st: st.Hello(_hello(protocol_version=99)), S.FAILED_PRECONDITION,
         ["protocol version mismatch", "99"]),
        ("Hello with a 5-byte nonce", lambda st: st.Hello(_hello(client_nonce=b"short")), S.INVALID_ARGUMENT,
         ["client nonce must be 32 bytes"]),
        ("Join with a wrong proof", lambda st: join(st, tamper=True), S.UNAUTHENTICATED, ["rig token mismatch"]),
        ("Join for an unknown slot", lambda st: join(st, slot="r9c9"), S.NOT_FOUND, ["r9c9", "r0c0, r0c1"]),
        ("Join in the operator role", lambda st: join(st, role="operator"), S.INVALID_ARGUMENT,
         ["for role 'node'"]),
        ("Join replayed", replayed_join, S.UNAUTHENTICATED, ["single use"]),
        ("Join with a forged server nonce", forged_nonce, S.UNAUTHENTICATED, ["expired or unknown"]),
        ("Frames without a session", frames_without_session, S.UNAUTHENTICATED, ["session"]),
        ("Report with columns of unequal length", report_unequal, S.INVALID_ARGUMENT, ["swap"]),
    ]


def _operator_cases():
    """(name, coroutine factory taking (RigControl stub, metadata), code, words)."""
    nan_gain = control_pb2.ConfigureRequest(slot="r0c0", gain=math.nan)
    return [
        ("Status without a session", lambda st, md: st.Status(control_pb2.StatusRequest()), S.UNAUTHENTICATED,
         ["not logged in"]),
        ("Show with no message", lambda st, md: st.Show(_stream(), metadata=md), S.INVALID_ARGUMENT,
         ["sent no image"]),
        ("Show of a 0-pixel-wide image", lambda st, md: st.Show(_stream(control_pb2.ShowRequest(
            image=common_pb2.Image(width=0, height=4, channels=1, dtype=common_pb2.DTYPE_UINT8))), metadata=md),
         S.INVALID_ARGUMENT, ["outside"]),
        # one surplus part: the client has sent everything before the refusal can race its next write
        ("Show sending more bytes than its size holds", lambda st, md: st.Show(_stream(
            _show_parts()[0], control_pb2.ShowRequest(more=b"\0" * (1 << 20))), metadata=md),
         S.INVALID_ARGUMENT, ["sent more than"]),
        ("Show of damaged image data", lambda st, md: st.Show(_stream(control_pb2.ShowRequest(
            image=_corrupt_image())), metadata=md), S.INVALID_ARGUMENT, ["image"]),
        ("Show of another aspect, no fit", lambda st, md: st.Show(_stream(*_show_parts(_image((32, 64, 3)))),
                                                                  metadata=md),
         S.INVALID_ARGUMENT, ["64x32", "32x32", "contain"]),
        ("Show with fit 'zoom'", lambda st, md: st.Show(_stream(*_show_parts(fit="zoom")), metadata=md),
         S.INVALID_ARGUMENT, ["unknown fit 'zoom'"]),
        ("Show larger than a message", lambda st, md: st.Show(_stream(control_pb2.ShowRequest(
            more=b"\0" * (MAX_REQUEST_BYTES + 1))), metadata=md), S.RESOURCE_EXHAUSTED, ["larger than max"]),
        ("Play without settings", lambda st, md: st.Play(_stream(*image_parts.play_frame_items(_image())), metadata=md),
         S.INVALID_ARGUMENT, ["settings"]),
        ("Play bytes before a frame", lambda st, md: st.Play(_stream(
            control_pb2.PlayItem(settings=control_pb2.PlaySettings(fps=30)), control_pb2.PlayItem(more=b"x")),
            metadata=md), S.INVALID_ARGUMENT, ["before the image"]),
        ("Play at -5 fps", lambda st, md: st.Play(_stream(
            control_pb2.PlayItem(settings=control_pb2.PlaySettings(fps=-5, wait=True)),
            *image_parts.play_frame_items(_image())), metadata=md), S.INVALID_ARGUMENT, ["fps", "-5"]),
        ("Play an unknown pattern", lambda st, md: st.Play(_stream(
            control_pb2.PlayItem(settings=control_pb2.PlaySettings(fps=30, pattern="plaid"))), metadata=md),
         S.INVALID_ARGUMENT, ["unknown pattern 'plaid'"]),
        ("Configure with nothing to change", lambda st, md: st.Configure(control_pb2.ConfigureRequest(slot="r0c0"),
                                                                         metadata=md),
         S.INVALID_ARGUMENT, ["nothing to change", "r0c0"]),
        ("Configure a NaN gain", lambda st, md: st.Configure(nan_gain, metadata=md), S.INVALID_ARGUMENT, ["gain"]),
        ("Configure a 5-value homography", lambda st, md: st.Configure(control_pb2.ConfigureRequest(
            slot="r0c0", homography=node_pb2.Homography(m=[1, 0, 0, 0, 1])), metadata=md),
         S.INVALID_ARGUMENT, ["homography"]),
        ("Configure an unknown slot", lambda st, md: st.Configure(control_pb2.ConfigureRequest(
            slot="nope", gain=1.0), metadata=md), None, ["nope"]),
        ("RunJob with broken JSON", lambda st, md: _drain(st.RunJob(control_pb2.JobRequest(
            kind="response", params_json="{"), metadata=md)), S.INVALID_ARGUMENT, ["bad job parameters"]),
        ("RunJob of an unknown kind", lambda st, md: _drain(st.RunJob(control_pb2.JobRequest(
            kind="levitate", params_json="{}"), metadata=md)), None, ["levitate"]),
        ("PlayAsset of an unknown asset", lambda st, md: st.PlayAsset(control_pb2.PlayAssetRequest(asset="nothing"),
                                                                      metadata=md), None, ["nothing"]),
    ]


async def _drain(call):
    async for _ in call:
        pass


def _checksums(root: Path) -> dict[str, str]:
    """What the rig stores (not the logs: the action log records each refused operator call)."""
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file() and p.suffix != ".log" and p.name != "console-actions.jsonl"}


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    r = LocalRig(["r0c0", "r0c1"], tmp_path_factory.mktemp("bad-messages"), output_size=(32, 32),
                 content_size=(32, 32), mdns=False).create()
    r.start_coordinator()
    r.wait_ready()
    yield r
    r.close()


def _check(exc: grpc.aio.AioRpcError, code, words, name):
    assert exc.code() not in (S.UNKNOWN, S.INTERNAL), f"{name}: {exc.code()} {exc.details()}"
    if code is not None:
        assert exc.code() == code, f"{name}: {exc.code()} {exc.details()}"
    for w in words:
        assert w in exc.details(), f"{name}: {w!r} not in {exc.details()!r}"


def test_bad_network_messages_are_refused_clearly(rig, corpus_table):
    before = _checksums(rig.rig_dir)

    async def go():
        async with grpc.aio.insecure_channel(f"127.0.0.1:{rig.port}",
                                             options=[("grpc.max_send_message_length", 64 << 20)]) as ch:
            node = node_pb2_grpc.NodeLinkStub(ch)
            ctl = control_pb2_grpc.RigControlStub(ch)
            login = await _login(ctl, rig.token, role="operator", slot="")
            md = ((SESSION_KEY, (await ctl.Login(login)).session),)
            results = []
            cases = [(n, lambda m=m: m(node), c, w) for n, m, c, w in _node_cases(rig.token)]
            cases += [(n, lambda m=m: m(ctl, md), c, w) for n, m, c, w in _operator_cases()]
            for name, make, code, words in cases:
                try:
                    await make()
                except grpc.aio.AioRpcError as exc:
                    results.append((name, exc, code, words))
                else:
                    pytest.fail(f"{name}: accepted")
            return results

    results = asyncio.run(go())
    for name, exc, code, words in results:
        _check(exc, code, words, name)
        corpus_table("network message", name, f"{exc.code().name}: {exc.details()}", "-")
    assert len(results) >= 28
    assert "Traceback" not in rig.log("coordinator")
    assert _checksums(rig.rig_dir) == before, "a refused message changed what the rig stores"
    audit = rig.rig_dir / "console-actions.jsonl"
    logged = [json.loads(line) for line in audit.read_text().splitlines()] if audit.exists() else []
    assert logged and all(not e["ok"] and e["who"] == "token" and e["action"].startswith("cli ") for e in logged), \
        "every refused operator call is an entry of the action log, a refusal"
