"""Cameras for calibration: one interface, three sources.

A camera spec is a string (rig.toml ``cameras = [...]``, the coordinator's
``--camera`` or a job's ``cameras`` parameter):

``room://HOST:PORT[?camera=N&wait=1&timeout=60]``
    The virtual room's Capture RPC (``shadowless room``); ``camera`` picks one
    of the room's cameras (default 0). The coordinator's monotonic clock is the
    rig clock, so from the second capture on the camera asks the room to wait
    until every streaming projector has swapped in a frame shown after this
    camera's previous capture (``wait=0`` turns that off; a job that captures
    twice without showing anything new needs it off).
``opencv:INDEX[?options]`` or a device path (``/dev/video0[?options]``)
    A real camera through ``cv2.VideoCapture``. Options (query string):
    ``exposure`` (CAP_PROP_EXPOSURE, driver units; on V4L2 set
    ``auto_exposure=1`` first for manual mode), ``auto_exposure``, ``gain``,
    ``width``, ``height``, ``fps``, ``discard`` (frames dropped before each
    capture so a pattern shown after the previous frame is not read from the
    driver's queue, default 2), ``average`` (frames averaged per capture,
    default 1) and ``backend`` (``any`` or ``v4l2``).
``folder:DIR``
    Replays ``DIR/000001.png``, ``DIR/000002.png`` ... in order, as recorded by
    :class:`RecordingCamera` (16-bit PNG, RGB); fails clearly when it runs
    out of images or when an image's size differs from the first one's.

Every camera returns captures as ``(H, W, 3) float32`` in [0, 1] (linear, as
the sensor reports it) from :meth:`Camera.capture`. :class:`RecordingCamera`
wraps any camera and saves each capture atomically, so a calibration run on a
real rig can be replayed offline with ``folder:DIR``.
"""
from __future__ import annotations

import math
import re
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol
from urllib.parse import parse_qsl

import numpy as np

from coordinator.errors import CoordinatorError
from protos.store import atomic_write_bytes

#: File names of a recorded/replayed sequence: 000001.png, 000002.png, ...
FRAME_NAME = "{:06d}.png"
_FRAME_RE = re.compile(r"^(\d{6})\.png$")


class CameraError(CoordinatorError):
    """A camera cannot be opened or cannot deliver a capture; the message names the spec."""


class Camera(Protocol):
    """What calibration needs from a camera."""

    spec: str

    @property
    def size(self) -> tuple[int, int] | None:
        """(width, height) of the captures, once known (None before the first capture)."""

    #: whether :meth:`capture` accepts a relative ``exposure`` per capture
    supports_exposure: bool

    def capture(self, *, exposure: float | None = None) -> np.ndarray:
        """One image: (H, W, 3) float32 in [0, 1]. ``exposure``: relative to the camera's own
        (only where :attr:`supports_exposure`; others raise :class:`CameraError`)."""

    def close(self) -> None:
        """Release the device or channel."""


@dataclass(frozen=True)
class CameraSpec:
    """A parsed camera spec: ``kind`` in {"room", "opencv", "folder"}, ``target`` and options."""

    kind: str
    target: str
    options: dict[str, str] = field(default_factory=dict)
    text: str = ""


_OPENCV_OPTIONS = {"exposure", "auto_exposure", "gain", "width", "height", "fps", "discard", "average", "backend"}
_ROOM_OPTIONS = {"camera", "timeout", "wait"}


