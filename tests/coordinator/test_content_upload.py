"""Content uploaded from an operator's machine: `shadowless content add|list|rm --coordinator`
against a real coordinator process, its ContentStore service over gRPC, the upload resumed
after a cut, damaged bytes refused, and what the store holds compared with a local add."""
from __future__ import annotations

import asyncio
import hashlib
import json
import shutil
import subprocess
import sys

import av
import cv2
import grpc
import numpy as np
import pytest

from cli_inprocess import cli_capture, shadowless_here  # noqa: F401 - cli_capture: the module's autouse fixture
from coordinator.assets import AssetStore
from rigctl.client import CallRefused
from rigctl.content_format import human_bytes
from protos import control_pb2, control_pb2_grpc
from shadowless.local import LocalRig


def run(coro):
    return asyncio.run(coro)


def write_clip(path, frames: int = 20, w: int = 64, h: int = 48) -> None:
    with av.open(str(path), "w") as c:
        s = c.add_stream("libx264", rate=25)
        s.width, s.height, s.pix_fmt = w, h, "yuv420p"
        rng = np.random.default_rng(3)
        for i in range(frames):
            arr = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)   # noise: a file of some size
            for pkt in s.encode(av.VideoFrame.from_ndarray(arr, format="rgb24")):
                c.mux(pkt)
        for pkt in s.encode():
            c.mux(pkt)


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    work = tmp_path_factory.mktemp("upload")
    r = LocalRig(["r0c0"], work, output_size=(64, 48), content_size=(64, 48), mdns=False)
    r.create()
    try:
        r.start_coordinator()

        async def answering():
            async with await r.client(timeout=60):
                pass

        run(answering())
        yield r
    finally:
        r.close()


def cli(rig, *args: str, process: bool = False) -> subprocess.CompletedProcess:
    """`shadowless content ARGS...` against ``rig``: in this interpreter, or with ``process`` as a real process."""
    argv = ["content", *args, "--coordinator", rig.coordinator_target, "--token-file", str(rig.rig_dir / "token")]
    if not process:
        return shadowless_here(argv)
    return subprocess.run([sys.executable, "-m", "shadowless", *argv], capture_output=True, text=True, timeout=120)


def test_a_video_added_from_another_machine_is_the_asset_a_local_add_makes(rig, tmp_path):
    clip = tmp_path / "clip.mp4"
    write_clip(clip)
    r = cli(rig, "add", str(clip), process=True)
    assert r.returncode == 0, r.stderr
    aid = r.stdout.strip()
    assert "added" in r.stderr and f"sent {human_bytes(clip.stat().st_size)}" in r.stderr
    # the same file added locally to another rig's store gives the same content-addressed asset
    other = tmp_path / "other"
    other.mkdir()
    assert AssetStore(other).add(clip).asset_id == aid
    listed = json.loads(cli(rig, "list", "--json").stdout)
    assert [a["id"] for a in listed if a["name"] == "clip"] == [aid]
    again = cli(rig, "add", str(clip))
    assert again.returncode == 0 and again.stdout.strip() == aid and "already stored" in again.stderr
    gone = cli(rig, "rm", aid[:8])
    assert gone.returncode == 0 and "removed" in gone.stdout
    assert aid not in cli(rig, "list").stdout


def test_an_interrupted_upload_resumes_where_it_stopped(rig, tmp_path):
    clip = tmp_path / "long.mp4"
    write_clip(clip, frames=60)
    data = clip.read_bytes()
    half = len(data) // 2

    async def send_half():
        async with await rig.client() as c:
            uid, have = await c.begin_upload([(clip.name, len(data), hashlib.sha256(data).hexdigest())])
            assert have == [0]

            async def chunks():
                yield data[:half]

            assert await c.upload_file(uid, 0, 0, chunks()) == [half]
            with pytest.raises(CallRefused, match="holds"):   # not from where it stopped
                await c.upload_file(uid, 0, 0, chunks())
            return uid

    uid = run(send_half())
    r = cli(rig, "add", str(clip), "--name", "long")
    assert r.returncode == 0, r.stderr
    assert f"resuming upload {uid[:12]}" in r.stderr
    assert f"sent {human_bytes(len(data) - half)}" in r.stderr
    m = AssetStore(rig.rig_dir).get(r.stdout.strip())
    assert m.name == "long" and m.kind == "video" and m.frames == 60
    assert not (rig.rig_dir / "assets" / "uploads" / uid).exists()      # finished uploads are removed


