"""The coordinator's one image decoder: a file whose header declares more than the limit is
refused from its header (nothing decoded, memory bounded) for nine formats, through the console's
upload and the camera and job readers alike; small valid files decode to the pixels they were
written from (or, for the lossy formats, to OpenCV's own decode); a format the header reader does
not know is refused even where OpenCV would decode it."""
from __future__ import annotations

import asyncio
import contextlib
import io
import json
import struct
import subprocess
import sys
from pathlib import Path

import aiohttp
import cv2
import numpy as np
import pytest
from numpy.lib import format as npy_format

import bench.image_headers as H
from coordinator.camera import CameraError, read_png
from coordinator.compensation.image_param import decode_image_bytes
from imaging.compensation.errors import CompensationError
from coordinator.console import auth
from coordinator.image_decode import FORMATS as DECODER_FORMATS
from coordinator.image_decode import MAX_PIXELS, ImageRefused, decode_image, declared_size, read_image_file
from coordinator.rig import Rig, grid_slots, init_rig
from coordinator.schema import MAX_SIDE
from protos.image_limits import MAX_IMAGE_SIDE
from inprocess_coordinator import inprocess_coordinator


TOKEN = b"t" * 32
LOSSLESS = ("PNG", "TIFF", "PPM", "BMP", "EXR", "PFM", "WebP")   # cv2's WebP default (quality 100) is lossless


def test_the_limit_is_the_rigs():
    assert MAX_PIXELS == 64 * 2**20 and MAX_IMAGE_SIDE == MAX_SIDE


@pytest.mark.parametrize("fmt", H.FORMATS)
def test_a_header_declaring_too_many_pixels_is_refused_naming_the_file_and_size(fmt):
    data = H.huge(fmt)
    w, h = (10000, 10000)
    assert len(data) < 10_000, len(data)       # a small file ...
    assert declared_size(data)[1:] == (w, h)   # ... declaring 100 megapixels
    with pytest.raises(ImageRefused) as exc:
        decode_image(data, f"bomb{H.SUFFIX[fmt]}")
    msg = str(exc.value)
    assert "\n" not in msg
    assert msg.startswith(f"bomb{H.SUFFIX[fmt]}: its ") and f"header declares {w}x{h} pixels" in msg, msg
    assert "nothing was decoded" in msg and "at most 67 megapixels" in msg, msg


def test_a_side_longer_than_the_rigs_is_refused_even_under_the_pixel_count():
    with pytest.raises(ImageRefused, match=r"declares 20000x100 pixels"):
        decode_image(H.huge("PNG", 20000, 100), "strip.png")
    assert decode_image(H.valid("PNG"), "ok.png").shape == (24, 32, 3)


def test_refusing_every_huge_header_keeps_memory_bounded(tmp_path):
    """In a fresh process: the peak RSS grows by less than one refused image would take (10000 x
    10000 x 3 bytes is 286 MiB; the float formats 1.1 GiB) while all nine are refused, and a whole
    6.4 MB run-length-encoded HDR (which OpenCV decodes into 1.1 GiB) with them."""
    for fmt in H.FORMATS:
        (tmp_path / f"bomb{H.SUFFIX[fmt]}").write_bytes(H.huge(fmt))
    (tmp_path / "bomb.whole.hdr").write_bytes(H.hdr_whole())   # 6.4 MB that OpenCV would decode whole
    script = f"""
import resource, json, sys
from pathlib import Path
import cv2, numpy, PIL.Image, av
from coordinator.image_decode import ImageRefused, read_image_file
before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
refused = []
for p in sorted(Path({str(tmp_path)!r}).glob("bomb.*")):
    try:
        read_image_file(p)
    except ImageRefused as exc:
        refused.append(str(exc))
after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(json.dumps({{"grew_kib": after - before, "refused": refused}}))
"""
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert len(out["refused"]) == 10 and all("declares 10000x10000 pixels" in m for m in out["refused"]), out
    assert out["grew_kib"] < 64 * 1024, f"peak RSS grew {out['grew_kib'] / 1024:.0f} MiB while refusing"


def _cv2_rgb(data: bytes) -> np.ndarray:
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if img.ndim == 3 and img.shape[2] == 4:
        return cv2.cvtColor(img, cv2.COLOR_BGRA2RGBA)
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB) if img.ndim == 3 else img


