"""Export a rig's geometry to an MPCDI archive, and import it back.

An MPCDI file is a zip archive: ``mpcdi.xml`` describes one display, its buffer (here: the rig's
content) and a region per projector, and names the files of each region. Two profiles fit a rig:

* **2d** for a table (homography poses). Each region is the box of the buffer that its projector
  covers (x, y, xsize, ysize, normalised, origin top-left), and its geometry warp file, a PFM of
  (u, v, 0) samples, gives for a grid over the projector's frame the point of that box it shows
  (normalised within the box, v down; NaN where the projector shows no content). Sample
  ``(i, j)`` of a ``gw`` x ``gh`` grid stands for the projector point
  ``((i + 0.5) W / gw - 0.5, (j + 0.5) H / gh - 0.5)`` in pixels (texel centres, as a linear
  texture lookup of the warp reads it); PFM rows are stored bottom-up.
* **sl** (shader lamp) for an object (projection poses): each region has its projector's frustum
  and coordinateFrame (see :mod:`rigctl.mpcdi.frustum`); the object's mesh travels as an OBJ.

What MPCDI cannot carry exactly (the poses at full precision, 3x4 matrices with skew, the node's
gain and inverse-response LUT, the mesh) goes into an extension, ``shadowless``, that other tools
ignore and :func:`import_mpcdi` prefers: the round trip is exact.

A rig with a stored blend also gets each region's alphaMap and betaMap (16-bit PNGs) and the
float32 maps in the extension (:mod:`rigctl.mpcdi.blend_maps`); a rig without one is written as
before.
"""
from __future__ import annotations

import datetime as _dt
import math
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence
from xml.etree import ElementTree as ET

import numpy as np

from rigctl.mpcdi.blend_maps import read_blend, write_blend
from rigctl.mpcdi.frustum import Frustum, from_frustum, to_frustum
from rigctl.mpcdi.pfm import decode_pfm, encode_pfm
from coordinator.blend_store import StoredBlend
from coordinator.rig import HomographyPose, Mesh, ProjectionPose, SlotState
from protos.blend import BlendMaps
from protos.mesh_files import MeshFileError, format_obj, parse_mesh

EXTENSION = "shadowless"
#: warp samples per projector: one every this many pixels each way
WARP_STEP = 8


@dataclass(frozen=True)
class ImportedRig:
    """What an MPCDI archive says about a rig."""

    name: str
    content_size: tuple[int, int]
    slots: tuple[SlotState, ...]
    profile: str
    exact: bool            # poses read from the shadowless extension (else fitted from the standard data)
    #: sl regions read without the extension: their (3, 4) matrices (normalised); the mesh they
    #: render is not part of standard MPCDI, so these slots carry no pose
    projections: tuple[tuple[str, np.ndarray], ...] = ()
    #: the blend maps the archive carries, by slot (empty: none), the blend's figures, and whether
    #: every map came from the extension's float32 maps (else from the standard PNGs' levels)
    blend: dict[str, BlendMaps] = field(default_factory=dict)
    blend_info: dict = field(default_factory=dict)
    blend_exact: bool = True


def _num(x: float) -> str:
    return repr(float(x))   # shortest text that reads back as the same double


def _sub(parent: ET.Element, tag: str, text: str | None = None, **attrs: str) -> ET.Element:
    e = ET.SubElement(parent, tag, {k: str(v) for k, v in attrs.items()})
    if text is not None:
        e.text = text
    return e


def _warp_grid(width: int, height: int, step: int) -> tuple[np.ndarray, np.ndarray]:
    """Projector pixel coordinates (gh, gw) of the warp samples (texel centres of the grid)."""
    gw, gh = max(2, math.ceil(width / step)), max(2, math.ceil(height / step))
    xs = (np.arange(gw) + 0.5) * width / gw - 0.5
    ys = (np.arange(gh) + 0.5) * height / gh - 0.5
    return np.meshgrid(xs, ys)


def _content_points(h: np.ndarray, width: int, height: int, content_size: tuple[int, int],
                    step: int) -> np.ndarray:
    """(gh, gw, 2) content pixels shown at the warp samples (NaN beyond the horizon or outside)."""
    px, py = _warp_grid(width, height, step)
    inv = np.linalg.inv(h)
    cw, ch = content_size
    if (h @ np.array([(cw - 1) / 2.0, (ch - 1) / 2.0, 1.0]))[2] < 0:
        inv = -inv
    q = np.einsum("ij,jhw->ihw", inv, np.stack([px, py, np.ones_like(px)]))
    with np.errstate(divide="ignore", invalid="ignore"):
        x, y = q[0] / q[2], q[1] / q[2]
    outside = (q[2] <= 0) | ~(x >= -0.5) | ~(x <= cw - 0.5) | ~(y >= -0.5) | ~(y <= ch - 0.5)
    pts = np.stack([x, y], axis=-1)
    pts[outside] = np.nan
    return pts


