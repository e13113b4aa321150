"""A rig's per-pixel blend in an MPCDI archive: each region's alphaMap and betaMap, and back.

What is written, for each slot with blend maps (``protos.blend.BlendMaps``, the grid a downscaled
image of the projector's frame, row 0 at the top, which is how a linear texture lookup over the
region reads an MPCDI map):

* in the region's ``fileset`` (made when the profile has none, as ``sl`` regions), after its
  geometry warp file:

  - ``alphaMap``: ``path`` ``alpha-<slot>.png``, ``componentDepth`` 3, ``bitDepth`` 16,
    ``gammaEmbedded`` 1.0. A 16-bit RGB PNG of ``round(alpha * 65535)`` per channel. The gain
    applies to linear light, so no gamma is embedded: a reader takes ``(level / 65535) ** 1.0``;
  - ``betaMap``: ``path`` ``beta-<slot>.png``, ``componentDepth`` 1, ``bitDepth`` 16. A 16-bit
    grey PNG of ``round(beta * 65535)``, the black offset added in linear light;

* in the ``shadowless`` extension: ``<blend>`` holding the blend's figures as JSON text, and per
  slot ``<blendMaps slot= alpha= beta=>`` naming float32 PFMs of the maps as stored (alpha
  (h, w, 3), beta (h, w, 1)).

What "exactly" means. From shadowless to shadowless the float32 maps come back bit for bit (the
extension's PFMs are used when the PNGs still hold their quantised levels; if another tool
rewrote a PNG, the PNG wins). Through the standard data alone a map is its 16-bit levels:
maps on 16-bit levels survive export -> import bit for bit, and import -> export -> import is the
identity for any archive this module reads (8-bit levels ``q`` become the 16-bit levels
``257 q``, the same fractions). Reading accepts 8- and 16-bit grey or RGB PNGs, an alpha map's
``gammaEmbedded`` (linear alpha = value ** gammaEmbedded), a grey alpha map (the same gain on
every channel) and an RGB beta map whose channels agree; a missing alpha map means gain 1, a
missing beta map offset 0. Anything else (no PNG, a depth or channel count other than declared,
maps larger than the projector's frame or of two sizes, NaN in a PFM, values outside 0..1) is
refused with a ValueError naming the file, before anything is written.
"""
from __future__ import annotations

import json
import math
import struct
from typing import Callable, Mapping
from xml.etree import ElementTree as ET

import numpy as np

from rigctl.mpcdi.pfm import decode_pfm, encode_pfm
from protos.blend import MAX_MAP_SIDE, BlendMapError, BlendMaps

__all__ = ["LEVELS", "decode_png", "encode_png", "quantize", "read_blend", "write_blend"]

#: the levels of a 16-bit map
LEVELS = 65535
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_CHANNELS = {0: 1, 2: 3}            # PNG colour type -> channels (grey, RGB)


def quantize(values: np.ndarray) -> np.ndarray:
    """float maps in 0..1 -> uint16 levels ``round(v * 65535)`` (same shape)."""
    return np.rint(np.asarray(values, np.float64) * LEVELS).astype(np.uint16)


def encode_png(levels: np.ndarray) -> bytes:
    """(h, w) or (h, w, 3) uint16 levels -> 16-bit grey or RGB PNG bytes (channels R, G, B)."""
    import cv2  # the coordinator's stack: only when a blend is written

    a = np.asarray(levels)
    if a.dtype != np.uint16 or not (a.ndim == 2 or (a.ndim == 3 and a.shape[2] == 3)):
        raise ValueError(f"a blend map PNG holds (h, w) or (h, w, 3) uint16 levels, got {a.dtype} {a.shape}")
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(a[..., ::-1] if a.ndim == 3 else a))
    if not ok:
        raise ValueError("OpenCV could not encode a blend map PNG")
    return buf.tobytes()