@pytest.mark.parametrize("fmt", H.FORMATS)
def test_a_small_valid_file_decodes_to_its_pixels(fmt):
    data = H.valid(fmt)
    img = decode_image(data, f"ok{H.SUFFIX[fmt]}")
    assert img.shape == (24, 32, 3)
    if fmt in LOSSLESS:      # the pixels it was written from: no decoder is the reference
        np.testing.assert_array_equal(img, H.source(fmt))
    if fmt != "EXR":         # OpenCV's direct decode (this OpenCV has no OpenEXR)
        np.testing.assert_array_equal(img, _cv2_rgb(data))
    if fmt in ("PNG", "JPEG", "TIFF", "PPM", "BMP"):   # and Pillow's, a second library
        from PIL import Image

        ref = np.asarray(Image.open(io.BytesIO(data)).convert("RGB"))
        tol = 2 if fmt == "JPEG" else 0               # two JPEG decoders' IDCTs may differ by a level
        assert np.abs(img.astype(int) - ref).max() <= tol


@pytest.mark.parametrize("dtype, channels", [(np.float32, 3), (np.float32, 1), (np.uint16, 4), (np.uint8, 1)])
def test_tiff_layouts_pillow_cannot_hold_are_read_too(dtype, channels):
    """The TIFF header is read here, not by Pillow, which refuses 3-channel float (OpenCV reads it)."""
    img = (np.random.default_rng(5).random((20, 28, channels)) * (1 if dtype == np.float32 else 200)).astype(dtype)
    ok, buf = cv2.imencode(".tif", img)
    assert ok
    assert declared_size(buf.tobytes()) == ("TIFF", 28, 20)
    np.testing.assert_array_equal(decode_image(buf.tobytes(), "x.tif"), _cv2_rgb(buf.tobytes()))


def test_a_bigtiff_header_is_read():
    tifffile = pytest.importorskip("tifffile")
    out = io.BytesIO()
    tifffile.imwrite(out, np.zeros((20, 28, 3), np.uint8), bigtiff=True)
    assert out.getvalue()[:4] == b"II+\0"
    assert declared_size(out.getvalue()) == ("TIFF", 28, 20)


def test_an_exr_is_judged_by_its_display_window_too():
    """FFmpeg's EXR decoder allocates the display window, whatever the data window stores."""
    data = H.valid("EXR")
    i = data.index(b"displayWindow\0box2i\0") + len(b"displayWindow\0box2i\0") + 4
    with pytest.raises(ImageRefused, match=r"its OpenEXR header declares 12000x9000 pixels"):
        decode_image(data[:i] + struct.pack("<4i", 0, 0, 11999, 8999) + data[i + 16:], "wide.exr")
    with pytest.raises(ImageRefused, match=r"no displayWindow in its header"):
        decode_image(data.replace(b"displayWindow", b"displayWindoX"), "odd.exr")


def test_declared_sizes_of_other_formats_opencv_reads():
    u8 = np.random.default_rng(3).integers(0, 256, (64, 48, 3), np.uint8)
    for ext, fmt in ((".gif", "GIF"), (".ras", "Sun raster"), (".jp2", "JPEG 2000"), (".pgm", "PPM")):
        ok, buf = cv2.imencode(ext, u8[:, :, 0] if ext == ".pgm" else u8)
        assert ok, ext
        assert declared_size(buf.tobytes()) == (fmt, 48, 64), ext
        assert decode_image(buf.tobytes(), "x" + ext).shape[:2] == (64, 48)


@pytest.mark.parametrize("what, data", [
    ("PAM (OpenCV decodes it, the header reader does not know it)",
     cv2.imencode(".pam", np.zeros((8, 8, 3), np.uint8))[1].tobytes()),
    ("text", b"not an image at all"),
    ("a TGA (Pillow reads it, OpenCV does not)", b"\0\0\x02" + b"\0" * 9 + b"\x08\0\x08\0\x18\0" + b"\0" * 192),
])
def test_a_format_the_header_reader_does_not_know_is_refused_not_decoded(what, data):
    with pytest.raises(ImageRefused, match=r"^x\.bin is not an image the coordinator reads: give PNG, JPEG"):
        decode_image(data, "x.bin")


