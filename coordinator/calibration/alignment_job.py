"""The ``alignment`` job: how far each projector's image lands from where its pose says.

Every checked projector shows, at the same time, a lattice of dots drawn through its
current pose; the camera measures where they land (the method and its numerics:
:mod:`imaging.calibration.alignment`). The result gives per projector the RMS, 95th
percentile and maximum residual (projector pixels) and where the worst one is, and heat
maps saved as ``calibration/alignment.png`` (and ``alignment-mesh.png`` when a rig has
both planar and 3D poses) beside ``calibration/alignment.json``. Each map is also drawn as a
figure to read (``alignment-figure.png``, ``alignment-mesh-figure.png``: colour bar, axes in
table mm or camera px, each planar projector's outline; :mod:`.heatmap_figure`), whose file,
layout, extent, outlines (table mm) and projector pixel sizes (mm) the map's entry lists.

Options: :class:`coordinator.calibration.options.AlignmentOptions`.
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from imaging.calibration import multiplex, planar, threed
from imaging.calibration.alignment import (
    HEATMAP_FULL_SCALE_PX,
    heatmap,
    plan_surface_lattice,
    render_heatmap,
    residuals,
    sample_points,
)
from imaging.calibration.errors import CalibrationError
from imaging.calibration.heatmap_figure import footprint_mm, heatmap_figure, pixel_mm
from coordinator.calibration.options import AlignmentOptions
from coordinator.calibration.runs import calibration_dir
from coordinator.jobs import JobContext, JobError
from coordinator.jobs.results import Figures, JobResult
from coordinator.rig import HomographyPose, ProjectionPose
from protos.store import atomic_write_bytes, atomic_write_json
from protos.spaces import content_to_table
from protos.wording import count

OPTIONS = AlignmentOptions


@dataclass(frozen=True, kw_only=True)
class AlignmentResult(JobResult):
    """The ``alignment`` job's result (also ``calibration/alignment.json``): per projector its residuals
    (``dots``, ``planned``, ``rms_px``, ``p95_px``, ``max_px``, ...), those skipped for want of a pose, the
    worst projector, and per heat map (planar: table mm; mesh: camera px) its files, frame and extent;
    ``heatmap`` is the first one's file."""

    slots: dict[str, Figures]
    skipped: list[str]
    worst_slot: str | None
    worst_rms_px: float | None
    heatmap_full_scale_px: float
    captures: int
    wall_s: float
    checked_at: float
    heatmaps: list[Figures]
    heatmap: str

#: One heat map: file name, the map, its extent (left, right, top, bottom).
HeatMap = tuple[str, np.ndarray, tuple[float, float, float, float]]


def _load_cameras(rig_dir: Path) -> dict:
    f = calibration_dir(rig_dir) / "cameras.json"
    try:
        return json.loads(f.read_text())
    except FileNotFoundError:
        raise JobError("no camera calibration in this rig yet (calibration/cameras.json): run `shadowless calibrate` first") from None
    except (OSError, json.JSONDecodeError) as exc:
        raise JobError(f"{f}: cannot read the camera calibration ({exc}); run `shadowless calibrate` again") from exc