def decode_png(data: bytes, *, name: str) -> tuple[np.ndarray, int]:
    """PNG bytes -> ((h, w, C) uint8 or uint16 levels, C = 1 or 3, channels R, G, B; bit depth).

    The header is read before anything is decoded: grey or RGB, 8 or 16 bits, at most
    ``MAX_MAP_SIDE`` texels a side; ValueError (one line naming ``name``) otherwise."""
    if len(data) < 33 or not data.startswith(_PNG_SIGNATURE) or data[12:16] != b"IHDR":
        raise ValueError(f"{name}: not a PNG file")
    width, height, bits, colour = struct.unpack(">IIBB", data[16:26])
    if colour not in _PNG_CHANNELS:
        raise ValueError(f"{name}: a blend map must be a grey or RGB PNG without transparency or palette "
                         f"(PNG colour type {colour})")
    if bits not in (8, 16):
        raise ValueError(f"{name}: a blend map must have 8 or 16 bits a sample, this PNG has {bits}")
    if not (1 <= width <= MAX_MAP_SIDE and 1 <= height <= MAX_MAP_SIDE):
        raise ValueError(f"{name}: a blend map must be 1..{MAX_MAP_SIDE} texels a side, this PNG is {width}x{height}")
    import cv2

    arr = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    channels = _PNG_CHANNELS[colour]
    want = np.uint16 if bits == 16 else np.uint8
    if arr is None or arr.dtype != want or arr.shape[:2] != (height, width) or (arr.ndim == 3) != (channels == 3):
        raise ValueError(f"{name}: the PNG is damaged (it does not decode to the {width}x{height} {bits}-bit image "
                         f"its header declares)")
    arr = arr[..., ::-1] if channels == 3 else arr[..., None]
    return np.ascontiguousarray(arr), bits


# ------------------------------------------------------------------------------------- export
def _sub(parent: ET.Element, tag: str, text: str | None = None, **attrs: str) -> ET.Element:
    e = ET.SubElement(parent, tag, attrs)
    if text is not None:
        e.text = text
    return e


def write_blend(root: ET.Element, ext: ET.Element, blobs: dict[str, bytes], maps: Mapping[str, BlendMaps],
                info: Mapping, regions: set[str]) -> None:
    """Add ``maps`` to an archive being written: the standard maps in the fileset of each slot in
    ``regions`` (the slots that have a region), the exact maps and ``info`` in the extension
    ``ext``; the files go into ``blobs`` by name."""
    files = root.find("files")
    if files is None:
        files = _sub(root, "files")
    _sub(ext, "blend", json.dumps(dict(info), sort_keys=True))
    for slot in sorted(maps):
        m = maps[slot]
        blobs[f"{slot}.alpha.pfm"] = encode_pfm(m.alpha)
        blobs[f"{slot}.beta.pfm"] = encode_pfm(m.beta)
        _sub(ext, "blendMaps", slot=slot, alpha=f"{slot}.alpha.pfm", beta=f"{slot}.beta.pfm")
        if slot not in regions:
            continue
        fileset = files.find(f"fileset[@region='{slot}']")
        if fileset is None:
            fileset = _sub(files, "fileset", region=slot)
        blobs[f"alpha-{slot}.png"] = encode_png(quantize(m.alpha))
        blobs[f"beta-{slot}.png"] = encode_png(quantize(m.beta))
        am = _sub(fileset, "alphaMap")
        _sub(am, "path", f"alpha-{slot}.png")
        _sub(am, "componentDepth", "3")
        _sub(am, "bitDepth", "16")
        _sub(am, "gammaEmbedded", "1.0")
        bm = _sub(fileset, "betaMap")
        _sub(bm, "path", f"beta-{slot}.png")
        _sub(bm, "componentDepth", "1")
        _sub(bm, "bitDepth", "16")