def test_a_folder_uploads_as_an_image_sequence_at_its_rate(rig, tmp_path):
    folder = tmp_path / "intro"
    folder.mkdir()
    for i in range(4):
        img = np.full((48, 64, 3), i * 60, np.uint16) * 257
        assert cv2.imwrite(str(folder / f"f{i:03d}.png"), img)
    (folder / "notes.txt").write_text("not an image")
    r = cli(rig, "add", str(folder), "--fps", "12")
    assert r.returncode == 0, r.stderr
    m = AssetStore(rig.rig_dir).get(r.stdout.strip())
    assert (m.kind, m.name, m.frames, m.bit_depth, m.fps) == ("sequence", "intro", 4, 16, 12.0)


def test_compensate_uploads_a_video_file_from_another_machine(rig, tmp_path, capfd):
    import argparse

    from rigctl import compensation_cli as compensate_cli

    clip = tmp_path / "scene.mp4"
    write_clip(clip, frames=10)
    p = argparse.ArgumentParser()
    compensate_cli.configure(p)
    args = p.parse_args([str(clip), "--coordinator", rig.coordinator_target, "--token-file", str(rig.rig_dir / "token"),
                         "--max-frames", "2"])
    kind, params = compensate_cli.compensate_request(args)
    assert kind == "compensate_video" and params["max_frames"] == 2
    m = AssetStore(rig.rig_dir).get(params["asset"])
    assert (m.kind, m.name, m.frames) == ("video", "scene", 10)
    assert "uploaded to the store" in capfd.readouterr().err


def test_damaged_bytes_are_refused_and_dropped_and_bad_names_and_strangers_too(rig, tmp_path):
    good = b"\x89PNG not really" * 100

    async def go():
        async with await rig.client() as c:
            uid, _ = await c.begin_upload([("x.png", len(good), hashlib.sha256(good).hexdigest())])

            async def flipped():
                yield bytes([good[0] ^ 1]) + good[1:]

            assert await c.upload_file(uid, 0, 0, flipped()) == [len(good)]
            with pytest.raises(CallRefused, match="hash to .* not the announced") as e:
                await c.finish_upload(uid)
            assert e.value.code == "FAILED_PRECONDITION"
            assert (await c.begin_upload([("x.png", len(good), hashlib.sha256(good).hexdigest())]))[1] == [0]
            for name in ("../x.png", "a/b.png", ".hidden.png"):
                with pytest.raises(CallRefused, match="plain file name") as e:
                    await c.begin_upload([(name, 1, "0" * 64)])
                assert e.value.code == "INVALID_ARGUMENT"
            with pytest.raises(CallRefused, match="not complete"):
                uid2, _ = await c.begin_upload([("y.png", 10, "1" * 64)])
                await c.finish_upload(uid2)
        async with grpc.aio.insecure_channel(rig.coordinator_target) as ch:   # no session: refused
            with pytest.raises(grpc.aio.AioRpcError) as e:
                await control_pb2_grpc.ContentStoreStub(ch).ListAssets(control_pb2.StatusRequest(), timeout=10)
            assert e.value.code() == grpc.StatusCode.UNAUTHENTICATED

    run(go())
    missing = cli(rig, "add", str(tmp_path / "nope.mp4"))
    assert missing.returncode == 2 and "no such file or folder" in missing.stderr
    assert cli(rig, "verify", "x").returncode == 2
    shutil.rmtree(rig.rig_dir / "assets" / "uploads", ignore_errors=True)