class _Check:
    """One alignment check: shows lattices and captures them with the calibrated camera."""

    def __init__(self, ctx: JobContext, opts: AlignmentOptions, camera_size: tuple[int, int]):
        self.ctx, self.opts, self.camera_size = ctx, opts, camera_size

    async def shoot(self, images: dict[str, np.ndarray], require: list[str]) -> np.ndarray:
        await self.ctx.show(images, settle_s=self.opts.settle_s, require=require)
        img = await self.ctx.capture(self.opts.camera)
        if (img.shape[1], img.shape[0]) != self.camera_size:
            raise JobError(f"camera {self.opts.camera} delivers {img.shape[1]}x{img.shape[0]} images but was calibrated "
                           f"at {self.camera_size[0]}x{self.camera_size[1]}: recalibrate")
        return img

    async def measure(self, lattice: multiplex.Lattice, stage: str) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Dark + one capture per round, every checked projector at once; camera centroids and drawn centres."""
        ctx, sizes, slots = self.ctx, lattice.sizes, list(lattice.slots)
        ctx.progress(stage, "", 0, len(lattice.rounds) + 1, "every projector black")
        dark = await self.shoot({s: np.zeros((sizes[s][1], sizes[s][0]), np.uint8) for s in slots}, slots)
        found: dict[str, tuple[list, list]] = {s: ([], []) for s in slots}
        for r in range(len(lattice.rounds)):
            ctx.progress(stage, "", r + 1, len(lattice.rounds) + 1, f"{count(len(slots), 'projector')} at once")
            ms = await ctx.compute(multiplex.measure_lattice, await self.shoot(lattice.frames(r), slots), dark, lattice, r)
            for s in slots:
                found[s][0].append(ms[s].camera)
                found[s][1].append(ms[s].projector)
        return {s: (np.vstack(found[s][0]), np.vstack(found[s][1])) for s in slots}


async def _check_planar(check: _Check, flat: dict[str, HomographyPose], entry: dict, cams: dict,
                        per_slot: dict[str, dict]) -> HeatMap:
    ctx, opts = check.ctx, check.opts
    if "table_to_camera" not in entry:
        raise JobError(f"camera {opts.camera} has no table mapping in calibration/cameras.json: calibrate the table first")
    table_mm = tuple(cams.get("table_mm", (1200.0, 600.0)))
    H_t2c = np.array(entry["table_to_camera"], np.float64)
    c2t = content_to_table((ctx.rig.config.content_width, ctx.rig.config.content_height), table_mm)
    t2p = {s: p.matrix @ np.linalg.inv(c2t) for s, p in flat.items()}
    try:
        lattice = multiplex.plan_lattice(t2p, H_t2c, sizes={s: ctx.projector_size(s) for s in flat},
                                         camera_size=check.camera_size, table_mm=table_mm, rounds=opts.rounds)
    except ValueError as exc:
        raise JobError(f"cannot plan the alignment pattern: {exc}") from exc
    found = await check.measure(lattice, "alignment")
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
    return "alignment.png", await ctx.compute(heatmap, pts, mags, extent=extent, width=opts.heatmap_width), extent


async def _check_mesh(check: _Check, solid: dict[str, ProjectionPose], entry: dict, per_slot: dict[str, dict],
                      name: str) -> HeatMap:
    ctx, opts = check.ctx, check.opts
    if "pinhole" not in entry:
        raise JobError(f"camera {opts.camera} was not posed in 3D (calibration/cameras.json): calibrate the mesh first")
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
        lattice = await ctx.compute(plan_surface_lattice, devices, camera, cam_pts, usable, proj_pts, rounds=opts.rounds)
    except (CalibrationError, ValueError) as exc:
        raise JobError(f"cannot plan the alignment pattern on the mesh: {exc}") from exc
    found = await check.measure(lattice, "alignment (mesh)")
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
    W, H = check.camera_size
    extent = (-0.5, W - 0.5, -0.5, H - 0.5)
    return name, await ctx.compute(heatmap, pts, mags, extent=extent, width=min(opts.heatmap_width, W)), extent


async def run(ctx: JobContext, opts: AlignmentOptions) -> AlignmentResult:
    """Measure every checked projector's residual misalignment (see the module docstring)."""
    t0 = time.monotonic()
    rig = ctx.rig
    cams = _load_cameras(Path(rig.path))
    entry = next((c for c in cams.get("cameras", []) if c.get("camera") == opts.camera), None)
    if entry is None:
        raise JobError(f"camera {opts.camera} is not in calibration/cameras.json: calibrate with it first")
    slots = ctx.select_slots(opts.slots)
    flat = {s: rig.slot(s).pose for s in slots if isinstance(rig.slot(s).pose, HomographyPose)}
    solid = {s: rig.slot(s).pose for s in slots if isinstance(rig.slot(s).pose, ProjectionPose)}
    skipped = [s for s in slots if s not in flat and s not in solid]
    if skipped:
        ctx.log(f"skipped {', '.join(skipped)}: no pose yet (calibrate them first)")
    if not flat and not solid:
        raise JobError("no calibrated projector to check")
    if opts.record:
        ctx.record_captures(opts.record)
    check = _Check(ctx, opts, tuple(entry["size"]))
    per_slot: dict[str, dict] = {}
    maps: list[HeatMap] = []
    if flat:
        maps.append(await _check_planar(check, flat, entry, cams, per_slot))
    if solid:
        maps.append(await _check_mesh(check, solid, entry, per_slot, "alignment-mesh.png" if flat else "alignment.png"))
    cdir = calibration_dir(rig.path)
    worst_slot = max((s for s in per_slot if per_slot[s]["rms_px"] is not None), key=lambda s: per_slot[s]["rms_px"],
                     default=None)
    captures, wall_s, checked_at = ctx.captures, round(time.monotonic() - t0, 3), time.time()
    heatmaps: list[Figures] = []
    outlines = _outlines(ctx, flat, cams)
    for name, hm, extent in maps:
        atomic_write_bytes(cdir / name, render_heatmap(hm))
        frame = "table mm" if name == "alignment.png" and flat else "camera px"
        lines = outlines if frame == "table mm" else {}
        png, layout = heatmap_figure(hm, extent, units=frame, full_scale=HEATMAP_FULL_SCALE_PX, outlines=lines)
        figure = name.replace(".png", "-figure.png")
        atomic_write_bytes(cdir / figure, png)
        entry_map = {"file": str(cdir / name), "frame": frame, "extent": [float(e) for e in extent],
                     "figure": str(cdir / figure), "figure_layout": layout,
                     "outlines": {s: [[round(float(v), 2) for v in p] for p in o] for s, o in lines.items()},
                     "pixel_mm": {s: round(pixel_mm(o, ctx.projector_size(s)), 4) for s, o in lines.items()}}
        if np.isfinite(hm).any():
            iy, ix = np.unravel_index(int(np.nanargmax(hm)), hm.shape)
            left, right, top, bottom = extent
            entry_map["peak_at"] = [round(left + (ix + 0.5) / hm.shape[1] * (right - left), 1),
                                    round(top + (iy + 0.5) / hm.shape[0] * (bottom - top), 1)]
        heatmaps.append(entry_map)
    result = AlignmentResult(slots=per_slot, skipped=skipped, worst_slot=worst_slot,
                             worst_rms_px=per_slot[worst_slot]["rms_px"] if worst_slot else None,
                             heatmap_full_scale_px=HEATMAP_FULL_SCALE_PX, captures=captures, wall_s=wall_s,
                             checked_at=checked_at, heatmaps=heatmaps, heatmap=heatmaps[0]["file"])
    ctx.progress("alignment", "", 1, 1, "done")
    atomic_write_json(cdir / "alignment.json", result.to_wire())
    return result


