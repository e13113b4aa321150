"""The console's pictures: what the jobs left in the rig directory, and the camera's view.

* ``GET /api/pictures``: what exists, as JSON: the alignment heat maps (``calibration/
  alignment.json``: extent, frame, per-slot residuals, projector outlines in table mm, the
  figure's layout) and the compensation quality picture with its PSNR/SSIM (``compensation/
  quality.json``) and the coverage heat map with its per-slot summary (``coverage/coverage.json``),
  each with its file's modification time; the stored blend's figures (``blend/``: headroom,
  its brightness cost, uniformity before and after; :mod:`coordinator.console.blend_view`); whether
  a camera is configured; the
  current job (the page refreshes a picture when its file changes, and leaves the camera alone
  while a job runs).
* ``GET /api/pictures/alignment.png`` (``alignment-mesh.png`` for a rig with planar and 3D
  poses), ``/api/pictures/compensation.png`` and ``/api/pictures/coverage.png`` (how many
  projectors reach each point of the object, ``shadowless coverage``) and ``/api/pictures/blend.png``
  (the blend's before/after ratio pictures with a colour bar, drawn once per stored blend): never cached;
  404 with what to run when there is none yet. The alignment figure (colour bar, axes, outlines) is served when the
  job drew one, else the bare map (an older run).
* ``GET /api/camera.png``: one frame of the rig's first camera (``rig.toml`` ``cameras`` or the
  coordinator's ``--camera``), at most one capture per :data:`CAMERA_INTERVAL_S` (the last frame,
  or its error, is served in between), at most :data:`CAMERA_MAX_WIDTH` px wide (the capture's own
  size is ``camera.size`` in the listing and ``X-Capture-Size``, for the page's point picking); 404 without a
  camera, 409 while a job runs (jobs own the camera), 503 when the camera fails.

Only file names known here are ever read, from the rig directory (the paths in the jobs' JSON
are not trusted). The camera is opened for each capture and closed after it, in a worker
thread, so the event loop never waits and a job finds the device free.
"""
from __future__ import annotations

import asyncio
import json
import logging
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from aiohttp import web

from coordinator.camera import CameraError, RoomCamera, open_camera, parse_spec
from coordinator.console.blend_view import NO_BLEND, BlendView

if TYPE_CHECKING:  # pragma: no cover - types only
    from coordinator.console.auth import Session
    from coordinator.ports import ConsoleRig

log = logging.getLogger(__name__)

#: at most one camera capture this often (seconds); requests in between get the last frame
CAMERA_INTERVAL_S = 2.0
#: the camera view's largest width (px); larger captures are scaled down
CAMERA_MAX_WIDTH = 960
#: how long a room camera's capture may take (seconds)
CAMERA_TIMEOUT_S = 10.0

#: the alignment heat maps the console serves, by route name: (map index in alignment.json, bare map file)
ALIGNMENT_ROUTES = {"alignment.png": (0, "alignment.png"), "alignment-mesh.png": (1, "alignment-mesh.png")}
#: every file of calibration/ the console may read
ALIGNMENT_FILES = {"alignment.png", "alignment-mesh.png", "alignment-figure.png", "alignment-mesh-figure.png"}
NO_ALIGNMENT = ("no alignment heat map in this rig yet: run the alignment job (Jobs: alignment here, or "
                "`shadowless alignment`) after calibrating")
NO_COMPENSATION = ("no compensation quality picture in this rig yet: run the compensate job with evaluate "
                   "(`shadowless compensate IMAGE --evaluate`)")
NO_COVERAGE = ("no coverage picture in this rig yet: run `shadowless coverage --rig-dir DIR` on a rig calibrated "
               "onto a mesh")
#: the figures of coverage.json the page shows (the rest is for scripts)
COVERAGE_KEYS = ("slots", "surface_mm2", "lit_pct", "count_mean", "count_min", "count_p5", "count_median",
                 "effective_mean", "max_share_mean_pct", "count_area_mm2", "views", "mesh", "texture")
COVERAGE_SLOT_KEYS = ("reach_mm2", "reach_pct", "reach_pct_of_lit", "mean_share_pct", "sole_mm2")


