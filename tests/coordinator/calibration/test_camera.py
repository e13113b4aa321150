"""Camera sources: spec parsing, folder replay and recording, the room camera over real gRPC,
and the OpenCV camera's error path (no device is faked)."""
from __future__ import annotations

import numpy as np
import pytest

from coordinator.camera import (
    CameraError,
    CaptureRecorder,
    FolderCamera,
    RecordingCamera,
    encode_png16,
    open_camera,
    parse_spec,
    quantize16,
    read_png,
    to_float_image,
)
from sim.room import Room
from sim.scene import reference_scene
from sim.wire.service import RoomServerThread


def test_specs_parse_with_their_options_and_bad_ones_are_named():
    s = parse_spec("room://127.0.0.1:7700?camera=1")
    assert (s.kind, s.target, s.options) == ("room", "127.0.0.1:7700", {"camera": "1"})
    s = parse_spec("opencv:0?exposure=-6&gain=0&auto_exposure=1&discard=3")
    assert (s.kind, s.target) == ("opencv", "0") and s.options["exposure"] == "-6" and s.options["discard"] == "3"
    s = parse_spec("/dev/video2?width=1920&height=1080")
    assert (s.kind, s.target, s.options["width"]) == ("opencv", "/dev/video2", "1920")
    assert parse_spec("folder:/tmp/run 1").target == "/tmp/run 1"
    for bad, words in [("", "empty"), ("room://nohost", "room://HOST:PORT"), ("room://h:99999", "room://HOST:PORT"),
                       ("opencv:0?exposure=bright", "exposure must be a number"), ("opencv:0?zoom=2", "unknown option(s) zoom"),
                       ("opencv:0?width=0", "width must be positive"), ("http://cam", "unknown camera source"),
                       ("folder:", "needs a directory"), ("opencv:", "device index"), ("room://h:1?camera=x", "camera number"),
                       ("opencv:0?backend=dshow", "backend")]:
        with pytest.raises(CameraError) as err:
            parse_spec(bad)
        assert words in str(err.value), (bad, str(err.value))


def test_images_of_any_camera_dtype_become_rgb_float32():
    assert to_float_image(np.full((2, 3), 255, np.uint8), source="t").shape == (2, 3, 3)
    np.testing.assert_allclose(to_float_image(np.full((1, 1, 3), 65535, np.uint16), source="t"), 1.0)
    np.testing.assert_allclose(to_float_image(np.array([[[2.0, -1.0, np.nan, 0.5]]]), source="t"), [[[1.0, 0.0, 0.0]]])
    with pytest.raises(CameraError, match="shape"):
        to_float_image(np.zeros((2, 3, 5), np.uint8), source="t")


def test_recording_then_folder_replay_gives_the_same_pixels(tmp_path):
    rng = np.random.default_rng(0)
    frames = [rng.random((30, 40, 3), dtype=np.float32) for _ in range(3)]

    class Source:   # a stand-in for any Camera: returns prepared frames
        spec = "test"
        size = (40, 30)
        supports_exposure = False

        def __init__(self):
            self.i = 0

        def capture(self, *, exposure=None):
            self.i += 1
            return frames[self.i - 1]

        def close(self):
            pass

    rec = RecordingCamera(Source(), tmp_path / "run")
    live = [rec.capture() for _ in range(3)]
    assert sorted(p.name for p in (tmp_path / "run").iterdir()) == ["000001.png", "000002.png", "000003.png"]
    for a, f in zip(live, frames):
        assert np.abs(a - f).max() <= 0.5 / 65535 + 1e-7      # 16-bit quantisation only
        np.testing.assert_array_equal(a, quantize16(f))
    cam = open_camera(f"folder:{tmp_path / 'run'}")
    for a in live:
        np.testing.assert_array_equal(cam.capture(), a)       # bit-identical replay
    with pytest.raises(CameraError, match="ran out of images after 3 captures"):
        cam.capture()
    with pytest.raises(CameraError, match="already holds 3 captures"):
        CaptureRecorder(tmp_path / "run")


def test_folder_camera_errors_on_a_size_change_and_on_missing_folders(tmp_path):
    d = tmp_path / "f"
    d.mkdir()
    (d / "000001.png").write_bytes(encode_png16(np.zeros((10, 12, 3), np.float32)))
    (d / "000002.png").write_bytes(encode_png16(np.zeros((11, 12, 3), np.float32)))
    cam = FolderCamera(parse_spec(f"folder:{d}"))
    assert cam.capture().shape == (10, 12, 3) and cam.size == (12, 10)
    with pytest.raises(CameraError, match="000002.png is 12x11 but this camera's earlier captures are 12x10"):
        cam.capture()
    with pytest.raises(CameraError, match="not a directory"):
        open_camera(f"folder:{tmp_path / 'nope'}")
    (tmp_path / "empty").mkdir()
    with pytest.raises(CameraError, match="no recorded captures"):
        open_camera(f"folder:{tmp_path / 'empty'}")
    (d / "000003.png").write_bytes(b"not a png")
    cam.next_index = 3
    with pytest.raises(CameraError, match="not a readable PNG"):
        cam.capture()


def test_png16_keeps_channel_order(tmp_path):
    img = np.zeros((4, 5, 3), np.float32)
    img[..., 0] = 1.0      # red
    f = tmp_path / "x.png"
    f.write_bytes(encode_png16(img))
    back = read_png(f, source="t")
    assert back[0, 0].tolist() == [1.0, 0.0, 0.0]


def test_opencv_camera_without_a_device_says_so():
    # no camera is attached to this machine; the error must say what to check
    with pytest.raises(CameraError, match="no device /dev/video97"):
        open_camera("/dev/video97?exposure=-6")
    with pytest.raises(CameraError, match="cannot open the device"):
        open_camera("opencv:97")


def test_room_camera_captures_over_grpc_and_names_an_absent_room():
    room = Room(reference_scene(projector_scale=0.1, camera_scale=0.1), noise=False)
    room.set_active(["r2c2"])
    w, h = room.projector_size("r2c2")
    room.set_frame("r2c2", np.full((h, w, 3), 255, np.uint8))
    expected = room.capture()
    with RoomServerThread(room) as server:
        cam = open_camera(f"room://{server.address}")
        try:
            img = cam.capture()
            assert img.dtype == np.float32 and img.shape == expected.shape
            np.testing.assert_allclose(img, expected, atol=1e-6)   # noise off: the same picture
            assert cam.size == (expected.shape[1], expected.shape[0])
        finally:
            cam.close()
        bad = open_camera(f"room://{server.address}?camera=5")
        try:
            with pytest.raises(CameraError, match="refused the capture.*camera"):
                bad.capture()
        finally:
            bad.close()
    gone = open_camera(f"room://{server.address}?timeout=2")
    try:
        with pytest.raises(CameraError, match="not reachable"):
            gone.capture()
    finally:
        gone.close()