def parse_spec(spec: str) -> CameraSpec:
    """Parse a camera spec (see the module docstring); raise :class:`CameraError` naming what is wrong."""
    if not isinstance(spec, str) or not spec.strip():
        raise CameraError("empty camera spec: use room://HOST:PORT, opencv:INDEX, /dev/videoN or folder:DIR")
    text = spec.strip()
    if text.startswith("folder:"):
        target = text[len("folder:"):]
        if not target:
            raise CameraError(f"camera {text!r}: folder: needs a directory, e.g. folder:captures/run1")
        return CameraSpec("folder", target, {}, text)
    base, _, query = text.partition("?")
    try:
        options = dict(parse_qsl(query, keep_blank_values=True, strict_parsing=bool(query)))
    except ValueError as exc:
        raise CameraError(f"camera {text!r}: cannot read the options after '?' ({exc}); write e.g. ?exposure=-6&gain=0") from None
    if base.startswith("room://"):
        target = base[len("room://"):].rstrip("/")
        host, sep, port = target.rpartition(":")
        if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
            raise CameraError(f"camera {text!r}: room cameras are room://HOST:PORT, e.g. room://127.0.0.1:7700")
        _check_options(text, options, _ROOM_OPTIONS)
        if "camera" in options and not options["camera"].isdigit():
            raise CameraError(f"camera {text!r}: camera=N needs a room camera number, got {options['camera']!r}")
        if options.get("wait", "1") not in ("0", "1"):
            raise CameraError(f"camera {text!r}: wait must be 0 or 1, got {options['wait']!r}")
        if "timeout" in options and not _number(text, "timeout", options["timeout"], float) > 0:
            raise CameraError(f"camera {text!r}: timeout must be positive seconds")
        return CameraSpec("room", target, options, text)
    if base.startswith("opencv:"):
        target = base[len("opencv:"):]
        if not target:
            raise CameraError(f"camera {text!r}: opencv: needs a device index or path, e.g. opencv:0")
    elif base.startswith("/dev/"):
        target = base
    else:
        raise CameraError(f"camera {text!r}: unknown camera source; use room://HOST:PORT, opencv:INDEX, "
                          "a device path such as /dev/video0, or folder:DIR")
    _check_options(text, options, _OPENCV_OPTIONS)
    for key in ("exposure", "auto_exposure", "gain", "fps"):
        if key in options:
            _number(text, key, options[key], float)
    for key in ("width", "height", "discard", "average"):
        if key in options:
            value = _number(text, key, options[key], int)
            if value < (1 if key in ("width", "height", "average") else 0):
                raise CameraError(f"camera {text!r}: {key} must be {'positive' if key != 'discard' else '>= 0'}, got {value}")
    if options.get("backend", "any") not in ("any", "v4l2"):
        raise CameraError(f"camera {text!r}: backend must be 'any' or 'v4l2', got {options['backend']!r}")
    return CameraSpec("opencv", target, options, text)


def _check_options(text: str, options: dict[str, str], known: set[str]) -> None:
    unknown = sorted(set(options) - known)
    if unknown:
        raise CameraError(f"camera {text!r}: unknown option(s) {', '.join(unknown)} (known: {', '.join(sorted(known))})")


def _number(text: str, key: str, value: str, kind):
    try:
        return kind(value)
    except ValueError:
        raise CameraError(f"camera {text!r}: {key} must be {'an integer' if kind is int else 'a number'}, got {value!r}") from None


def to_float_image(image: np.ndarray, *, source: str) -> np.ndarray:
    """Any camera image as (H, W, 3) float32 in [0, 1]: uint8 / 255, uint16 / 65535, floats clipped.

    Single-channel images are repeated to three channels; a fourth channel is dropped.
    """
    arr = np.asarray(image)
    if arr.ndim == 2:
        arr = arr[:, :, None]
    if arr.ndim != 3 or arr.shape[2] not in (1, 3, 4) or arr.shape[0] < 1 or arr.shape[1] < 1:
        raise CameraError(f"{source}: delivered an image of shape {arr.shape}; expected (H, W), (H, W, 3) or (H, W, 4)")
    if arr.shape[2] == 1:
        arr = np.repeat(arr, 3, axis=2)
    arr = arr[:, :, :3]
    if arr.dtype == np.uint8:
        out = arr.astype(np.float32) / np.float32(255.0)
    elif arr.dtype == np.uint16:
        out = arr.astype(np.float32) / np.float32(65535.0)
    elif arr.dtype in (np.float16, np.float32, np.float64):
        out = np.clip(np.nan_to_num(arr.astype(np.float32), nan=0.0), 0.0, 1.0)
    else:
        raise CameraError(f"{source}: delivered {arr.dtype} pixels; expected uint8, uint16 or float")
    return np.ascontiguousarray(out)


