"""Stage 3, sequential on a mesh (3D): per projector the Gray codes of :mod:`.gray`; every
camera pixel's ray cast onto the mesh (and the table) turns decoded pixels into world <->
projector correspondences, and :func:`imaging.calibration.threed.calibrate_projector`
gives the projector's 3x4 pose."""
from __future__ import annotations

import math

import numpy as np

from imaging.calibration import threed
from imaging.calibration.errors import CalibrationError
from coordinator.calibration.options import CalibrateOptions
from coordinator.calibration.runs import slot_doc
from coordinator.calibration.stages.gray import decode_all, gray_captures, seen_check
from coordinator.calibration.stages.loops import one_by_one
from coordinator.calibration.stages.state import CameraSetup, State
from coordinator.jobs import JobError
from coordinator.rig import ProjectionPose


def cast_surfaces(setup: CameraSetup, table_mm: tuple[float, float] | None) -> dict[int, tuple[np.ndarray, ...]]:
    """Per posed camera: the world point, surface kind and unreliable-edge mask of every pixel."""
    out = {}
    with threed.SurfaceCaster(setup.mesh, table_mm=table_mm) as caster:
        for i, dev in setup.devices.items():
            pts, kind = caster.cast(dev)
            out[i] = (pts, kind, threed.edge_mask(pts, kind))
    return out


def fit_3d(decodes, surfaces, slot: str, size: tuple[int, int], opts: CalibrateOptions):
    """The projector's pinhole from every camera's decoded pixels on the surface; residuals per
    projector pixel, the number of correspondences and per-camera counts."""
    Xs, xs, per_camera = [], [], {}
    for i, d in enumerate(decodes):
        if i not in surfaces:
            continue
        pts, kind, edges = surfaces[i]
        use = d.valid & ~edges & ((kind == threed.MESH) | ((kind == threed.TABLE) & opts.use_table))
        ys, xx = np.nonzero(use)
        Xs.append(pts[ys, xx])
        xs.append(d.projector[ys, xx].astype(np.float64))
        per_camera[i] = {"decoded": int(len(ys)), "on_mesh": int(np.sum(kind[ys, xx] == threed.MESH))}
    X, x = np.vstack(Xs), np.vstack(xs)
    seen_check(slot, decodes, len(X), opts.min_pixels, opts.min_contrast)
    fit = threed.calibrate_projector(X, x, size, seed=opts.seed)
    # report residuals per projector pixel (mean surface point of the camera pixels that decoded to it)
    keys = x[fit.inliers].astype(np.int64)
    key = keys[:, 1] * (size[0] + 1) + keys[:, 0]
    uniq, inv, counts = np.unique(key, return_inverse=True, return_counts=True)
    sums = np.zeros((len(uniq), 3))
    np.add.at(sums, inv, X[fit.inliers])
    keep = counts >= 3
    centre = np.column_stack([uniq % (size[0] + 1), uniq // (size[0] + 1)]).astype(np.float64)
    r = threed.residuals(fit.device, sums[keep] / counts[keep, None], centre[keep])
    return fit, r[np.isfinite(r)], len(X), per_camera


async def sequential_3d(st: State) -> None:
    """Calibrate ``st.todo`` one after another on the mesh."""
    ctx, opts, setup = st.ctx, st.opts, st.setup
    try:
        surfaces = await ctx.compute(cast_surfaces, setup, opts.table_mm if opts.use_table else None)
    except CalibrationError as exc:
        raise JobError(str(exc)) from exc

    async def measure(slot: str):
        size = st.sizes[slot]
        white, black, caps = await gray_captures(st, slot)
        decodes = await ctx.compute(decode_all, white, black, caps, size, opts.min_contrast)
        fit, r, count, per_camera = await ctx.compute(fit_3d, decodes, surfaces, slot, size, opts)
        near, far = threed.depth_range(fit.device.P, setup.rig_mesh.vertices)
        return fit, r, count, per_camera, near, far

    def pose_of(slot: str, measured, before: int) -> tuple[ProjectionPose, dict]:
        fit, r, count, per_camera, near, far = measured
        P = fit.device.P / np.linalg.norm(fit.device.P[2, :3])
        pose = ProjectionPose(P, setup.rig_mesh, near_mm=near, far_mm=far)
        doc = slot_doc(st.run, slot, opts, rms=float(np.sqrt(np.mean(r ** 2))) if len(r) else math.nan,
                       mx=float(r.max()) if len(r) else math.nan, points=len(r), raw_rms=fit.rms, decoded=count,
                       inliers=fit.count, captures=st.shots - before, cameras=per_camera,
                       K=fit.device.K.tolist(), center_mm=fit.device.center.tolist())
        return pose, doc

    await one_by_one(st, measure, pose_of)
