"""Which video decoder a node uses: hardware where the platform offers one, else software.

The node's ``--decoder`` option (``$SHADOWLESS_DECODER`` for its presenter process) says what
to use for each video stream:

* ``auto`` (the default): the first hardware decoder that opens here, in this order: the
  codec's V4L2 memory-to-memory decoder (``h264_v4l2m2m``, ``hevc_v4l2m2m``: a Raspberry Pi,
  most ARM boards), then FFmpeg's hardware acceleration through VAAPI (Intel and AMD on Linux),
  DRM (stateless decoders: a Pi 5's HEVC) or VideoToolbox (macOS), when this FFmpeg was built
  with them; else software, saying once why each was passed over.
* ``software``: FFmpeg's own decoder, on the CPU.
* a decoder's name (``h264_v4l2m2m``), a family (``v4l2m2m``: the stream's codec's), or a
  hardware device type (``vaapi``, ``drm``, ``cuda``, ``videotoolbox``, ``qsv``): that one, or
  software when it cannot open here, with one log line saying why.

A choice is probed by opening it (a decoder's context, a device's hardware context), never by
decoding a picture, and remembered for the process: the line is logged once per codec and wish.
A hardware decoder that opens but then fails on a stream's first picture is passed over for
that stream (:class:`node.asset_decode.VideoDecoder` says so and decodes in software).
"""
from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field
from typing import Any

__all__ = ["AUTO_DEVICES", "ENV", "DecoderChoice", "check_wish", "choose", "wish_from_env"]

log = logging.getLogger(__name__)

#: the environment variable the presenter process reads its ``--decoder`` from
ENV = "SHADOWLESS_DECODER"
#: hardware device types ``auto`` tries (after the codec's V4L2 M2M decoder), in this order
AUTO_DEVICES = ("vaapi", "drm", "videotoolbox")
_DEVICE_TYPES = ("vaapi", "drm", "cuda", "qsv", "videotoolbox", "vdpau", "d3d11va", "dxva2", "vulkan", "opencl",
                 "mediacodec", "amf")
_FAMILIES = ("v4l2m2m", "cuvid", "qsv", "mediacodec", "rkmpp", "mmal")


@dataclass(frozen=True)
class DecoderChoice:
    """The decoder a stream of ``codec`` is decoded with.

    ``kind``: "software"; "decoder" (``name`` is an FFmpeg decoder, e.g. ``h264_v4l2m2m``); or
    "hwaccel" (``name`` is a device type, e.g. ``vaapi``; ``hwaccel`` the PyAV ``HWAccel`` to
    open the container with). ``note``: why the wish was not granted ("" when it was).
    """

    codec: str
    name: str
    kind: str
    note: str = ""
    hwaccel: Any = field(default=None, compare=False)
    detail: str = field(default="", compare=False)   # what each candidate said, for the log

    @property
    def label(self) -> str:
        """The decoder alone, as a heartbeat's ``decoder`` names it: ``h264_v4l2m2m``,
        ``vaapi (hwaccel)`` or ``software`` (the note apart)."""
        return {"software": "software", "decoder": self.name, "hwaccel": f"{self.name} (hwaccel)"}[self.kind]

    def describe(self) -> str:
        """What the log shows: ``h264_v4l2m2m``, ``vaapi (hwaccel)``, ``software`` or
        ``software (h264_v4l2m2m: cannot open here)``."""
        return f"{self.label} ({self.note})" if self.note else self.label


def check_wish(text: str) -> str:
    """``--decoder``'s value, checked: "auto", "software", a family, a device type or a name
    FFmpeg knows as a decoder; ``ValueError`` naming the choices otherwise (argparse's type)."""
    import av

    wish = str(text).strip()
    if wish in ("auto", "software") or wish in _FAMILIES or wish in _DEVICE_TYPES:
        return wish
    if wish in av.codecs_available:
        try:
            av.Codec(wish, "r")
            return wish
        except Exception:   # noqa: BLE001 - an encoder only
            pass
    raise ValueError(f"no decoder {wish!r}: use auto, software, a decoder's name (h264_v4l2m2m), a family "
                     f"({', '.join(_FAMILIES[:2])}) or a hardware device type ({', '.join(AUTO_DEVICES)}, cuda)")