class _SizeCheck:
    """Shared: remember the first capture's size and refuse a different one later."""

    spec: str
    _size: tuple[int, int] | None = None
    supports_exposure = False

    def _no_exposure(self, exposure: float | None) -> None:
        if exposure is not None and exposure != 1.0:
            raise CameraError(f"camera {self.spec} cannot change its exposure per capture; use a camera that can "
                              "(the virtual room's) or leave the exposure to the camera's settings")

    @property
    def size(self) -> tuple[int, int] | None:
        return self._size

    def _check_size(self, image: np.ndarray, what: str) -> np.ndarray:
        size = (image.shape[1], image.shape[0])
        if self._size is None:
            self._size = size
        elif size != self._size:
            raise CameraError(f"{what} is {size[0]}x{size[1]} but this camera's earlier captures are "
                              f"{self._size[0]}x{self._size[1]}: the camera changed resolution mid-run")
        return image


# ---------------------------------------------------------------------- room
class RoomCamera(_SizeCheck):
    """A camera of the virtual room: calls its Capture RPC (gRPC, blocking; use from a worker thread)."""

    supports_exposure = True

    def __init__(self, spec: CameraSpec, *, timeout_s: float | None = None):
        self.spec = spec.text
        self.target = spec.target
        self.index = int(spec.options.get("camera", 0))
        self.timeout_s = float(spec.options.get("timeout", timeout_s or 60.0))
        self.wait = spec.options.get("wait", "1") == "1"
        self._last_ns = 0
        # the room's gRPC link and messages only when a room camera is opened, not at every coordinator's start
        from coordinator.wire.room_camera import RoomCaptureLink
        self._link = RoomCaptureLink(self.target)
        self._lock = threading.Lock()

    def not_before(self, rig_ns: int) -> None:
        """The next capture must see frames swapped at or after ``rig_ns`` (the last pattern's time)."""
        self._last_ns = max(self._last_ns, int(rig_ns))

    def capture(self, *, exposure: float | None = None) -> np.ndarray:
        if exposure is not None and not (math.isfinite(exposure) and exposure > 0):
            raise CameraError(f"camera {self.spec}: exposure must be a positive factor, got {exposure}")
        from coordinator.wire.room_camera import RoomCallError, RoomFailure
        timeout_ms = int(min(self.timeout_s, 30.0) * 1000)
        try:
            with self._lock:
                got = self._link.capture(camera=self.index, not_before_rig_ns=self._last_ns if self.wait else 0,
                                         timeout_ms=timeout_ms, exposure=exposure or 0.0,
                                         deadline_s=self.timeout_s + 5.0)
                self._last_ns = got.received_ns
        except RoomCallError as exc:
            if exc.failure is RoomFailure.UNREACHABLE:
                raise CameraError(f"camera {self.spec}: the room at {self.target} is not reachable "
                                  "(is `shadowless room` running there?)") from exc
            if exc.failure is RoomFailure.TIMEOUT:
                raise CameraError(f"camera {self.spec}: the room did not answer within {self.timeout_s:g} s") from exc
            if exc.failure is RoomFailure.MALFORMED:
                raise CameraError(f"camera {self.spec}: the room sent a malformed image: {exc.details}") from exc
            raise CameraError(f"camera {self.spec}: the room refused the capture: {exc.details}") from exc
        if got.late_slots:
            raise CameraError(f"camera {self.spec}: projector(s) {', '.join(got.late_slots)} had not shown the current "
                              f"pattern in the room when it captured (waited {timeout_ms / 1000:g} s): are their nodes "
                              "sending to this room (--output room://...)?")
        return self._check_size(to_float_image(got.image, source=f"camera {self.spec}"), f"camera {self.spec}: a capture")

    def close(self) -> None:
        self._link.close()