def _region_box(pts: np.ndarray, content_size: tuple[int, int]) -> tuple[float, float, float, float]:
    """The normalised box (x, y, xsize, ysize) of the content a projector covers (whole buffer if none)."""
    cw, ch = content_size
    ok = np.isfinite(pts[..., 0])
    if not ok.any():
        return 0.0, 0.0, 1.0, 1.0
    u = (pts[..., 0][ok] + 0.5) / cw
    v = (pts[..., 1][ok] + 0.5) / ch
    x0, x1 = float(np.clip(u.min(), 0, 1)), float(np.clip(u.max(), 0, 1))
    y0, y1 = float(np.clip(v.min(), 0, 1)), float(np.clip(v.max(), 0, 1))
    return x0, y0, max(x1 - x0, 1e-6), max(y1 - y0, 1e-6)


def export_mpcdi(path: str | Path, *, rig_name: str, content_size: tuple[int, int], slots: Sequence[SlotState],
                 warp_step: int = WARP_STEP, blend: StoredBlend | None = None) -> str:
    """Write the rig's geometry (and, in the extension, gains, LUTs and exact poses) to ``path``.

    ``slots`` are the rig's slot states; slots without a pose are listed in the extension only.
    ``blend``: the rig's stored blend; its maps for these slots go into the regions' alphaMap and
    betaMap and the extension.
    Returns the profile written ("2d" or "sl"). ValueError if the poses mix tables and objects.
    """
    posed = [s for s in slots if s.pose is not None]
    kinds = {s.pose.kind for s in posed}
    if len(kinds) > 1:
        raise ValueError("the rig mixes homography and projection poses; MPCDI describes one profile per file")
    profile = "sl" if kinds == {"projection"} else "2d"
    cw, ch = content_size
    root = ET.Element("MPCDI", profile=profile, geometry="1", version="2.0",
                      date=_dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M:%S"))
    buffer = _sub(_sub(root, "display"), "buffer", id=rig_name, Xresolution=str(cw), Yresolution=str(ch))
    files = _sub(root, "files")
    ext = _sub(_sub(root, "extensionSet"), "extension", Name=EXTENSION, hasExternalFiles="true")
    _sub(ext, "contentSize", width=str(cw), height=str(ch))
    blobs: dict[str, bytes] = {}
    meshes: dict[str, str] = {}
    for s in slots:
        xs = _sub(ext, "slot", id=s.name, width=str(s.width), height=str(s.height), gain=_num(s.gain))
        if s.lut is not None:
            blobs[f"{s.name}.lut.pfm"] = encode_pfm(np.asarray(s.lut, np.float32))
            _sub(xs, "lut", path=f"{s.name}.lut.pfm")
        if s.pose is None:
            continue
        _sub(xs, "pose", " ".join(_num(v) for v in s.pose.matrix.ravel()), kind=s.pose.kind)
        if isinstance(s.pose, HomographyPose):
            pts = _content_points(s.pose.matrix, s.width, s.height, (cw, ch), warp_step)
            x, y, xsize, ysize = _region_box(pts, (cw, ch))
            _sub(buffer, "region", id=s.name, Xresolution=str(s.width), Yresolution=str(s.height),
                 x=_num(x), y=_num(y), xsize=_num(xsize), ysize=_num(ysize))
            warp = np.full(pts.shape[:2] + (3,), np.nan, np.float32)
            warp[..., 0] = ((pts[..., 0] + 0.5) / cw - x) / xsize
            warp[..., 1] = ((pts[..., 1] + 0.5) / ch - y) / ysize
            warp[..., 2] = np.where(np.isfinite(pts[..., 0]), 0.0, np.nan)
            blobs[f"{s.name}.pfm"] = encode_pfm(warp)
            gwf = _sub(_sub(files, "fileset", region=s.name), "geometryWarpFile")
            _sub(gwf, "path", f"{s.name}.pfm")
            _sub(gwf, "interpolation", "linear")
            _sub(gwf, "componentDepth", "2")
            _sub(gwf, "bitDepth", "32")
            _sub(gwf, "originOf2DData", "topLeft")
        else:
            pose: ProjectionPose = s.pose
            f = to_frustum(pose.matrix, s.width, s.height)
            region = _sub(buffer, "region", id=s.name, Xresolution=str(s.width), Yresolution=str(s.height),
                          x="0", y="0", xsize="1", ysize="1")
            fr = _sub(region, "frustum")
            for tag, val in (("yaw", f.yaw), ("pitch", f.pitch), ("roll", f.roll), ("rightAngle", f.right),
                             ("leftAngle", f.left), ("upAngle", f.up), ("downAngle", f.down)):
                _sub(fr, tag, _num(val))
            cf = _sub(region, "coordinateFrame")
            axes = (("posx", f.position_m[0]), ("posy", f.position_m[1]), ("posz", f.position_m[2]),
                    ("yawx", 0), ("yawy", 0), ("yawz", -1), ("pitchx", 1), ("pitchy", 0), ("pitchz", 0),
                    ("rollx", 0), ("rolly", 1), ("rollz", 0))
            for tag, val in axes:
                _sub(cf, tag, _num(val))
            if abs(f.skew) > 1e-9:
                _sub(xs, "note", f"skew {f.skew!r} is not expressible in the frustum; the pose above is exact")
            if pose.mesh.mesh_id not in meshes:
                meshes[pose.mesh.mesh_id] = f"{pose.mesh.mesh_id}.obj"
                blobs[meshes[pose.mesh.mesh_id]] = format_obj(pose.mesh.vertices, pose.mesh.faces, pose.mesh.uvs,
                                                              exact=True).encode()
            _sub(xs, "mesh", id=pose.mesh.mesh_id, path=meshes[pose.mesh.mesh_id], near=_num(pose.near_mm),
                 far=_num(pose.far_mm))
    if blend is not None and blend.maps:
        names = {s.name for s in slots}
        write_blend(root, ext, blobs, {k: v for k, v in blend.maps.items() if k in names}, blend.info,
                    {s.name for s in posed})
    ET.indent(root)
    xml = b'<?xml version="1.0" encoding="utf-8"?>\n' + ET.tostring(root, encoding="utf-8")
    tmp = Path(path).with_name(Path(path).name + ".partial")
    with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("mpcdi.xml", xml)
        for name, data in blobs.items():
            z.writestr(name, data)
    tmp.replace(path)
    return profile


def _fit_homography(warp: np.ndarray, box: tuple[float, float, float, float], width: int, height: int,
                    content_size: tuple[int, int]) -> np.ndarray:
    """A homography (content px -> projector px) fitted to a 2d region's warp samples."""
    import cv2  # the coordinator's stack

    gh, gw = warp.shape[:2]
    step_x, step_y = width / gw, height / gh
    px, py = np.meshgrid((np.arange(gw) + 0.5) * step_x - 0.5, (np.arange(gh) + 0.5) * step_y - 0.5)
    x, y, xsize, ysize = box
    cw, ch = content_size
    cx = (x + warp[..., 0] * xsize) * cw - 0.5
    cy = (y + warp[..., 1] * ysize) * ch - 0.5
    ok = np.isfinite(cx) & np.isfinite(cy)
    if ok.sum() < 4:
        raise ValueError("the warp file has fewer than 4 samples on the content")
    h, _ = cv2.findHomography(np.stack([cx[ok], cy[ok]], 1), np.stack([px[ok], py[ok]], 1), 0)
    if h is None:
        raise ValueError("no homography fits the warp file")
    return h


def import_mpcdi(path: str | Path) -> ImportedRig:
    """Read an MPCDI archive: exact poses, gains and LUTs from the shadowless extension when it
    is there, else from the standard data (2d warps fitted with a homography; sl frusta)."""
    p = Path(path)
    try:
        z = zipfile.ZipFile(p)
    except (OSError, zipfile.BadZipFile) as exc:
        raise ValueError(f"{p}: not an MPCDI archive (a zip file): {exc}") from None
    with z:
        try:
            return _read_archive(z, p)
        except (TypeError, AttributeError, KeyError, IndexError) as exc:   # a missing attribute or element
            raise ValueError(f"{p}: malformed mpcdi.xml ({type(exc).__name__}: {exc})") from None
        except ValueError as exc:
            raise ValueError(str(exc) if str(p) in str(exc) else f"{p}: {exc}") from None


def _read_archive(z: zipfile.ZipFile, p: Path) -> ImportedRig:
    """The rig in archive ``z`` (``p`` its path, for messages)."""
    try:
        root = ET.fromstring(z.read("mpcdi.xml"))
    except KeyError:
        raise ValueError(f"{p}: the archive has no mpcdi.xml") from None
    except ET.ParseError as exc:
        raise ValueError(f"{p}: mpcdi.xml is not valid XML: {exc}") from None

    def blob(name: str) -> bytes:
        try:
            return z.read(name)
        except KeyError:
            raise ValueError(f"{p}: mpcdi.xml names {name}, which the archive lacks") from None

    profile = root.get("profile", "")
    buffer = root.find("display/buffer")
    if buffer is None:
        raise ValueError(f"{p}: mpcdi.xml has no display/buffer")
    name = buffer.get("id", "rig")
    regions = {r.get("id"): r for r in buffer.findall("region")}
    ext = next((e for e in root.findall("extensionSet/extension") if e.get("Name") == EXTENSION), None)
    if ext is not None and ext.find("contentSize") is not None:
        cs = ext.find("contentSize")
        content = (int(cs.get("width")), int(cs.get("height")))
    else:
        content = (int(buffer.get("Xresolution")), int(buffer.get("Yresolution")))
    slots: list[SlotState] = []
    projections: list[tuple[str, np.ndarray]] = []
    frames = {sid: (int(r.get("Xresolution")), int(r.get("Yresolution"))) for sid, r in regions.items()}
    if ext is not None:
        frames.update({xs.get("id"): (int(xs.get("width")), int(xs.get("height"))) for xs in ext.findall("slot")})
    maps, info, maps_exact = read_blend(root, ext, blob, frames)
    blend = {"blend": maps, "blend_info": info, "blend_exact": maps_exact}
    if ext is not None:
        meshes: dict[str, Mesh] = {}
        for xs in ext.findall("slot"):
            sid, w, h = xs.get("id"), int(xs.get("width")), int(xs.get("height"))
            lut_e = xs.find("lut")
            lut = decode_pfm(blob(lut_e.get("path")), name=lut_e.get("path"))[:, :, 0] if lut_e is not None else None
            pose = None
            pe = xs.find("pose")
            if pe is not None:
                m = np.array([float(t) for t in pe.text.split()], np.float64)
                if pe.get("kind") == "homography":
                    pose = HomographyPose(m.reshape(3, 3))
                else:
                    me = xs.find("mesh")
                    mid = me.get("id")
                    if mid not in meshes:
                        try:
                            arrays = parse_mesh(blob(me.get("path")), ".obj")
                        except MeshFileError as exc:
                            raise ValueError(f"{p}: {me.get('path')}: {exc}") from None
                        meshes[mid] = Mesh(mid, arrays.vertices, arrays.uvs, arrays.faces)
                    pose = ProjectionPose(m.reshape(3, 4), meshes[mid], float(me.get("near")), float(me.get("far")))
            slots.append(SlotState(name=sid, width=w, height=h, gain=float(xs.get("gain", "1")), pose=pose,
                                   lut=lut, source="mpcdi"))
        return ImportedRig(name, content, tuple(slots), profile, exact=True, **blend)
    for sid, r in regions.items():
        w, h = int(r.get("Xresolution")), int(r.get("Yresolution"))
        if profile == "2d":
            fs = root.find(f"files/fileset[@region='{sid}']/geometryWarpFile/path")
            if fs is None:
                raise ValueError(f"{p}: region {sid} has no geometry warp file")
            warp = decode_pfm(blob(fs.text), name=fs.text)
            box = tuple(float(r.get(k)) for k in ("x", "y", "xsize", "ysize"))
            pose = HomographyPose(_fit_homography(warp, box, w, h, content))
            slots.append(SlotState(name=sid, width=w, height=h, pose=pose, source="mpcdi"))
        else:
            fr, cf = r.find("frustum"), r.find("coordinateFrame")
            if fr is None or cf is None:
                raise ValueError(f"{p}: region {sid} has no frustum or coordinateFrame")
            val = lambda e, tag: float(e.find(tag).text)  # noqa: E731
            f = Frustum(val(fr, "yaw"), val(fr, "pitch"), val(fr, "roll"), val(fr, "leftAngle"),
                        val(fr, "rightAngle"), val(fr, "upAngle"), val(fr, "downAngle"),
                        (val(cf, "posx"), val(cf, "posy"), val(cf, "posz")))
            slots.append(SlotState(name=sid, width=w, height=h, source="mpcdi"))
            projections.append((sid, from_frustum(f, w, h)))
    return ImportedRig(name, content, tuple(slots), profile, exact=False, projections=tuple(projections), **blend)
