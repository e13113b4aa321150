"""The alignment check: how far each projector's image lands from where its pose says.

Every projector shows, at the same time, a lattice of small dots drawn
*through its current pose* at table sites shared out between the projectors
so that no two dots overlap (the interleaved lattice of
:mod:`coordinator.calibration.multiplex`). The camera measures where each dot
really lands; mapped back through the camera's table mapping and the
projector's pose, that is the projector pixel which actually lit the site's
point, and its distance from the pixel that was drawn is the residual
misalignment in projector pixels (what blurs the synthetic aperture).

For projectors with a 3D pose (a mesh), the sites are points of the object's
surface the camera sees (camera rays cast onto the mesh), each given to one of
the projectors that sees it; a dot's landing point is the surface point under
its camera centroid, and the residual is that point's projection through the
pose minus the drawn pixel.

The result gives per projector the RMS, 95th percentile and maximum residual
and where the worst one is, and a heat map (the largest residual of any
projector at each point) saved as ``calibration/alignment.png`` beside
``calibration/alignment.json``: over the table in the content image's frame
for planar poses, over the camera image for 3D poses
(``alignment-mesh.png`` when a rig has both).
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from coordinator.calibration import multiplex, planar, threed
from coordinator.calibration.errors import CalibrationError
from coordinator.camera import CameraError, CaptureRecorder
from coordinator.jobs import JobError
from coordinator.rig import HomographyPose, ProjectionPose
from coordinator.store import atomic_write_bytes, atomic_write_json

#: Heat-map colour scale: residuals at or above this many projector pixels are full red.
HEATMAP_FULL_SCALE_PX = 1.0

_KNOWN = {"slots", "rounds", "settle_s", "camera", "record", "heatmap_width"}


def residuals(table_to_projector: np.ndarray, table_to_camera: np.ndarray, measured: np.ndarray,
              drawn: np.ndarray) -> np.ndarray:
    """Residual misalignment of dots, in projector pixels.

    Parameters
    ----------
    table_to_projector : (3, 3) float64 the projector's current pose, table mm -> projector px
    table_to_camera : (3, 3) float64
    measured : (M, 2) float64 camera centroids of the dots
    drawn : (M, 2) float64 projector centres the dots were drawn at

    Returns
    -------
    (M, 2) float64: pose(where the dot landed) - drawn
    """
    landed = planar.apply_homography(np.linalg.inv(table_to_camera), measured)
    return planar.apply_homography(table_to_projector, landed) - np.asarray(drawn, np.float64)


def heatmap(points: dict[str, np.ndarray], values: dict[str, np.ndarray], *,
            extent: tuple[float, float, float, float], width: int = 600, step: int = 4) -> np.ndarray:
    """Largest residual of any projector at each point of a rectangle, interpolated between the dots.

    Each projector's residuals are interpolated linearly inside its dots' hull
    (Delaunay, ``scipy.interpolate.LinearNDInterpolator``) and extended with
    the nearest dot's value outside it, on a grid ``step`` times coarser than
    the map (the field is smooth at the dot spacing), then upsampled.

    Parameters
    ----------
    points : dict slot -> (M, 2) positions of the measured dots (table mm, or camera px)
    values : dict slot -> (M,) residual magnitudes (projector px)
    extent : (left, right, top, bottom)
        Coordinates of the map's left and right edges and of its top and bottom
        rows, e.g. ``(-600, 600, 300, -300)`` for a 1200 x 600 mm table seen from
        above (row 0 at +y, like the content image), ``(-0.5, W - 0.5, -0.5, H - 0.5)``
        for a camera image.
    width : int
        Width of the map in pixels (height follows the extent's aspect).

    Returns
    -------
    (h, width) float32; NaN where no projector has dots.
    """
    import cv2
    from scipy.interpolate import LinearNDInterpolator
    from scipy.spatial import QhullError, cKDTree

    left, right, top, bottom = (float(v) for v in extent)
    height = max(2, int(round(width * abs(bottom - top) / abs(right - left))))
    cw, ch = max(2, width // step), max(2, height // step)
    xs = left + (np.arange(cw) + 0.5) / cw * (right - left)
    ys = top + (np.arange(ch) + 0.5) / ch * (bottom - top)
    q = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
    out = np.full(len(q), np.nan, np.float32)
    for slot, pts in points.items():
        v = np.asarray(values[slot], np.float64)
        if len(pts) == 0:
            continue
        grid = v[cKDTree(pts).query(q)[1]]
        if len(pts) >= 3:
            try:
                lin = LinearNDInterpolator(pts, v)(q)
                grid = np.where(np.isfinite(lin), lin, grid)
            except QhullError:   # collinear dots: nearest values only
                pass
        out = np.fmax(out, grid.astype(np.float32))
    coarse = out.reshape(ch, cw)
    up = cv2.resize(np.nan_to_num(coarse, nan=0.0), (width, height), interpolation=cv2.INTER_LINEAR)
    mask = cv2.resize(np.isfinite(coarse).astype(np.uint8), (width, height), interpolation=cv2.INTER_NEAREST) > 0
    return np.where(mask, up, np.nan).astype(np.float32)


def plan_surface_lattice(projectors: dict[str, threed.Pinhole], camera: threed.Pinhole, camera_points: np.ndarray,
                         usable: np.ndarray, projector_points: dict[str, np.ndarray], *, rounds: int = 2,
                         dot_px: int = 3, spacing_px: float | None = None, visible_mm: float = 3.0) -> multiplex.Lattice:
    """Share sites on a 3D surface out between projectors that see them (the alignment pattern for 3D poses).

    Sites are camera pixels on a lattice over the surface the camera sees
    (``usable``); a site belongs, round by round, to one of the projectors whose
    own view of the surface reaches the same point (within ``visible_mm``:
    not hidden by the object), which draws a dot where its pose puts it.

    Parameters
    ----------
    projectors : dict slot -> Pinhole from each projector's current 3x4 pose
    camera : Pinhole of the camera
    camera_points : (H, W, 3) float64 world point per camera pixel (NaN where nothing)
    usable : (H, W) bool camera pixels to put sites on (the object, away from silhouettes)
    projector_points : dict slot -> (h, w, 3) world point each projector pixel lights (NaN: nothing)
    """
    slots = tuple(projectors)
    W, H = camera.size
    # how many camera pixels a projector pixel spans on the surface (focal length over distance, both devices)
    probe = camera_points[usable]
    if len(probe) == 0:
        raise ValueError("the camera sees none of the surface")
    probe = probe[:: max(1, len(probe) // 2000)]
    cam_scale = camera.K[0, 0] / np.maximum(camera.project(probe)[1], 1e-6)
    ratios = [np.median(cam_scale / (d.K[0, 0] / np.maximum(d.project(probe)[1], 1e-6))) for d in projectors.values()]
    dot_cam = dot_px * float(max(ratios))
    radius = int(np.ceil(dot_cam / 2 + 2.5))
    if spacing_px is None:
        spacing_px = max(12.0, 2 * radius + 4.0)
    edge = radius + 3
    # a dot's whole footprint must sit on usable surface (no silhouette or depth step under it)
    from scipy import ndimage

    usable = ndimage.binary_erosion(usable, iterations=radius)
    n = len(slots)
    q = multiplex._lattice_multiplier(n)
    na, nb = int((W - 2 * edge) // spacing_px) + 1, int((H - 2 * edge) // spacing_px) + 1
    a, b = np.meshgrid(np.arange(na), np.arange(nb), indexing="xy")
    a, b = a.ravel(), b.ravel()
    shifts = [(0.0, 0.0), (0.5, 0.5), (0.5, 0.0), (0.0, 0.5)]
    lattice = multiplex.Lattice(slots, {s: projectors[s].size for s in slots}, dot_px, float("nan"), float(spacing_px), radius)
    for r in range(rounds):
        sx, sy = shifts[r % 4]
        px = np.rint(edge + (a + sx) * spacing_px).astype(np.int64)
        py = np.rint(edge + (b + sy) * spacing_px).astype(np.int64)
        ok = (px < W - edge) & (py < H - edge)
        px, py, aa, bb = px[ok], py[ok], a[ok], b[ok]
        on = usable[py, px]
        px, py, aa, bb = px[on], py[on], aa[on], bb[on]
        X = camera_points[py, px]
        # which projectors see each site, and where they would draw it
        sees = np.zeros((len(X), n), bool)
        centres = np.zeros((len(X), n, 2))
        landed = np.full((len(X), n, 3), np.nan)
        for i, s in enumerate(slots):
            dev = projectors[s]
            w, h = dev.size
            c = multiplex.snap_centre(dev.project(X)[0], dot_px)
            half = (dot_px - 1) / 2 + 1
            inside = np.isfinite(c).all(axis=1) & (c[:, 0] >= half) & (c[:, 1] >= half) & (c[:, 0] <= w - 1 - half) & (c[:, 1] <= h - 1 - half)
            ix = np.clip(np.rint(np.nan_to_num(c[:, 0])).astype(np.int64), 0, w - 1)
            iy = np.clip(np.rint(np.nan_to_num(c[:, 1])).astype(np.int64), 0, h - 1)
            hit = projector_points[s][iy, ix]
            # the snapped pixel lights a point up to a pixel's footprint away from the site; farther means hidden
            tol = visible_mm + 1.5 * np.abs(dev.project(X)[1]) / dev.K[0, 0]
            near = inside & np.isfinite(hit).all(axis=1) & (np.linalg.norm(np.nan_to_num(hit, nan=1e9) - X, axis=1) < tol)
            sees[:, i] = near
            centres[:, i] = c
            landed[:, i] = hit
        count = sees.sum(axis=1)
        pick = np.full(len(X), -1)
        for k in np.flatnonzero(count):
            vis = np.flatnonzero(sees[k])
            pick[k] = vis[(aa[k] + q * bb[k] + r * (n // max(rounds, 1) + 1)) % len(vis)]
        rc, re, rs = {}, {}, {}
        for i, s in enumerate(slots):
            sel = pick == i
            e, _ = camera.project(landed[sel, i])
            good = np.isfinite(e).all(axis=1) & (e[:, 0] >= edge) & (e[:, 1] >= edge) & (e[:, 0] < W - edge) & (e[:, 1] < H - edge)
            rc[s], re[s], rs[s] = centres[sel, i][good], e[good], landed[sel, i][good]
        lattice.rounds.append(multiplex.LatticeRound(rc, re, rs))
    return lattice


def sample_points(points: np.ndarray, usable: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Bilinear world points (M, 3) at sub-pixel camera positions ``xy`` (M, 2); NaN unless all four
    neighbouring pixels are ``usable``."""
    H, W = usable.shape
    x, y = xy[:, 0], xy[:, 1]
    x0 = np.floor(x).astype(np.int64)
    y0 = np.floor(y).astype(np.int64)
    ok = (x0 >= 0) & (y0 >= 0) & (x0 < W - 1) & (y0 < H - 1)
    x0, y0 = np.where(ok, x0, 0), np.where(ok, y0, 0)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    for dy in (0, 1):
        for dx in (0, 1):
            ok &= usable[y0 + dy, x0 + dx]
    p = (points[y0, x0] * (1 - fx) * (1 - fy) + points[y0, x0 + 1] * fx * (1 - fy)
         + points[y0 + 1, x0] * (1 - fx) * fy + points[y0 + 1, x0 + 1] * fx * fy)
    p[~ok] = np.nan
    return p


def render_heatmap(values: np.ndarray, *, full_scale: float = HEATMAP_FULL_SCALE_PX) -> bytes:
    """PNG bytes of a heat map: 0 px dark blue ... ``full_scale`` px and more red (OpenCV's TURBO map), NaN grey."""
    import cv2

    v = np.asarray(values, np.float32)
    scaled = np.clip(np.nan_to_num(v, nan=0.0) / full_scale, 0.0, 1.0)
    img = cv2.applyColorMap((scaled * 255).astype(np.uint8), cv2.COLORMAP_TURBO)
    img[~np.isfinite(v)] = (128, 128, 128)
    ok, buf = cv2.imencode(".png", img)
    if not ok:  # pragma: no cover
        raise CalibrationError("cannot encode the heat map")
    return buf.tobytes()


def _load_cameras(rig_dir: Path) -> dict:
    f = rig_dir / "calibration" / "cameras.json"
    try:
        return json.loads(f.read_text())
    except FileNotFoundError:
        raise JobError("no camera calibration in this rig yet (calibration/cameras.json): run `shadowless calibrate` first") from None
    except (OSError, json.JSONDecodeError) as exc:
        raise JobError(f"{f}: cannot read the camera calibration ({exc}); run `shadowless calibrate` again") from exc


def _slot_stats(res: np.ndarray, where: np.ndarray, planned: int, *, where_key: str) -> dict:
    mag = np.linalg.norm(res, axis=1)
    k = int(np.argmax(mag))
    return {"dots": int(len(mag)), "planned": planned, "rms_px": round(float(np.sqrt(np.mean(mag ** 2))), 4),
            "p95_px": round(float(np.percentile(mag, 95)), 4), "max_px": round(float(mag.max()), 4),
            "mean_offset_px": [round(float(v), 4) for v in res.mean(axis=0)],
            where_key: [round(float(v), 1) for v in where[k]]}


async def run_alignment(ctx, params: dict) -> dict:
    """The ``alignment`` job: parameters ``slots``, ``rounds`` (2), ``settle_s`` (0.1), ``camera`` (0),
    ``record`` (folder for the captures), ``heatmap_width`` (600)."""
    unknown = sorted(set(params) - _KNOWN)
    if unknown:
        raise JobError(f"unknown alignment parameter(s) {', '.join(unknown)} (known: {', '.join(sorted(_KNOWN))})")
    t0 = time.monotonic()
    rig = ctx.rig
    rig_dir = Path(rig.path)
    cams = _load_cameras(rig_dir)
    cam = int(params.get("camera", 0))
    entry = next((c for c in cams.get("cameras", []) if c.get("camera") == cam), None)
    if entry is None:
        raise JobError(f"camera {cam} is not in calibration/cameras.json: calibrate with it first")
    table_mm = tuple(cams.get("table_mm", (1200.0, 600.0)))
    content_size = (rig.config.content_width, rig.config.content_height)
    live = ctx.live_slots()
    slots = list(params.get("slots") or live)
    missing = [s for s in slots if s not in live]
    if missing:
        raise JobError(f"projector(s) {', '.join(missing)} not connected: start their nodes (see `shadowless status`)")
    flat = {s: rig.slot(s).pose for s in slots if isinstance(rig.slot(s).pose, HomographyPose)}
    solid = {s: rig.slot(s).pose for s in slots if isinstance(rig.slot(s).pose, ProjectionPose)}
    skipped = [s for s in slots if s not in flat and s not in solid]
    if skipped:
        ctx.log(f"skipped {', '.join(skipped)}: no pose yet (calibrate them first)")
    if not flat and not solid:
        raise JobError("no calibrated projector to check")
    rounds = int(params.get("rounds", 2))
    settle = float(params.get("settle_s", 0.1))
    if not 1 <= rounds <= 16 or not 0 <= settle <= 30:
        raise JobError("rounds must be in 1..16 and settle_s in 0..30")
    camera_size = tuple(entry["size"])
    width = int(params.get("heatmap_width", 600))
    recorder = CaptureRecorder(params["record"]) if params.get("record") else None
    captures = 0

    async def shoot(images, require):
        nonlocal captures
        await ctx.show(images, settle_s=settle, require=require)
        try:
            img = await ctx.capture(cam)
        except CameraError as exc:
            raise JobError(str(exc)) from exc
        captures += 1
        img = np.asarray(img, np.float32)
        if (img.shape[1], img.shape[0]) != camera_size:
            raise JobError(f"camera {cam} delivers {img.shape[1]}x{img.shape[0]} images but was calibrated at "
                           f"{camera_size[0]}x{camera_size[1]}: recalibrate")
        return await ctx.compute(recorder.record, img) if recorder else img

    async def measure(lattice: multiplex.Lattice, stage: str) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Dark + one capture per round, every checked projector at once; camera centroids and drawn centres."""
        sizes = lattice.sizes
        ctx.progress(stage, "", 0, len(lattice.rounds) + 1, "every projector black")
        dark = await shoot({s: np.zeros((sizes[s][1], sizes[s][0]), np.uint8) for s in lattice.slots}, list(lattice.slots))
        found = {s: ([], []) for s in lattice.slots}
        for r in range(len(lattice.rounds)):
            ctx.progress(stage, "", r + 1, len(lattice.rounds) + 1, f"{len(lattice.slots)} projectors at once")
            ms = await ctx.compute(multiplex.measure_lattice, await shoot(lattice.frames(r), list(lattice.slots)), dark, lattice, r)
            for s in lattice.slots:
                found[s][0].append(ms[s].camera)
                found[s][1].append(ms[s].projector)
        return {s: (np.vstack(found[s][0]), np.vstack(found[s][1])) for s in lattice.slots}

    per_slot: dict[str, dict] = {}
    maps: list[tuple[str, np.ndarray, tuple]] = []
    if flat:
        if "table_to_camera" not in entry:
            raise JobError(f"camera {cam} has no table mapping in calibration/cameras.json: calibrate the table first")
        H_t2c = np.array(entry["table_to_camera"], np.float64)
        c2t = planar.content_to_table(content_size, table_mm)
        t2p = {s: p.matrix @ np.linalg.inv(c2t) for s, p in flat.items()}
        try:
            lattice = multiplex.plan_lattice(t2p, H_t2c, sizes={s: ctx.projector_size(s) for s in flat},
                                             camera_size=camera_size, table_mm=table_mm, rounds=rounds)
        except ValueError as exc:
            raise JobError(f"cannot plan the alignment pattern: {exc}") from exc
        found = await measure(lattice, "alignment")
        pts, mags = {}, {}
        for s in flat:
            camxy, drawn = found[s]
            planned = sum(len(r.centres[s]) for r in lattice.rounds)
            if len(camxy) == 0:
                per_slot[s] = _not_found(planned)
                continue
            res = residuals(t2p[s], H_t2c, camxy, drawn)
            at = planar.apply_homography(np.linalg.inv(H_t2c), camxy)
            per_slot[s] = _slot_stats(res, at, planned, where_key="worst_at_mm")
            pts[s], mags[s] = at, np.linalg.norm(res, axis=1)
        tw, th = table_mm
        extent = (-tw / 2, tw / 2, th / 2, -th / 2)
        maps.append(("alignment.png", await ctx.compute(heatmap, pts, mags, extent=extent, width=width), extent))
    if solid:
        if "pinhole" not in entry:
            raise JobError(f"camera {cam} was not posed in 3D (calibration/cameras.json): calibrate the mesh first")
        meshes = {p.mesh.mesh_id for p in solid.values()}
        if len(meshes) > 1:
            raise JobError(f"projectors render different meshes ({', '.join(sorted(meshes))}); calibrate them together")
        mesh = next(iter(solid.values())).mesh
        camera = threed.Pinhole.from_dict(entry["pinhole"])
        devices = {}
        for s, p in solid.items():
            K, R, t = threed.decompose(p.matrix)
            devices[s] = threed.Pinhole(K, R, t, ctx.projector_size(s))

        def cast():
            with threed.SurfaceCaster(threed.MeshData(mesh.vertices, mesh.faces, mesh.uvs)) as caster:
                cp, kind = caster.cast(camera)
                usable = (kind == threed.MESH) & ~threed.edge_mask(cp, kind)
                return cp, usable, {s: caster.cast(d)[0] for s, d in devices.items()}

        try:
            cam_pts, usable, proj_pts = await ctx.compute(cast)
            lattice = await ctx.compute(plan_surface_lattice, devices, camera, cam_pts, usable, proj_pts, rounds=rounds)
        except (CalibrationError, ValueError) as exc:
            raise JobError(f"cannot plan the alignment pattern on the mesh: {exc}") from exc
        found = await measure(lattice, "alignment (mesh)")
        pts, mags = {}, {}
        for s in solid:
            camxy, drawn = found[s]
            planned = sum(len(r.centres[s]) for r in lattice.rounds)
            X = sample_points(cam_pts, usable, camxy) if len(camxy) else np.zeros((0, 3))
            ok = np.isfinite(X).all(axis=1)
            if not ok.any():
                per_slot[s] = _not_found(planned)
                continue
            res = devices[s].project(X[ok])[0] - drawn[ok]
            per_slot[s] = _slot_stats(res, camxy[ok], planned, where_key="worst_at_camera_px")
            pts[s], mags[s] = camxy[ok], np.linalg.norm(res, axis=1)
        W, H = camera_size
        extent = (-0.5, W - 0.5, -0.5, H - 0.5)
        maps.append(("alignment-mesh.png" if flat else "alignment.png",
                     await ctx.compute(heatmap, pts, mags, extent=extent, width=min(width, W)), extent))
    cdir = rig_dir / "calibration"
    worst_slot = max((s for s in per_slot if per_slot[s]["rms_px"] is not None), key=lambda s: per_slot[s]["rms_px"], default=None)
    result = {
        "slots": per_slot, "skipped": skipped, "worst_slot": worst_slot,
        "worst_rms_px": per_slot[worst_slot]["rms_px"] if worst_slot else None,
        "heatmap_full_scale_px": HEATMAP_FULL_SCALE_PX, "captures": captures, "wall_s": round(time.monotonic() - t0, 3),
        "checked_at": time.time(), "heatmaps": [],
    }
    for name, hm, extent in maps:
        atomic_write_bytes(cdir / name, render_heatmap(hm))
        entry_map = {"file": str(cdir / name), "frame": "table mm" if name == "alignment.png" and flat else "camera px"}
        if np.isfinite(hm).any():
            iy, ix = np.unravel_index(int(np.nanargmax(hm)), hm.shape)
            left, right, top, bottom = extent
            entry_map["peak_at"] = [round(left + (ix + 0.5) / hm.shape[1] * (right - left), 1),
                                    round(top + (iy + 0.5) / hm.shape[0] * (bottom - top), 1)]
        result["heatmaps"].append(entry_map)
    result["heatmap"] = result["heatmaps"][0]["file"]
    ctx.progress("alignment", "", 1, 1, "done")
    atomic_write_json(cdir / "alignment.json", result)
    return result


def _not_found(planned: int) -> dict:
    return {"dots": 0, "planned": planned, "rms_px": None, "p95_px": None, "max_px": None,
            "note": "no dot found: projector off, blocked, or misaligned by more than half a lattice step"}
