"""Float content must lie in 0..1: refused in one line naming the file and the range found (or
clipped with ``--clip``) wherever float content arrives -- the gRPC Show and Play of any client,
`show` and `play` of .npy and float image files, `content add` (the console's upload: in
test_image_decode.py)."""
from __future__ import annotations

import asyncio
import subprocess
import sys

import numpy as np
import pytest

from coordinator.api import PlaySettings
from coordinator.asset_probe import probe_still
from rigctl.client import CallRefused
from rigctl.link import Client
from imaging.compensation.errors import CompensationError
from coordinator.compensation.image_param import decode_image_param, encode_image_array
from coordinator.errors import AssetError
from coordinator.float_range import check_float_range
from coordinator.rig import Rig, init_rig
from inprocess_coordinator import inprocess_coordinator

TOKEN = b"f" * 32


@pytest.mark.parametrize("dtype", [np.float16, np.float32, np.float64])
def test_floats_in_0_1_and_integers_pass_unchanged(dtype):
    a = np.linspace(0, 1, 12, dtype=dtype).reshape(3, 4)
    assert check_float_range(a, "a") is a
    u = np.full((2, 2), 65535, np.uint16)
    assert check_float_range(u, "u") is u


def test_out_of_range_is_refused_naming_the_range_and_clip_clips():
    a = np.array([[-0.25, 0.5], [3.5, 1.0]], np.float32)
    with pytest.raises(ValueError, match=r"^hot\.npy holds values from -0\.25 to 3\.5, but float content must lie "
                                         r"in 0\.\.1 .*pass --clip"):
        check_float_range(a, "hot.npy")
    clipped = check_float_range(a, "hot.npy", clip=True)
    np.testing.assert_array_equal(clipped, np.minimum(np.maximum(a, 0), 1))   # numpy's clip, independently
    assert clipped.dtype == np.float32 and a[1, 0] == 3.5, "the caller's array is not changed"


def test_nan_is_refused_even_with_clip():
    a = np.array([0.5, np.nan], np.float32)
    for clip in (False, True):
        with pytest.raises(ValueError, match="NaN or infinite"):
            check_float_range(a, "n.npy", clip=clip)


def test_content_add_refuses_an_out_of_range_npy_or_float_tiff(tmp_path):
    np.save(tmp_path / "hot.npy", np.full((4, 4, 3), 2.0, np.float32))
    with pytest.raises(AssetError, match=r"hot\.npy holds values from 2 to 2"):
        probe_still(tmp_path / "hot.npy")
    np.save(tmp_path / "ok.npy", np.full((4, 4, 3), 0.5, np.float32))
    assert probe_still(tmp_path / "ok.npy").bit_depth == 32
    import cv2

    assert cv2.imwrite(str(tmp_path / "hot.tif"), np.full((4, 4, 3), 2.5, np.float32))   # a float TIFF
    with pytest.raises(AssetError, match=r"hot\.tif holds values from 2\.5 to 2\.5.*clip it to 0\.\.1 before adding"):
        probe_still(tmp_path / "hot.tif")


def test_a_compensation_target_outside_0_1_is_refused(tmp_path):
    hot = np.full((8, 8, 3), 0.25, np.float32)
    hot[2, 3] = 1.75
    with pytest.raises(CompensationError, match=r"^image target\.npy holds values from 0\.25 to 1\.75.*clip it to 0\.\.1"):
        decode_image_param(encode_image_array(hot, "target.npy"))
    img, _ = decode_image_param(encode_image_array(np.clip(hot, 0, 1), "target.npy"))
    assert img.max() == 1.0


def test_grpc_show_and_play_refuse_floats_outside_0_1_from_any_client(tmp_path):
    """A client other than the CLI (which refuses before sending) reaches the coordinator's own check."""
    async def go():
        rig = Rig(init_rig(tmp_path / "rig", name="floats", slots=["r0c0"], width=32, height=24,
                           content_width=32, content_height=24))
        async with inprocess_coordinator(rig, TOKEN) as app:
            async with await Client.connect(f"127.0.0.1:{app.port}", TOKEN) as c:
                hot = np.full((24, 32, 3), 0.5, np.float32)
                hot[0, 0] = 7.0
                with pytest.raises(CallRefused) as exc:
                    await c.show(hot, name="hot")
                assert exc.value.code == "INVALID_ARGUMENT"
                assert "holds values from 0.5 to 7" in exc.value.details and "--clip" in exc.value.details
                with pytest.raises(CallRefused) as exc:
                    await c.play(PlaySettings(fps=30, wait=False), [hot])
                assert exc.value.code == "INVALID_ARGUMENT" and "0.5 to 7" in exc.value.details
                r = await c.show(np.clip(hot, 0, 1), name="clipped")
                assert r.frame_id > 0

    asyncio.run(go())


def test_show_clip_clips_what_it_refuses_without(tmp_path, coordinator_process):
    """`shadowless show` against a real coordinator process: refused without --clip, shown with it."""
    rig_dir = init_rig(tmp_path / "rig", name="clip", slots=["r0c0"], width=32, height=24, content_width=32,
                       content_height=24)
    hot = tmp_path / "hot.npy"
    np.save(hot, np.full((24, 32, 3), 1.5, np.float32))
    conn = ["--coordinator", coordinator_process(rig_dir), "--rig-dir", str(rig_dir)]
    r = subprocess.run([sys.executable, "-m", "shadowless", "show", str(hot), *conn],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "holds values from 1.5 to 1.5" in r.stderr, r.stderr
    r = subprocess.run([sys.executable, "-m", "shadowless", "show", str(hot), "--clip", *conn],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and "showing" in r.stdout, r.stderr