def wish_from_env() -> str:
    """The presenter's wish: ``$SHADOWLESS_DECODER`` if set (the node's ``--decoder``), else auto."""
    return os.environ.get(ENV, "").strip() or "auto"


def _open_decoder(name: str, codec: str) -> str:
    """"" if decoder ``name`` decodes ``codec`` and opens here, else why not (a few words)."""
    import av

    if name not in av.codecs_available:
        return "not in this FFmpeg"
    try:
        c = av.Codec(name, "r")
    except Exception:   # noqa: BLE001
        return "not a decoder"
    if c.id != av.Codec(codec, "r").id:
        return f"does not decode {codec}"
    try:
        ctx = av.CodecContext.create(name, "r")
        ctx.open()
    except Exception as exc:   # noqa: BLE001 - av.FFmpegError and friends: the device is not there
        return f"cannot open here ({_short(exc)})"
    return ""


def _open_device(device: str, codec: str) -> tuple[Any, str]:
    """(HWAccel, "") if hardware device ``device`` opens for ``codec`` here, else (None, why not)."""
    import av
    from av.codec import hwaccel

    if device not in hwaccel.hwdevices_available():
        return None, "not in this FFmpeg"
    try:
        probe = hwaccel.HWAccel(device, allow_software_fallback=False)
        probe.create(av.Codec(codec, "r"))
    except Exception as exc:   # noqa: BLE001 - NotImplementedError, PermissionError, av errors
        return None, f"cannot open here ({_short(exc)})"
    return hwaccel.HWAccel(device, allow_software_fallback=True), ""


def _short(exc: BaseException) -> str:
    text = str(exc).strip() or type(exc).__name__
    return text if len(text) <= 80 else text[:77] + "..."


_CHOSEN: dict[tuple[str, str], DecoderChoice] = {}


def choose(codec: str, wish: str = "auto") -> DecoderChoice:
    """The decoder for a stream of ``codec`` ("h264", "hevc", ...) under ``wish`` (see the module
    docstring). Remembered per (codec, wish) for the process; a fall-back is logged once."""
    key = (codec, wish)
    if key not in _CHOSEN:
        _CHOSEN[key] = _choose(codec, wish)
        c = _CHOSEN[key]
        if c.note and wish != "auto":
            log.warning("video decoder %s for %s: %s; decoding in software", wish, codec, c.note)
        elif c.note:
            log.info("video decoder for %s: software, %s%s", codec, c.note, f" ({c.detail})" if c.detail else "")
        elif c.kind != "software":
            log.info("video decoder for %s: %s", codec, c.describe())
    return _CHOSEN[key]


def _choose(codec: str, wish: str) -> DecoderChoice:
    if wish == "software":
        return DecoderChoice(codec, codec, "software")
    if wish == "auto":
        tried = []
        for name in (f"{codec}_v4l2m2m",):
            why = _open_decoder(name, codec)
            if not why:
                return DecoderChoice(codec, name, "decoder")
            if why != "not in this FFmpeg":
                tried.append(f"{name}: {why}")
        for device in AUTO_DEVICES:
            acc, why = _open_device(device, codec)
            if acc is not None:
                return DecoderChoice(codec, device, "hwaccel", hwaccel=acc)
            if why != "not in this FFmpeg":
                tried.append(f"{device}: {why}")
        return DecoderChoice(codec, codec, "software", note="no hardware decoder here", detail="; ".join(tried))
    if wish in _DEVICE_TYPES:
        acc, why = _open_device(wish, codec)
        if acc is not None:
            return DecoderChoice(codec, wish, "hwaccel", hwaccel=acc)
        return DecoderChoice(codec, codec, "software", note=f"{wish} {why}")
    name = f"{codec}_{wish}" if wish in _FAMILIES else wish
    if name == codec:
        return DecoderChoice(codec, codec, "software")
    why = _open_decoder(name, codec)
    if not why:
        return DecoderChoice(codec, name, "decoder")
    return DecoderChoice(codec, codec, "software", note=f"{name} {why}")