# ------------------------------------------------------------------------------------- import
def _int(e: ET.Element, tag: str, where: str) -> int | None:
    t = e.find(tag)
    if t is None:
        return None
    try:
        return int((t.text or "").strip())
    except ValueError:
        raise ValueError(f"{where}: {tag} {t.text!r} is not a whole number") from None


def _standard_map(e: ET.Element, blob: Callable[[str], bytes], what: str, region: str
                  ) -> tuple[np.ndarray, np.ndarray, int, float, str]:
    """(levels (h, w, C), linear values (h, w, C) float32, bits, gamma, path) of a region's alphaMap
    or betaMap element ``e``."""
    where = f"the {what} of region {region}"
    path_e = e.find("path")
    if path_e is None or not (path_e.text or "").strip():
        raise ValueError(f"{where} names no file (no path)")
    path = path_e.text.strip()
    levels, bits = decode_png(blob(path), name=path)
    depth, declared_bits = _int(e, "componentDepth", f"{where} ({path})"), _int(e, "bitDepth", f"{where} ({path})")
    if depth is not None and depth != levels.shape[2]:
        raise ValueError(f"{path}: {what} declares componentDepth {depth}, its PNG has {levels.shape[2]} channel(s)")
    if declared_bits is not None and declared_bits != bits:
        raise ValueError(f"{path}: {what} declares bitDepth {declared_bits}, its PNG has {bits}-bit samples")
    gamma = 1.0
    g = e.find("gammaEmbedded")
    if g is not None:
        try:
            gamma = float((g.text or "").strip())
        except ValueError:
            gamma = math.nan
        if not (math.isfinite(gamma) and 0.0 < gamma <= 10.0):
            raise ValueError(f"{path}: {what} gammaEmbedded {g.text!r} must be a number in (0, 10]")
    values = levels.astype(np.float64) / (2 ** bits - 1)
    if gamma != 1.0:
        values = values ** gamma
    return levels, values.astype(np.float32), bits, gamma, path


def _exact_maps(ext_e: ET.Element, blob: Callable[[str], bytes]) -> tuple[np.ndarray, np.ndarray, str]:
    """(alpha (h, w, 3), beta (h, w)) float32 from the extension's PFMs, and the alpha's path."""
    names = []
    for key in ("alpha", "beta"):
        n = ext_e.get(key)
        if not n:
            raise ValueError(f"the shadowless extension's blendMaps of slot {ext_e.get('slot')} lacks its {key} file")
        names.append(n)
    alpha = decode_pfm(blob(names[0]), name=names[0])
    beta = decode_pfm(blob(names[1]), name=names[1])
    if alpha.shape[2] != 3 or beta.shape[2] != 1:
        raise ValueError(f"{names[0]}, {names[1]}: the exact maps must be 3- and 1-channel PFMs, "
                         f"got {alpha.shape[2]} and {beta.shape[2]}")
    return alpha, beta[..., 0], names[0]


