"""The asset store: real image, sequence and video files in temp folders, content addressing,
atomic adds (even when killed), removal that keeps shared blobs, verification, chunked reads,
lookups, and the `shadowless content` command through its own parser."""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import cv2
import numpy as np
import pytest

av = pytest.importorskip("av")

from coordinator import assets as assets_mod  # noqa: E402
from rigctl import content_commands, content_format  # noqa: E402
from coordinator.asset_probe import pixel_format_layout, probe_video  # noqa: E402
from coordinator.assets import STAGING_LOCK, AssetStore  # noqa: E402
from coordinator.errors import AssetError  # noqa: E402
from coordinator.errors import CoordinatorError  # noqa: E402
from coordinator.rig import init_rig  # noqa: E402
from protos.asset_manifest import Manifest  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]


# ---------------------------------------------------------------- helpers
def png(path: Path, img: np.ndarray) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), img)
    return path


def gradient(h: int = 48, w: int = 64, c: int = 3, dtype=np.uint8, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    top = np.iinfo(dtype).max
    img = rng.integers(0, top, size=(h, w, c) if c > 1 else (h, w), dtype=np.int64)
    return img.astype(dtype)


def write_video(path: Path, *, codec: str, frames: int, w: int, h: int, fps: int, pix_fmt: str,
                src_format: str = "rgb24", gop: int | None = None) -> Path:
    """Encode ``frames`` frames with PyAV; the source is (h, w, 3) uint8 RGB or (h, w) uint16 gray;
    ``gop``: a keyframe every that many frames (None: the encoder's default)."""
    with av.open(str(path), "w") as c:
        s = c.add_stream(codec, rate=fps)
        s.width, s.height, s.pix_fmt = w, h, pix_fmt
        if gop is not None:
            s.codec_context.gop_size = gop
            if codec == "libx264":      # and no keyframes of x264's own choosing (scene cuts)
                s.options = {"x264-params": f"keyint={gop}:min-keyint={gop}:scenecut=0"}
        for i in range(frames):
            if src_format == "gray16le":
                arr = np.full((h, w), i * 1000, np.uint16)
            else:
                arr = np.full((h, w, 3), (i * 8) % 256, np.uint8)
            for pkt in s.encode(av.VideoFrame.from_ndarray(arr, format=src_format)):
                c.mux(pkt)
        for pkt in s.encode():
            c.mux(pkt)
    return path


def h264_or_mpeg4() -> str:
    for codec in ("libx264", "mpeg4"):
        if codec in av.codecs_available:
            return codec
    pytest.skip("PyAV has neither libx264 nor mpeg4")


def stored_files(store: AssetStore) -> list[str]:
    """Everything under assets/ except the locks and empty folders."""
    root = store.root
    return sorted(p.relative_to(root).as_posix() for p in root.rglob("*")
                  if p.is_file() and p.name not in (".lock", STAGING_LOCK))


@pytest.fixture
def store(tmp_path) -> AssetStore:
    rig = tmp_path / "rig"
    rig.mkdir()
    return AssetStore(rig)


# ---------------------------------------------------------------- stills
def test_an_8_bit_png_round_trips_bit_exactly_and_is_named_by_its_hash(store, tmp_path):
    f = png(tmp_path / "in" / "logo.png", gradient())
    m = store.add(f)
    assert (m.kind, m.name, m.width, m.height, m.channels, m.bit_depth, m.frames, m.fps) == \
        ("still", "logo", 64, 48, 3, 8, 1, 0.0)
    data = f.read_bytes()
    (b,) = m.blobs
    assert (b.sha256, b.size, b.name) == (hashlib.sha256(data).hexdigest(), len(data), "logo.png")
    blob = store.root / "blobs" / b.sha256[:2] / b.sha256
    assert blob.read_bytes() == data
    with store.open_blob(b.sha256) as fh:
        assert fh.read() == data
    manifest_file = store.root / "manifests" / f"{m.asset_id}.json"
    assert hashlib.sha256(manifest_file.read_bytes()).hexdigest() == m.asset_id
    assert Manifest.from_bytes(manifest_file.read_bytes(), asset_id=m.asset_id) == m
    assert store.get(m.asset_id) == m and store.list() == [(m.asset_id, m)]
    assert list((store.root / "tmp").iterdir()) == []


def test_a_16_bit_png_keeps_its_depth_and_every_byte(store, tmp_path):
    img = gradient(c=1, dtype=np.uint16, seed=3)
    f = png(tmp_path / "depth.png", img)
    m = store.add(f, name="depth map")
    assert (m.name, m.channels, m.bit_depth) == ("depth map", 1, 16)
    with store.open_blob(m.blobs[0].sha256) as fh:
        data = fh.read()
    assert data == f.read_bytes()
    back = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    assert back.dtype == np.uint16 and np.array_equal(back, img)


def test_a_float32_npy_still_and_its_refusals(store, tmp_path):
    arr = np.linspace(0, 1, 40 * 30 * 3, dtype=np.float32).reshape(40, 30, 3)
    np.save(tmp_path / "lin.npy", arr)
    m = store.add(tmp_path / "lin.npy")
    assert (m.width, m.height, m.channels, m.bit_depth) == (30, 40, 3, 32)
    np.save(tmp_path / "gray.npy", arr[..., 0])
    assert store.add(tmp_path / "gray.npy").channels == 1
    np.save(tmp_path / "f64.npy", arr.astype(np.float64))
    with pytest.raises(AssetError, match=r"f64\.npy.*float32"):
        store.add(tmp_path / "f64.npy")
    bad = arr.copy()
    bad[3, 4, 1] = np.nan
    np.save(tmp_path / "nan.npy", bad)
    with pytest.raises(AssetError, match=r"nan\.npy.*NaN"):
        store.add(tmp_path / "nan.npy")
    np.save(tmp_path / "cube.npy", np.zeros((2, 3, 4, 5), np.float32))
    with pytest.raises(AssetError, match=r"cube\.npy.*shape"):
        store.add(tmp_path / "cube.npy")
    assert len(store.list()) == 2


def test_unreadable_or_unsupported_files_are_refused_naming_the_file_and_leave_nothing(store, tmp_path):
    (tmp_path / "broken.png").write_bytes(b"\x89PNG not really")
    (tmp_path / "broken.mp4").write_bytes(os.urandom(5000))
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(AssetError, match=r"broken\.png"):
        store.add(tmp_path / "broken.png")
    with pytest.raises(AssetError, match=r"broken\.mp4"):
        store.add(tmp_path / "broken.mp4")
    with pytest.raises(AssetError, match=r"notes\.txt.*unsupported"):
        store.add(tmp_path / "notes.txt")
    with pytest.raises(AssetError, match="no such file"):
        store.add(tmp_path / "missing.png")
    f = png(tmp_path / "s.png", gradient())
    with pytest.raises(AssetError, match="a still has no frame rate"):
        store.add(f, fps=24)
    assert issubclass(AssetError, CoordinatorError)
    assert store.list() == [] and stored_files(store) == []


# ---------------------------------------------------------------- sequences
def test_a_folder_is_a_sequence_of_its_images_sorted_by_name(store, tmp_path):
    seq = tmp_path / "intro"
    frames = [gradient(seed=i) for i in range(5)]
    for i in (3, 0, 4, 1, 2):
        png(seq / f"f{i:03d}.png", frames[i])
    png(seq / "f005.png", frames[0])  # a repeated frame: stored once
    (seq / "README.txt").write_text("not a frame")
    (seq / ".DS_Store").write_bytes(b"x")
    notes: list[str] = []
    m = store.add(seq, note=notes.append)
    assert (m.kind, m.name, m.frames, m.fps, m.width, m.height) == ("sequence", "intro", 6, 30.0, 64, 48)
    assert [b.name for b in m.blobs] == [f"f{i:03d}.png" for i in range(6)]
    assert [b.sha256 for b in m.blobs] == [hashlib.sha256((seq / b.name).read_bytes()).hexdigest() for b in m.blobs]
    assert m.blobs[5].sha256 == m.blobs[0].sha256
    assert len([f for f in stored_files(store) if f.startswith("blobs/")]) == 5
    assert any("assuming 30 fps" in n for n in notes) and any("README.txt" in n for n in notes)
    m24 = store.add(seq, fps=24, name="intro24", note=notes.append)
    assert m24.fps == 24.0 and m24.duration_s == pytest.approx(6 / 24) and m24.asset_id != m.asset_id


def test_a_sequence_with_a_frame_that_differs_is_refused_naming_it(store, tmp_path):
    seq = tmp_path / "bad"
    for i in range(4):
        png(seq / f"{i:02d}.png", gradient(seed=i))
    png(seq / "02.png", gradient(h=32, w=32))
    with pytest.raises(AssetError, match=r"frame 2 '02\.png' is 32x32.*first frame '00\.png' is 64x48"):
        store.add(seq)
    png(seq / "02.png", gradient(dtype=np.uint16))
    with pytest.raises(AssetError, match=r"'02\.png' is 64x48, 3 ch, 16-bit"):
        store.add(seq)
    assert stored_files(store) == []


def test_unpadded_frame_numbers_are_refused_rather_than_played_out_of_order(store, tmp_path):
    seq = tmp_path / "unpadded"
    for i in (1, 2, 10):
        png(seq / f"frame{i}.png", gradient(seed=i))
    with pytest.raises(AssetError, match="zero-pad"):
        store.add(seq)
    with pytest.raises(AssetError, match="no image files"):
        store.add((tmp_path / "empty").mkdir() or tmp_path / "empty")


# ---------------------------------------------------------------- videos
def test_a_video_is_probed_for_frames_rate_size_and_codec(store, tmp_path):
    codec = h264_or_mpeg4()
    f = write_video(tmp_path / "clip.mp4", codec=codec, frames=30, w=64, h=48, fps=30, pix_fmt="yuv420p")
    m = store.add(f)
    assert (m.kind, m.name, m.frames, m.fps, m.width, m.height, m.channels, m.bit_depth) == \
        ("video", "clip", 30, 30.0, 64, 48, 3, 8)
    assert m.extra["codec"] == ("h264" if codec == "libx264" else "mpeg4")
    assert m.extra["pix_fmt"] == "yuv420p" and m.extra["rate"] == "30/1"
    with store.open_blob(m.blobs[0].sha256) as fh:
        assert fh.read() == f.read_bytes()
    with pytest.raises(AssetError, match="keeps its own frame rate"):
        store.add(f, fps=25)
    assert store.add(f, fps=30.0) == m


def test_a_video_with_keyframes_far_apart_is_added_with_a_note(store, tmp_path):
    """250 frames between keyframes (x264's own default): 3 s of a 25 fps clip has one keyframe,
    so a node joining mid-show would decode up to 3 s of video; a 1 s GOP is worth no note."""
    if "libx264" not in av.codecs_available:
        pytest.skip("no libx264")
    notes: list[str] = []
    store.add(write_video(tmp_path / "long.mp4", codec="libx264", frames=75, w=64, h=48, fps=25, pix_fmt="yuv420p",
                          gop=250), note=notes.append)
    assert len(notes) == 1 and "keyframes up to 3.0 s apart" in notes[0] and "ffmpeg -g 25" in notes[0]
    notes.clear()
    store.add(write_video(tmp_path / "short.mp4", codec="libx264", frames=75, w=64, h=48, fps=25, pix_fmt="yuv420p",
                          gop=25), note=notes.append)
    assert notes == []


def test_a_container_without_a_frame_count_is_counted_by_demuxing(tmp_path):
    if "ffv1" not in av.codecs_available:
        pytest.skip("no ffv1 encoder")
    f = write_video(tmp_path / "depth.mkv", codec="ffv1", frames=12, w=32, h=24, fps=25, pix_fmt="gray16le",
                    src_format="gray16le")
    with av.open(str(f)) as c:
        assert c.streams.video[0].frames == 0, "Matroska carries no frame count"
    p = probe_video(f)
    assert (p.frames, p.fps, p.width, p.height, p.channels, p.bit_depth) == (12, 25.0, 32, 24, 1, 16)
    assert p.extra["codec"] == "ffv1" and p.extra["container"] == "matroska"


@pytest.mark.parametrize("pix_fmt, expected", [
    ("yuv420p", (3, 8)), ("yuv420p10le", (3, 10)), ("yuv444p12le", (3, 12)), ("gray16le", (1, 16)),
    ("gray", (1, 8)), ("rgba", (4, 8)), ("yuva420p", (4, 8)), ("nv12", (3, 8)), ("p010le", (3, 10)),
    ("pal8", (3, 8)), ("rgb48le", (3, 16)), ("gbrpf32le", (3, 32)),
])
def test_pixel_formats_map_to_channels_and_bit_depth(pix_fmt, expected):
    assert pixel_format_layout(pix_fmt) == expected


# ---------------------------------------------------------------- identity, removal, verification
def test_adding_the_same_content_twice_gives_the_same_id_and_stores_nothing_new(store, tmp_path):
    f = png(tmp_path / "a.png", gradient())
    m1 = store.add(f)
    before = {p: (store.root / p).stat().st_ino for p in stored_files(store)}
    copy = tmp_path / "elsewhere" / "a.png"
    copy.parent.mkdir()
    copy.write_bytes(f.read_bytes())
    m2 = store.add(copy)
    assert m2.asset_id == m1.asset_id
    assert {p: (store.root / p).stat().st_ino for p in stored_files(store)} == before


def test_remove_keeps_the_blobs_another_asset_uses(store, tmp_path):
    f = png(tmp_path / "a.png", gradient())
    a = store.add(f, name="a")
    b = store.add(f, name="b")  # another asset, the same blob
    seq = tmp_path / "seq"
    png(seq / "0.png", gradient(seed=9))
    (seq / "1.png").write_bytes(f.read_bytes())
    s = store.add(seq, fps=10)
    shared, own = b.blobs[0].sha256, s.blobs[0].sha256
    assert a.blobs[0].sha256 == shared == s.blobs[1].sha256
    store.remove(a.asset_id)
    assert [aid for aid, _ in store.list()] == sorted([b.asset_id, s.asset_id], key=lambda i: store.get(i).name)
    assert store.blob_path(shared).exists()
    store.remove(s.asset_id)
    assert store.blob_path(shared).exists() and not store.blob_path(own).exists()
    store.remove(b.asset_id)
    assert not store.blob_path(shared).exists() and store.list() == []
    with pytest.raises(AssetError, match="no asset"):
        store.remove(b.asset_id)
    with pytest.raises(AssetError, match="not an asset id"):
        store.remove(b.asset_id[:8])


def test_verify_finds_missing_resized_and_corrupt_blobs(store, tmp_path):
    seq = tmp_path / "seq"
    for i in range(3):
        png(seq / f"{i}.png", gradient(seed=i))
    m = store.add(seq, fps=5)
    assert store.verify(m.asset_id) == []
    p0, p1, p2 = (store.blob_path(b.sha256) for b in m.blobs)
    os.chmod(p0, 0o644)
    data = bytearray(p0.read_bytes())
    data[100] ^= 0x01
    p0.write_bytes(bytes(data))
    os.chmod(p1, 0o644)
    p1.write_bytes(p1.read_bytes()[:-1])
    p2.unlink()
    problems = store.verify(m.asset_id[:10])
    assert len(problems) == 3
    assert "blob 0 '0.png'" in problems[0] and "corrupt" in problems[0]
    assert "blob 1 '1.png'" in problems[1] and "the manifest says" in problems[1]
    assert "blob 2 '2.png'" in problems[2] and "missing" in problems[2]


def test_read_blob_at_offsets_equals_slices_of_the_file(store, tmp_path):
    arr = np.random.default_rng(1).random((700, 800, 3), dtype=np.float32)  # ~6.7 MB: several chunks
    np.save(tmp_path / "big.npy", arr)
    data = (tmp_path / "big.npy").read_bytes()
    seen: list[tuple[int, int]] = []
    m = store.add(tmp_path / "big.npy", progress=lambda d, t: seen.append((d, t)))
    assert len(seen) > 1 and seen[-1] == (len(data), len(data)) and all(a[0] < b[0] for a, b in zip(seen, seen[1:]))
    sha = m.blobs[0].sha256
    chunk = assets_mod.CHUNK_BYTES
    for off, n in [(0, 10), (1, 1000), (chunk - 7, 20), (3 * chunk + 5, chunk), (len(data) - 5, 100), (0, len(data))]:
        assert store.read_blob(sha, off, n) == data[off:off + n]
    assert store.read_blob(sha, len(data) + 10, 5) == b"" and store.read_blob(sha, 5, 0) == b""
    with pytest.raises(ValueError):
        store.read_blob(sha, -1, 5)
    with pytest.raises(ValueError):
        store.read_blob(sha, 0, assets_mod.MAX_READ_BYTES + 1)
    with pytest.raises(AssetError, match="no blob"):
        store.read_blob("0" * 64, 0, 5)
    with pytest.raises(AssetError, match="not a blob name"):
        store.open_blob("../../rig.toml")


def test_lookup_by_id_prefix_and_name_with_clear_errors(store, tmp_path, monkeypatch):
    ids = {}
    for i in range(17):  # 17 ids over 16 hex digits: two share their first digit
        np.save(tmp_path / f"s{i:02d}.npy", np.full((4, 4), i / 16, np.float32))  # float content lies in 0..1
        ids[store.add(tmp_path / f"s{i:02d}.npy").asset_id] = f"s{i:02d}"
    aid = next(iter(ids))
    assert store.resolve(aid) == aid and store.resolve(aid[:8]) == aid and store.resolve(aid[:8].upper()) == aid
    assert store.get(ids[aid]).asset_id == aid
    with pytest.raises(AssetError, match="at least 4 hex digits"):
        store.resolve(aid[:2])
    with pytest.raises(AssetError, match="no asset matches 'nothing'"):
        store.get("nothing")
    monkeypatch.setattr(assets_mod, "MIN_PREFIX", 1)
    firsts = [a[0] for a in ids]
    digit = next(d for d in firsts if firsts.count(d) > 1)
    with pytest.raises(AssetError, match=f"'{digit}' is ambiguous: it matches {firsts.count(digit)} assets") as err:
        store.get(digit)
    assert all(a[:12] in str(err.value) for a in ids if a[0] == digit)
    store.add(tmp_path / "s00.npy", name="s01")  # a second asset named s01
    with pytest.raises(AssetError, match="'s01' is ambiguous"):
        store.get("s01")


def test_a_writer_killed_mid_add_leaves_no_manifest_and_adding_again_succeeds(store, tmp_path):
    arr = np.random.default_rng(2).random((600, 800, 3), dtype=np.float32)  # ~5.8 MB: several chunks
    np.save(tmp_path / "big.npy", arr)
    script = textwrap.dedent(f"""
        import os, signal, sys
        from coordinator.assets import AssetStore

        def progress(done, total):
            if done >= 2 * (1 << 20):
                sys.stdout.write("copying\\n"); sys.stdout.flush()
                os.kill(os.getpid(), signal.SIGKILL)

        AssetStore({str(store.rig_dir)!r}).add({str(tmp_path / "big.npy")!r}, progress=progress)
    """)
    p = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert p.returncode == -signal.SIGKILL and "copying" in p.stdout, p.stderr
    assert store.list() == []
    left = stored_files(store)
    assert left and all(f.startswith("tmp/") for f in left), left  # a half blob temp file, nothing else
    m = store.add(tmp_path / "big.npy")
    assert store.list() == [(m.asset_id, m)] and store.verify(m.asset_id) == []
    for f in (store.root / "tmp").iterdir():  # a later add sweeps stale leftovers
        os.utime(f, (1, 1))
    store.add(png(tmp_path / "x.png", gradient()))
    assert list((store.root / "tmp").iterdir()) == []


# ---------------------------------------------------------------- the command
def cli(*argv: str) -> int:
    p = argparse.ArgumentParser(prog="shadowless content")
    content_commands.configure(p)
    return content_commands.run(p.parse_args(list(argv)))


def test_the_content_command_end_to_end(tmp_path, capsys, monkeypatch):
    rig = init_rig(tmp_path / "rig", name="t", slots=["r0c0"])
    still = png(tmp_path / "logo.png", gradient())
    seq = tmp_path / "intro"
    for i in range(3):
        png(seq / f"{i:03d}.png", gradient(seed=i))

    monkeypatch.setattr(content_format, "PROGRESS_MIN_BYTES", 0)
    assert cli("--rig-dir", str(rig), "add", str(still)) == 0
    out, err = capsys.readouterr()
    still_id = out.strip()
    assert len(still_id) == 64 and "hashed" in err and "added" in err and "still 'logo'" in err
    assert cli("add", str(still), "--rig-dir", str(rig)) == 0  # --rig-dir after the action too
    out, err = capsys.readouterr()
    assert out.strip() == still_id and "already stored" in err

    assert cli("add", str(seq), "--fps", "24", "--name", "opening", "--rig-dir", str(rig)) == 0
    seq_id = capsys.readouterr().out.strip()
    assert cli("add", str(seq), "--rig-dir", str(rig)) == 0
    assert "note: sequence 'intro': no frame rate given, assuming 30 fps" in capsys.readouterr().err

    assert cli("list", "--rig-dir", str(rig)) == 0
    table = capsys.readouterr().out.splitlines()
    assert table[0].split() == ["id", "kind", "name", "frames", "size", "depth", "fps", "duration", "bytes"]
    row = next(line for line in table if line.startswith(seq_id[:12]))
    assert row.split()[:8] == [seq_id[:12], "sequence", "opening", "3", "64x48", "3x8", "24", "0.12"]
    assert cli("list", "--json", "--rig-dir", str(rig)) == 0
    doc = json.loads(capsys.readouterr().out)
    assert {d["id"] for d in doc} >= {still_id, seq_id} and len(doc) == 3
    assert next(d for d in doc if d["id"] == still_id)["bytes"] == still.stat().st_size

    assert cli("verify", seq_id[:6], "--rig-dir", str(rig)) == 0
    assert capsys.readouterr().out.startswith(f"ok: {seq_id[:12]}")
    blob = AssetStore(rig).blob_path(AssetStore(rig).get(still_id).blobs[0].sha256)
    os.chmod(blob, 0o644)
    blob.write_bytes(b"tampered")
    assert cli("verify", "logo", "--rig-dir", str(rig)) == 1
    assert "blob 0 'logo.png'" in capsys.readouterr().out

    assert cli("rm", "opening", "--rig-dir", str(rig)) == 0
    assert capsys.readouterr().out.startswith(f"removed {seq_id[:12]}")
    assert cli("rm", "opening", "--rig-dir", str(rig)) == 2
    assert "no asset matches 'opening'" in capsys.readouterr().err
    assert cli("list", "--rig-dir", str(tmp_path)) == 2
    assert "not a rig directory" in capsys.readouterr().err
    assert cli("add", str(tmp_path / "nope.png"), "--rig-dir", str(rig)) == 2
    assert "nope.png" in capsys.readouterr().err


def test_the_help_says_where_it_works_and_how_an_upload_resumes():
    p = argparse.ArgumentParser(prog="shadowless content")
    content_commands.configure(p)
    text = p.format_help()
    assert "--rig-dir" in text and "--coordinator HOST:PORT" in text and "resumes where it stopped" in text
    add_help = p._subparsers._group_actions[0].choices["add"].format_help()
    assert "--coordinator" in add_help and "--token-file" in add_help
