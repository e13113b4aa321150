"""The alignment check: how far each projector's image lands from where its pose says.

Every projector shows, at the same time, a lattice of small dots drawn
*through its current pose* at table sites shared out between the projectors
so that no two dots overlap (the interleaved lattice of
:mod:`coordinator.calibration.multiplex`). The camera measures where each dot
really lands; mapped back through the camera's table mapping and the
projector's pose, that is the projector pixel which actually lit the site's
point, and its distance from the pixel that was drawn is the residual
misalignment in projector pixels (what blurs the synthetic aperture).

The result gives per projector the RMS, 95th percentile and maximum residual
and where on the table the worst one is, and a heat map over the table (the
content image's frame: the largest residual of any projector at each point)
saved as ``calibration/alignment.png`` beside ``calibration/alignment.json``.
Planar poses only; projectors with a 3D pose are skipped with a note.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from coordinator.calibration import multiplex, planar
from coordinator.calibration.errors import CalibrationError
from coordinator.camera import CameraError, CaptureRecorder
from coordinator.jobs import JobError
from coordinator.rig import HomographyPose
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


def heatmap(points_mm: dict[str, np.ndarray], values: dict[str, np.ndarray], *, table_mm: tuple[float, float],
            width: int = 600, step: int = 4) -> np.ndarray:
    """Largest residual of any projector at each point of the table, interpolated between the dots.

    Each projector's residuals are interpolated linearly inside its dots' hull
    (Delaunay, ``scipy.interpolate.LinearNDInterpolator``) and extended with
    the nearest dot's value outside it, on a grid ``step`` times coarser than
    the map (the field is smooth at the dot spacing), then upsampled.

    Parameters
    ----------
    points_mm : dict slot -> (M, 2) table mm of the measured dots
    values : dict slot -> (M,) residual magnitudes (projector px)
    width : int
        Width of the map in pixels (height follows the table's aspect).

    Returns
    -------
    (h, width) float32; NaN where no projector has dots.
    Row 0 is the table's +y edge, like the content image.
    """
    import cv2
    from scipy.interpolate import LinearNDInterpolator
    from scipy.spatial import QhullError, cKDTree

    tw, th = table_mm
    height = max(2, int(round(width * th / tw)))
    cw, ch = max(2, width // step), max(2, height // step)
    xs = (np.arange(cw) + 0.5) / cw * tw - tw / 2
    ys = th / 2 - (np.arange(ch) + 0.5) / ch * th
    q = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
    out = np.full(len(q), np.nan, np.float32)
    for slot, pts in points_mm.items():
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
    filled = np.nan_to_num(coarse, nan=0.0)
    up = cv2.resize(filled, (width, height), interpolation=cv2.INTER_LINEAR)
    mask = cv2.resize(np.isfinite(coarse).astype(np.uint8), (width, height), interpolation=cv2.INTER_NEAREST) > 0
    return np.where(mask, up, np.nan).astype(np.float32)


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
    entry = next((c for c in cams.get("cameras", []) if c.get("camera") == cam and "table_to_camera" in c), None)
    if entry is None:
        raise JobError(f"camera {cam} has no table mapping in calibration/cameras.json: calibrate a planar surface first")
    H_t2c = np.array(entry["table_to_camera"], np.float64)
    table_mm = tuple(cams.get("table_mm", (1200.0, 600.0)))
    content_size = (rig.config.content_width, rig.config.content_height)
    H_content_to_table = planar.content_to_table(content_size, table_mm)
    live = ctx.live_slots()
    slots = list(params.get("slots") or live)
    missing = [s for s in slots if s not in live]
    if missing:
        raise JobError(f"projector(s) {', '.join(missing)} not connected: start their nodes (see `shadowless status`)")
    t2p, skipped = {}, []
    for s in slots:
        pose = rig.slot(s).pose
        if isinstance(pose, HomographyPose):
            t2p[s] = pose.matrix @ np.linalg.inv(H_content_to_table)
        else:
            skipped.append(s)
    if skipped:
        ctx.log(f"skipped {', '.join(skipped)}: no planar pose (calibrate them first; 3D poses are not checked here)")
    if not t2p:
        raise JobError("no projector with a planar pose to check")
    sizes = {s: ctx.projector_size(s) for s in t2p}
    rounds = int(params.get("rounds", 2))
    settle = float(params.get("settle_s", 0.1))
    if not 1 <= rounds <= 16 or not 0 <= settle <= 30:
        raise JobError("rounds must be in 1..16 and settle_s in 0..30")
    camera_size = tuple(entry["size"])
    try:
        lattice = multiplex.plan_lattice(t2p, H_t2c, sizes=sizes, camera_size=camera_size, table_mm=table_mm, rounds=rounds)
    except ValueError as exc:
        raise JobError(f"cannot plan the alignment pattern: {exc}") from exc
    recorder = CaptureRecorder(params["record"]) if params.get("record") else None
    captures = 0

    async def shoot(images):
        nonlocal captures
        await ctx.show(images, settle_s=settle, require=list(t2p))
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

    ctx.progress("alignment", "", 0, rounds + 1, "every projector black")
    dark = await shoot({s: np.zeros((sizes[s][1], sizes[s][0]), np.uint8) for s in t2p})
    found = {s: ([], []) for s in t2p}
    for r in range(rounds):
        ctx.progress("alignment", "", r + 1, rounds + 1, f"{len(t2p)} projectors at once")
        cap = await shoot(lattice.frames(r))
        ms = await ctx.compute(multiplex.measure_lattice, cap, dark, lattice, r)
        for s in t2p:
            found[s][0].append(ms[s].camera)
            found[s][1].append(ms[s].projector)
    per_slot, pts_mm, mags = {}, {}, {}
    worst_slot, worst = None, -1.0
    for s in t2p:
        camxy = np.vstack(found[s][0])
        drawn = np.vstack(found[s][1])
        planned = sum(len(r.centres[s]) for r in lattice.rounds)
        if len(camxy) == 0:
            per_slot[s] = {"dots": 0, "planned": planned, "rms_px": None, "p95_px": None, "max_px": None,
                           "note": "no dot found: projector off, blocked, or misaligned by more than half a lattice step"}
            continue
        res = residuals(t2p[s], H_t2c, camxy, drawn)
        mag = np.linalg.norm(res, axis=1)
        at = planar.apply_homography(np.linalg.inv(H_t2c), camxy)
        k = int(np.argmax(mag))
        per_slot[s] = {"dots": int(len(mag)), "planned": planned, "rms_px": round(float(np.sqrt(np.mean(mag ** 2))), 4),
                       "p95_px": round(float(np.percentile(mag, 95)), 4), "max_px": round(float(mag.max()), 4),
                       "mean_offset_px": [round(float(v), 4) for v in res.mean(axis=0)],
                       "worst_at_mm": [round(float(v), 1) for v in at[k]]}
        pts_mm[s], mags[s] = at, mag
        if mag.max() > worst:
            worst, worst_slot = float(mag.max()), s
    width = int(params.get("heatmap_width", 600))
    hm = await ctx.compute(heatmap, pts_mm, mags, table_mm=table_mm, width=width)
    cdir = rig_dir / "calibration"
    png = cdir / "alignment.png"
    atomic_write_bytes(png, render_heatmap(hm))
    ctx.progress("alignment", "", rounds + 1, rounds + 1, "done")
    result = {
        "slots": per_slot, "skipped": skipped, "worst_slot": worst_slot,
        "worst_px": round(worst, 4) if worst >= 0 else None, "heatmap": str(png),
        "heatmap_full_scale_px": HEATMAP_FULL_SCALE_PX, "captures": captures, "wall_s": round(time.monotonic() - t0, 3),
        "checked_at": time.time(),
    }
    if np.isfinite(hm).any():
        iy, ix = np.unravel_index(int(np.nanargmax(hm)), hm.shape)
        tw, th = table_mm
        result["heatmap_peak_mm"] = [round((ix + 0.5) / hm.shape[1] * tw - tw / 2, 1), round(th / 2 - (iy + 0.5) / hm.shape[0] * th, 1)]
    atomic_write_json(cdir / "alignment.json", result)
    return result