def test_a_corrupt_video_is_refused_naming_the_operators_file_and_nothing_of_it_stays(rig, tmp_path, corpus_table):
    uploads = rig.rig_dir / "assets" / "uploads"
    cases = {   # what the operator adds (the store's probes word the reason; the name is what is checked here)
        "holiday.mp4": np.random.default_rng(5).integers(0, 256, 300_000, dtype=np.uint8).tobytes(),
        "poster.png": b"\x89PNG\r\n\x1a\n" + b"\x00" * 5000,
        "frames.npy": b"\x93NUMPY not really an array",
    }
    for name, data in cases.items():
        (tmp_path / name).write_bytes(data)
        r = cli(rig, "add", str(tmp_path / name))
        lines = r.stderr.strip().splitlines()
        assert r.returncode == 2 and len(lines) == 1, r.stderr
        assert lines[0].startswith(f"shadowless content: the coordinator refused: {name}: "), lines[0]
        assert "uploads" not in lines[0] and "/files/" not in lines[0] and str(rig.rig_dir) not in lines[0], lines[0]
        assert not any(uploads.iterdir()), f"{name}: the refused upload stayed: {sorted(uploads.iterdir())}"
        corpus_table("content add --coordinator", name, lines[0], r.returncode)
    assert "Traceback" not in rig.log("coordinator")


def test_bad_upload_calls_are_refused_in_one_line_naming_what_is_wrong(rig, corpus_table):
    data = b"0123456789" * 30
    sha = hashlib.sha256(data).hexdigest()

    async def chunk(payload: bytes):
        yield payload

    async def go():
        async with await rig.client() as c:
            uid, _ = await c.begin_upload([("bad.npy", len(data), sha)])
            spec = rig.rig_dir / "assets" / "uploads" / uid / "spec.json"
            cases = [   # (what, call, words the refusal holds, its status)
                ("finish an upload never begun", lambda: c.finish_upload("c" * 64), "begin it again",
                 "FAILED_PRECONDITION"),
                ("an upload id that is not one", lambda: c.finish_upload("../../etc"), "not an upload id",
                 "INVALID_ARGUMENT"),
                ("a file index past the upload's files", lambda: c.upload_file(uid, 3, 0, chunk(b"x")),
                 "no file 3", "INVALID_ARGUMENT"),
                ("bytes from the wrong offset", lambda: c.upload_file(uid, 0, 100, chunk(b"x")),
                 "resume from there", "FAILED_PRECONDITION"),
                ("bytes past the announced size", lambda: c.upload_file(uid, 0, 0, chunk(data + b"!")),
                 "more than its announced 300 bytes", "INVALID_ARGUMENT"),
                ("an announcement of no file", lambda: c.begin_upload([]), "at least one file",
                 "INVALID_ARGUMENT"),
                ("a file announced twice", lambda: c.begin_upload([("a.npy", 1, sha), ("a.npy", 1, sha)]),
                 "appears twice", "INVALID_ARGUMENT"),
                ("finish before every byte came", lambda: c.finish_upload(uid), "not complete",
                 "FAILED_PRECONDITION"),
            ]
            out = []
            for what, call, words, code in cases:
                with pytest.raises(CallRefused) as e:
                    await call()
                out.append((what, e.value, words, code))
            shutil.rmtree(spec.parent)
            return out

    for what, exc, words, code in run(go()):
        msg = exc.details
        assert exc.code == code, f"{what}: {exc.code} {msg}"
        assert words in msg and "\n" not in msg and str(rig.rig_dir) not in msg, f"{what}: {msg!r}"
        corpus_table("upload call", what, f"{exc.code}: {msg}", "-")
    assert "Traceback" not in rig.log("coordinator")