def test_truncated_headers_and_empty_files_are_one_line_refusals(tmp_path):
    for fmt in H.FORMATS:
        data = H.valid(fmt)[:12]
        with pytest.raises(ImageRefused) as exc:
            decode_image(data, f"cut{H.SUFFIX[fmt]}")
        assert "\n" not in str(exc.value) and str(exc.value).startswith(f"cut{H.SUFFIX[fmt]}"), str(exc.value)
    with pytest.raises(ImageRefused, match=r"empty\.png is empty"):
        decode_image(b"", "empty.png")
    with pytest.raises(ImageRefused, match=r"no such file"):
        read_image_file(tmp_path / "missing.png")
    assert "OpenEXR" in DECODER_FORMATS and "Radiance HDR" in DECODER_FORMATS


def test_the_camera_and_job_readers_go_through_the_decoder(tmp_path):
    """A file camera's PNG and a job's image (an image file, or a .npy whose header declares more
    than its bytes hold) are refused in one line before anything is allocated."""
    (tmp_path / "000001.png").write_bytes(H.huge("PNG"))
    with pytest.raises(CameraError, match=r"000001\.png: its PNG header declares 10000x10000 pixels"):
        read_png(tmp_path / "000001.png", source="camera folder:x")
    with pytest.raises(CompensationError, match=r"target\.hdr: its Radiance HDR header declares 10000x10000"):
        decode_image_bytes(H.huge("HDR"), "target.hdr")
    img, _ = decode_image_bytes(H.valid("PNG"), "target.png")
    np.testing.assert_array_equal(img, H.source("PNG"))
    vast = io.BytesIO()
    npy_format.write_array_header_1_0(vast, {"descr": "<f4", "fortran_order": False, "shape": (100000, 100000, 3)})
    with pytest.raises(CompensationError, match=r"target\.npy: not a numpy array file \(its header declares an array "
                                                 r"of shape \(100000, 100000, 3\) float32"):
        decode_image_bytes(vast.getvalue() + bytes(64), "target.npy")


# ---------------------------------------------------------------- the console's upload
@contextlib.asynccontextmanager
async def _console(tmp_path: Path):
    rig = Rig(init_rig(tmp_path / "rig", name="web", slots=grid_slots(1, 1), width=32, height=24,
                       content_width=32, content_height=24))
    async with inprocess_coordinator(rig, TOKEN, console="127.0.0.1:0") as app:
        yield app.coordinator, f"http://127.0.0.1:{app.console_port}"


def test_the_console_refuses_each_huge_upload_from_its_header_and_shows_a_valid_one(tmp_path):
    async def go():
        async with _console(tmp_path) as (coord, base), \
                aiohttp.ClientSession(cookie_jar=aiohttp.DummyCookieJar()) as s:
            r = await s.post(base + "/login", json={"token": TOKEN.decode()}, headers={"Origin": base})
            assert r.status == 200, await r.text()
            body = await r.json()
            headers = {"Cookie": f"{auth.COOKIE}={r.cookies[auth.COOKIE].value}", "Origin": base,
                       auth.CSRF_HEADER: body["csrf"]}

            async def upload(data: bytes, name: str) -> tuple[int, dict]:
                f = aiohttp.FormData()
                f.add_field("image", data, filename=name, content_type="application/octet-stream")
                f.add_field("fit", "contain")
                r = await s.post(base + "/api/show", data=f, headers=headers)
                return r.status, await r.json()

            for fmt in H.FORMATS:
                name = f"bomb{H.SUFFIX[fmt]}"
                status, doc = await upload(H.huge(fmt), name)
                assert status == 400, (fmt, doc)
                assert doc["error"].startswith(f"{name}: its ") and "declares 10000x10000 pixels" in doc["error"], doc
            status, doc = await upload(H.valid("EXR"), "hot.exr")       # 0..4: refused, not shown clipped
            assert status == 400 and "hot.exr holds values from" in doc["error"] and "--clip" in doc["error"], doc
            ok = H.exr(H.source("EXR") / 4)
            status, doc = await upload(ok, "linear.exr")
            assert status == 200, doc
            assert "linear.exr" in coord.status().showing

    asyncio.run(go())