def _region_maps(fileset: ET.Element, blob, slot: str, exact: tuple | None) -> tuple[np.ndarray, np.ndarray, bool, str]:
    """A region's (alpha (h, w, 3), beta (h, w)) float32, whether they came from the exact maps,
    and the file to name in messages."""
    a_e, b_e = fileset.find("alphaMap"), fileset.find("betaMap")
    alpha = beta = None
    a_levels = b_levels = None
    plain16 = True          # both maps 16-bit, linear, alpha RGB: what the exact maps quantise to
    name = ""
    if a_e is not None:
        a_levels, alpha, bits, gamma, name = _standard_map(a_e, blob, "alpha map", slot)
        plain16 &= bits == 16 and gamma == 1.0 and alpha.shape[2] == 3
        if alpha.shape[2] == 1:
            alpha = np.repeat(alpha, 3, axis=2)
    if b_e is not None:
        b_levels, beta, bits, _, b_name = _standard_map(b_e, blob, "beta map", slot)
        name = name or b_name
        plain16 &= bits == 16 and b_levels.shape[2] == 1
        if beta.shape[2] == 3:
            if not (np.array_equal(beta[..., 0], beta[..., 1]) and np.array_equal(beta[..., 0], beta[..., 2])):
                raise ValueError(f"{b_name}: a beta map with a different offset per channel; shadowless's black "
                                 "offset is one value a texel (give a grey map)")
        beta = beta[..., 0]
    if alpha is None:
        alpha = np.ones(beta.shape + (3,), np.float32)
    if beta is None:
        beta = np.zeros(alpha.shape[:2], np.float32)
    if alpha.shape[:2] != beta.shape:
        raise ValueError(f"{name}: the alpha map of region {slot} is {alpha.shape[1]}x{alpha.shape[0]} texels, its beta "
                         f"map {beta.shape[1]}x{beta.shape[0]}: shadowless needs both on one grid")
    if exact is not None and a_levels is not None and b_levels is not None and plain16:
        ex_a, ex_b, _ = exact
        if (ex_a.shape == alpha.shape and ex_b.shape == beta.shape and np.all(np.isfinite(ex_a))
                and np.all(np.isfinite(ex_b)) and np.array_equal(quantize(np.clip(ex_a, 0, 1)), a_levels)
                and np.array_equal(quantize(np.clip(ex_b, 0, 1)), b_levels[..., 0])):
            return ex_a, ex_b, True, name
    return alpha, beta, False, name


def read_blend(root: ET.Element, ext: ET.Element | None, blob: Callable[[str], bytes],
               frames: Mapping[str, tuple[int, int]]) -> tuple[dict[str, BlendMaps], dict, bool]:
    """The blend an archive carries: ``({slot: BlendMaps}, info, exact)``; ``({}, {}, True)`` when
    it has none. ``frames`` gives each region's (and extension slot's) output size in pixels, which
    no map may exceed; ``exact`` says every map came from the extension's float32 maps. Raises
    ValueError (one line naming the file) for a malformed map."""
    exact_e = {e.get("slot"): e for e in ext.findall("blendMaps")} if ext is not None else {}
    info: dict = {}
    if ext is not None and ext.find("blend") is not None:
        try:
            info = json.loads(ext.find("blend").text or "{}")
        except ValueError:
            raise ValueError("the shadowless extension's blend figures are not JSON") from None
        if not isinstance(info, dict):
            raise ValueError("the shadowless extension's blend figures are not a JSON object")
    maps: dict[str, BlendMaps] = {}
    all_exact = True
    seen = set()
    for fileset in root.findall("files/fileset"):
        slot = fileset.get("region") or ""
        if fileset.find("alphaMap") is None and fileset.find("betaMap") is None:
            continue
        ex = _exact_maps(exact_e[slot], blob) if slot in exact_e else None
        alpha, beta, was_exact, name = _region_maps(fileset, blob, slot, ex)
        maps[slot] = _checked(slot, alpha, beta, name, frames)
        all_exact &= was_exact
        seen.add(slot)
    for slot, e in exact_e.items():
        if slot in seen:
            continue
        alpha, beta, name = _exact_maps(e, blob)
        maps[slot] = _checked(slot, alpha, beta, name, frames)
    return maps, (info if maps else {}), all_exact


def _checked(slot: str, alpha: np.ndarray, beta: np.ndarray, name: str, frames: Mapping[str, tuple[int, int]]) -> BlendMaps:
    frame = frames.get(slot)
    if frame is None:
        raise ValueError(f"{name}: blend maps for {slot!r}, which is neither a region nor a slot of the archive")
    h, w = beta.shape
    if w > frame[0] or h > frame[1]:
        raise ValueError(f"{name}: the blend maps of {slot} are {w}x{h} texels, larger than its {frame[0]}x{frame[1]} "
                         "px frame")
    try:
        return BlendMaps(alpha, beta)
    except BlendMapError as exc:
        raise ValueError(f"{name}: {exc}") from None