# ---------------------------------------------------------------------- opencv
class OpenCVCamera(_SizeCheck):
    """A real camera through ``cv2.VideoCapture`` (index or device path) with exposure settings."""

    def __init__(self, spec: CameraSpec):
        import cv2

        self.spec = spec.text
        opts = spec.options
        target: int | str = int(spec.target) if spec.target.isdigit() else spec.target
        backend = cv2.CAP_V4L2 if opts.get("backend") == "v4l2" else cv2.CAP_ANY
        if isinstance(target, str) and not Path(target).exists():
            raise CameraError(f"camera {self.spec}: no device {target} (is the camera plugged in? see `ls /dev/video*`)")
        try:
            cap = cv2.VideoCapture(target, backend)
        except cv2.error as exc:
            raise CameraError(f"camera {self.spec}: OpenCV cannot open it: {exc}") from exc
        if not cap.isOpened():
            cap.release()
            raise CameraError(f"camera {self.spec}: cannot open the device (no camera at {spec.target}, or it is in use "
                              "by another program; check `ls /dev/video*` and its permissions)")
        self._cap = cap
        props = [("width", cv2.CAP_PROP_FRAME_WIDTH), ("height", cv2.CAP_PROP_FRAME_HEIGHT), ("fps", cv2.CAP_PROP_FPS),
                 ("auto_exposure", cv2.CAP_PROP_AUTO_EXPOSURE), ("exposure", cv2.CAP_PROP_EXPOSURE),
                 ("gain", cv2.CAP_PROP_GAIN)]
        for key, prop in props:   # auto_exposure before exposure: drivers ignore manual exposure otherwise
            if key in opts and not cap.set(prop, float(opts[key])):
                cap.release()
                raise CameraError(f"camera {self.spec}: the driver refused {key}={opts[key]} "
                                  "(see `v4l2-ctl --list-ctrls` for supported values)")
        self.discard = int(opts.get("discard", 2))
        self.average = int(opts.get("average", 1))

    def _read(self) -> np.ndarray:
        import cv2

        ok, frame = self._cap.read()
        if not ok or frame is None:
            raise CameraError(f"camera {self.spec}: the camera stopped delivering frames (unplugged or busy?)")
        if frame.ndim == 3 and frame.shape[2] >= 3:
            frame = cv2.cvtColor(frame[:, :, :3], cv2.COLOR_BGR2RGB)
        return to_float_image(frame, source=f"camera {self.spec}")

    def capture(self, *, exposure: float | None = None) -> np.ndarray:
        self._no_exposure(exposure)
        for _ in range(self.discard):
            if not self._cap.grab():
                raise CameraError(f"camera {self.spec}: the camera stopped delivering frames (unplugged or busy?)")
        acc = self._read()
        for _ in range(self.average - 1):
            acc = acc + self._read()
        img = acc / np.float32(self.average) if self.average > 1 else acc
        return self._check_size(img, f"camera {self.spec}: a capture")

    def close(self) -> None:
        self._cap.release()


# ---------------------------------------------------------------------- folder
def read_png(path: Path, *, source: str) -> np.ndarray:
    """Read an 8- or 16-bit PNG (gray or RGB; alpha dropped) as (H, W, 3) float32 in [0, 1],
    through the coordinator's one decoder (its declared size checked before decoding)."""
    from coordinator.image_decode import ImageRefused, read_image_file

    try:
        img = read_image_file(path)
    except ImageRefused as exc:
        raise CameraError(f"{source}: not a readable PNG: {exc}") from None
    return to_float_image(img, source=f"{source} ({path.name})")