def _error(cls: type[web.HTTPException], message: str, **kw) -> web.HTTPException:
    return cls(text=json.dumps({"ok": False, "error": message}), content_type="application/json", **kw)


def _finite(x: Any) -> Any:
    """A JSON document with every NaN or infinity replaced by None (the browser's JSON has none)."""
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, dict):
        return {str(k): _finite(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_finite(v) for v in x]
    return x


def _read_json(path: Path) -> tuple[dict | None, str | None]:
    """(document, None), (None, None) when missing, (None, why) when unreadable."""
    try:
        doc = json.loads(path.read_text())
    except FileNotFoundError:
        return None, None
    except (OSError, ValueError) as exc:
        return None, f"{path.name} cannot be read ({exc})"
    return (doc, None) if isinstance(doc, dict) else (None, f"{path.name} is not a JSON object")


def _mtime(path: Path) -> float | None:
    try:
        return round(path.stat().st_mtime, 3)
    except OSError:
        return None


# ---------------------------------------------------------------------- what the jobs left
def alignment_file(rig_dir: Path, route: str) -> Path | None:
    """The file served as ``/api/pictures/<route>``: the job's figure, else its bare map; None if neither."""
    index, bare = ALIGNMENT_ROUTES[route]
    cdir = Path(rig_dir) / "calibration"
    doc, _ = _read_json(cdir / "alignment.json")
    maps = doc.get("heatmaps") if doc else None
    names = []
    if isinstance(maps, list) and len(maps) > index and isinstance(maps[index], dict):
        names = [Path(str(maps[index].get(k) or "")).name for k in ("figure", "file")]
    elif index == 0:
        names = [bare]
    for name in names:
        if name in ALIGNMENT_FILES and (cdir / name).is_file():
            return cdir / name
    return None


def describe_alignment(rig_dir: Path) -> dict | None:
    """The last alignment check: figures per slot and per map, or None when there is none."""
    cdir = Path(rig_dir) / "calibration"
    doc, problem = _read_json(cdir / "alignment.json")
    if doc is None:
        if problem is None and not (cdir / "alignment.png").is_file():
            return None
        doc = {"heatmaps": [{"file": "alignment.png", "frame": "table mm"}]}
    keep = ("dots", "planned", "rms_px", "p95_px", "max_px", "mean_offset_px", "worst_at_mm", "worst_at_camera_px",
            "note")
    slots = {s: {k: d[k] for k in keep if k in d} for s, d in (doc.get("slots") or {}).items() if isinstance(d, dict)}
    maps = []
    for route, (index, _) in ALIGNMENT_ROUTES.items():
        entries = doc.get("heatmaps") or []
        if index >= len(entries) or not isinstance(entries[index], dict):
            continue
        served = alignment_file(rig_dir, route)
        if served is None:
            continue
        e = entries[index]
        modified = _mtime(served)
        maps.append({"name": route, "url": f"/api/pictures/{route}?v={modified}", "modified": modified,
                     "annotated": served.name.endswith("-figure.png"), "frame": e.get("frame"),
                     "extent": e.get("extent"), "peak_at": e.get("peak_at"), "layout": e.get("figure_layout"),
                     "outlines": e.get("outlines") or {}, "pixel_mm": e.get("pixel_mm") or {}})
    if not maps:
        return None
    return {"checked_at": doc.get("checked_at"), "worst_slot": doc.get("worst_slot"),
            "worst_rms_px": doc.get("worst_rms_px"), "full_scale_px": doc.get("heatmap_full_scale_px"),
            "skipped": doc.get("skipped") or [], "slots": slots, "maps": maps, "problem": problem}


def describe_compensation(rig_dir: Path) -> dict | None:
    """The last compensation evaluation: PSNR/SSIM of each result and its picture, or None."""
    cdir = Path(rig_dir) / "compensation"
    png = cdir / "quality.png"
    modified = _mtime(png)
    if modified is None:
        return None
    doc, problem = _read_json(cdir / "quality.json")
    doc = doc or {}
    scores = {k: doc[k] for k in ("none", "baseline", "ours") if isinstance(doc.get(k), dict)}
    return {"url": f"/api/pictures/compensation.png?v={modified}", "modified": modified, "image": doc.get("image"),
            "finished_at": doc.get("finished_at"), "scores": scores, "predicted": doc.get("predicted"),
            "ordering": doc.get("ordering"), "captures_averaged": doc.get("captures_averaged"), "problem": problem}


def describe_coverage(rig_dir: Path) -> dict | None:
    """The last coverage computation: its picture, the count over the surface and each slot's reach,
    or None when there is none. The picture is ``coverage/coverage.png`` (a picture written
    elsewhere with ``--out`` is not the rig's and is not served)."""
    cdir = Path(rig_dir) / "coverage"
    modified = _mtime(cdir / "coverage.png")
    if modified is None:
        return None
    doc, problem = _read_json(cdir / "coverage.json")
    doc = doc or {}
    per_slot = doc.get("per_slot") if isinstance(doc.get("per_slot"), dict) else {}
    slots = {str(s): {k: d.get(k) for k in COVERAGE_SLOT_KEYS} for s, d in per_slot.items() if isinstance(d, dict)}
    return {"url": f"/api/pictures/coverage.png?v={modified}", "modified": modified,
            "computed_at": doc.get("computed_at"), **{k: doc.get(k) for k in COVERAGE_KEYS},
            "per_slot": slots, "problem": problem}


# ---------------------------------------------------------------------- the camera
def to_srgb(linear: np.ndarray) -> np.ndarray:
    """sRGB encoding of linear values in [0, 1] (same shape, float32)."""
    x = np.clip(np.asarray(linear, np.float32), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055).astype(np.float32)


def view_png(image: np.ndarray, *, srgb: bool, max_width: int = CAMERA_MAX_WIDTH) -> bytes:
    """PNG bytes (8-bit) of a capture, (H, W, 3) float32 RGB in [0, 1], scaled down to ``max_width``;
    ``srgb``: the capture is linear (the virtual room's), encode it for display."""
    import cv2  # the coordinator's stack

    img = np.asarray(image, np.float32)
    h, w = img.shape[:2]
    if w > max_width:
        img = cv2.resize(img, (max_width, max(1, round(h * max_width / w))), interpolation=cv2.INTER_AREA)
    if srgb:
        img = to_srgb(img)
    out = np.clip(np.rint(img * 255.0), 0, 255).astype(np.uint8)
    ok, buf = cv2.imencode(".png", cv2.cvtColor(out, cv2.COLOR_RGB2BGR))
    if not ok:  # pragma: no cover
        raise CameraError("cannot encode the camera view")
    return buf.tobytes()


def capture_view(spec: str) -> tuple[bytes, tuple[int, int]]:
    """Open the camera ``spec`` names, capture one frame, close it; the frame as :func:`view_png`
    and the capture's own (width, height) in camera px, before any scaling (blocking)."""
    parsed = parse_spec(spec)
    cam = RoomCamera(parsed, timeout_s=CAMERA_TIMEOUT_S) if parsed.kind == "room" else open_camera(spec)
    try:
        image = cam.capture()
    finally:
        cam.close()
    return view_png(image, srgb=parsed.kind == "room"), (int(image.shape[1]), int(image.shape[0]))


@dataclass
class _Frame:
    spec: str
    at: float                   # monotonic, when the capture ended (the next one waits the interval from here)
    wall: float                 # unix time of the same
    png: bytes | None
    error: str | None
    size: tuple[int, int] | None = None     # the capture's (width, height) in camera px, before scaling


class Pictures:
    """The handlers (``app.py`` wires them behind the session check)."""

    def __init__(self, coord: "ConsoleRig", *, camera_interval_s: float = CAMERA_INTERVAL_S):
        self.coord = coord
        self.camera_interval_s = camera_interval_s
        self.captures = 0                       # camera captures attempted (tests, benchmarks)
        self._last: _Frame | None = None
        self._camera_lock = asyncio.Lock()
        self.blend = BlendView()

    def _job(self) -> dict | None:
        job = self.coord.current_job()
        if job is None:
            return None
        return {"kind": job.kind, "state": job.state, "started": round(job.started, 3),
                "ended": round(job.ended, 3) if math.isfinite(job.ended) else None}

    async def listing(self, request: web.Request, session: "Session") -> web.Response:
        rig_dir = Path(self.coord.rig.path)
        alignment, compensation, coverage, blend = await asyncio.to_thread(
            lambda: (describe_alignment(rig_dir), describe_compensation(rig_dir), describe_coverage(rig_dir),
                     self.blend.describe(rig_dir)))
        specs = self.coord.camera_specs
        last = self._last
        doc = {"ok": True, "alignment": alignment, "compensation": compensation, "coverage": coverage, "blend": blend,
               "camera": {"configured": bool(specs), "spec": specs[0] if specs else None, "url": "/api/camera.png",
                          "interval_s": self.camera_interval_s,
                          "captured_at": round(last.wall, 3) if last is not None and last.png else None,
                          "size": list(last.size) if last is not None and last.png and last.size else None},
               "job": self._job()}
        return web.Response(text=json.dumps(_finite(doc), allow_nan=False), content_type="application/json")

    async def picture(self, request: web.Request, session: "Session") -> web.Response:
        name = request.match_info["name"]
        rig_dir = Path(self.coord.rig.path)
        if name in ALIGNMENT_ROUTES:
            path = await asyncio.to_thread(alignment_file, rig_dir, name)
            missing = NO_ALIGNMENT if name == "alignment.png" else \
                "no heat map over the camera image: this rig's last alignment check had no 3D pose beside planar ones"
        elif name == "compensation.png":
            path, missing = rig_dir / "compensation" / "quality.png", NO_COMPENSATION
        elif name == "coverage.png":
            path, missing = rig_dir / "coverage" / "coverage.png", NO_COVERAGE
        elif name == "blend.png":
            png = await asyncio.to_thread(self.blend.png, rig_dir)
            if png is None:
                doc = await asyncio.to_thread(self.blend.describe, rig_dir)
                raise _error(web.HTTPNotFound, (doc or {}).get("problem") or
                             (NO_BLEND if doc is None else "the stored blend has no before/after pictures"))
            return web.Response(body=png, content_type="image/png", headers={"Cache-Control": "no-store"})
        else:
            raise _error(web.HTTPNotFound, f"no picture {name!r}: there are alignment.png, alignment-mesh.png, "
                                           "compensation.png, coverage.png and blend.png")
        try:
            data = await asyncio.to_thread(path.read_bytes) if path is not None else None
        except FileNotFoundError:
            data = None
        if data is None:
            raise _error(web.HTTPNotFound, missing)
        return web.Response(body=data, content_type="image/png", headers={"Cache-Control": "no-store"})

    async def camera(self, request: web.Request, session: "Session") -> web.Response:
        specs = self.coord.camera_specs
        if not specs:
            raise _error(web.HTTPNotFound, "no camera configured: add cameras = [\"room://HOST:PORT\" or "
                                           "\"/dev/video0\"] to rig.toml, or start the coordinator with --camera")
        spec = specs[0]
        async with self._camera_lock:
            kind = self.coord.running_job()
            if kind is not None:
                raise _error(web.HTTPConflict, f"the camera is in use by the running {kind} job: its view comes "
                                               "back when the job ends")
            last, fresh = self._last, False
            if last is None or last.spec != spec or time.monotonic() - last.at >= self.camera_interval_s:
                wall = time.time()
                self.captures += 1
                png, error, size = None, None, None
                try:
                    png, size = await asyncio.to_thread(capture_view, spec)
                except CameraError as exc:
                    error = str(exc)
                except Exception as exc:  # noqa: BLE001 - the operator sees that it failed, the log says why
                    log.exception("console: the camera view failed")
                    error = f"camera {spec}: capture failed ({type(exc).__name__}: {exc}); see the coordinator's log"
                last = self._last = _Frame(spec, time.monotonic(), wall, png, error, size)
                fresh = True
        if last.png is None:
            raise _error(web.HTTPServiceUnavailable, last.error or "the camera delivered nothing",
                         headers={"Retry-After": str(math.ceil(self.camera_interval_s))})
        return web.Response(body=last.png, content_type="image/png",
                            headers={"Cache-Control": "no-store", "X-Captured-At": f"{last.wall:.3f}",
                                     **({"X-Capture-Size": "%dx%d" % last.size} if last.size else {}),
                                     "X-Capture": "fresh" if fresh else "cached"})