def _outlines(ctx: JobContext, flat: dict[str, HomographyPose], cams: dict) -> dict[str, np.ndarray]:
    """Each planar projector's footprint on the table, (4, 2) float64 mm (those beyond the horizon left out)."""
    table_mm = tuple(cams.get("table_mm", (1200.0, 600.0)))
    content = (ctx.rig.config.content_width, ctx.rig.config.content_height)
    found = {s: footprint_mm(p.matrix, ctx.projector_size(s), content, table_mm) for s, p in flat.items()}
    return {s: o for s, o in found.items() if o is not None}


def _slot_stats(res: np.ndarray, where: np.ndarray, planned: int, *, where_key: str) -> dict:
    mag = np.linalg.norm(res, axis=1)
    k = int(np.argmax(mag))
    return {"dots": int(len(mag)), "planned": planned, "rms_px": round(float(np.sqrt(np.mean(mag ** 2))), 4),
            "p95_px": round(float(np.percentile(mag, 95)), 4), "max_px": round(float(mag.max()), 4),
            "mean_offset_px": [round(float(v), 4) for v in res.mean(axis=0)],
            where_key: [round(float(v), 1) for v in where[k]]}


def _not_found(planned: int) -> dict:
    return {"dots": 0, "planned": planned, "rms_px": None, "p95_px": None, "max_px": None,
            "note": "no dot found: projector off, blocked, or misaligned by more than half a lattice step"}