def encode_png16(image: np.ndarray) -> bytes:
    """(H, W, 3) float in [0, 1] -> 16-bit RGB PNG bytes (round(65535 x))."""
    import cv2

    arr = np.asarray(image, np.float32)
    if arr.ndim != 3 or arr.shape[2] != 3:
        raise ValueError(f"image must be (H, W, 3), got {arr.shape}")
    q = np.round(np.clip(arr, 0.0, 1.0) * 65535.0).astype(np.uint16)
    ok, buf = cv2.imencode(".png", cv2.cvtColor(q, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:  # pragma: no cover - OpenCV always encodes a valid uint16 array
        raise CameraError("cannot encode a capture as PNG")
    return buf.tobytes()


class FolderCamera(_SizeCheck):
    """Replays a recorded run: ``DIR/000001.png``, ``DIR/000002.png``, ... in order."""

    def __init__(self, spec: CameraSpec):
        self.spec = spec.text
        self.dir = Path(spec.target)
        if not self.dir.is_dir():
            raise CameraError(f"camera {self.spec}: {self.dir} is not a directory of recorded captures")
        self.count = len([p for p in self.dir.iterdir() if _FRAME_RE.match(p.name)])
        if self.count == 0:
            raise CameraError(f"camera {self.spec}: {self.dir} holds no recorded captures (000001.png, ...)")
        self.next_index = 1

    def capture(self, *, exposure: float | None = None) -> np.ndarray:
        self._no_exposure(exposure)
        path = self.dir / FRAME_NAME.format(self.next_index)
        if not path.exists():
            raise CameraError(f"camera {self.spec}: ran out of images after {self.next_index - 1} captures "
                              f"({path.name} missing): this run asks for more captures than were recorded; "
                              "replay with the same slots, mode and parameters as the recorded run")
        img = read_png(path, source=f"camera {self.spec}")
        self._check_size(img, f"camera {self.spec}: {path.name}")
        self.next_index += 1
        return img

    def close(self) -> None:
        pass


# ---------------------------------------------------------------------- recording
def quantize16(image: np.ndarray) -> np.ndarray:
    """What a 16-bit PNG round trip gives back: (H, W, 3) float32 ``round(65535 x) / 65535``."""
    q = np.round(np.clip(np.asarray(image, np.float32), 0.0, 1.0) * np.float32(65535.0))
    return (q.astype(np.uint16).astype(np.float32) / np.float32(65535.0)).astype(np.float32)


class CaptureRecorder:
    """Saves captures into ``directory`` as 000001.png, 000002.png, ... (16-bit RGB, atomic writes).

    The directory must be empty (or absent): a replay has to see exactly one run.
    :meth:`record` returns what a replay will read back, so a live run and its
    replay compute on identical pixels.
    """

    def __init__(self, directory: str | Path):
        self.dir = Path(directory)
        if self.dir.exists():
            if not self.dir.is_dir():
                raise CameraError(f"cannot record into {self.dir}: it is a file")
            old = [p for p in self.dir.iterdir() if _FRAME_RE.match(p.name)]
            if old:
                raise CameraError(f"cannot record into {self.dir}: it already holds {len(old)} captures; choose an empty folder")
        try:
            self.dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise CameraError(f"cannot record into {self.dir}: {exc.strerror or exc}") from exc
        self.written = 0

    def record(self, image: np.ndarray) -> np.ndarray:
        self.written += 1
        try:
            atomic_write_bytes(self.dir / FRAME_NAME.format(self.written), encode_png16(image))
        except OSError as exc:
            raise CameraError(f"cannot record capture {self.written} into {self.dir}: {exc.strerror or exc}") from exc
        return quantize16(image)


class RecordingCamera:
    """Wraps ``camera``; saves every capture to ``directory`` (see :class:`CaptureRecorder`)."""

    def __init__(self, camera: Camera, directory: str | Path):
        self.camera = camera
        self.spec = camera.spec
        self.recorder = CaptureRecorder(directory)

    @property
    def size(self) -> tuple[int, int] | None:
        return self.camera.size

    @property
    def supports_exposure(self) -> bool:
        return self.camera.supports_exposure

    def capture(self, *, exposure: float | None = None) -> np.ndarray:
        return self.recorder.record(self.camera.capture(exposure=exposure))

    def close(self) -> None:
        self.camera.close()


def open_camera(spec: str, *, record: str | Path | None = None) -> Camera:
    """Open the camera ``spec`` names (see the module docstring); ``record``: also save each capture there."""
    parsed = parse_spec(spec)
    if parsed.kind == "room":
        cam: Camera = RoomCamera(parsed)
    elif parsed.kind == "folder":
        cam = FolderCamera(parsed)
    else:
        cam = OpenCVCamera(parsed)
    if record is not None:
        try:
            return RecordingCamera(cam, record)
        except BaseException:
            cam.close()
            raise
    return cam
