"""`shadowless bench bust`: coverage on the bust against the room's truth, and fingertip touches on it.

The paper touches its plaster bust with a fingertip (the head, the chest, the lower back of the
head) and finds shadows whose size "varied depending on the location of contact", larger where
fewer projectors reach (section 5.1.2). In the virtual room with ``surface="bust"``:

* ``coverage``: the coordinator's coverage (:mod:`coordinator.coverage`, from the projectors' 3x4
  poses and the mesh alone) against the room's ground truth
  (:meth:`sim.truth.Truth.illumination_count`) as seen by five cameras around the bust (ceiling,
  front, back, both sides), with the room's true poses so the comparison checks the computation
  itself. ``points``: at the very surface points the cameras see; ``pixels``: the stored
  texel map looked up at each camera pixel's uv; ``texels``: per visible texel (one a camera
  pixel's uv falls in), the map's count against the most common true count of its pixels.
  ``share_abs_err``: each projector's share of the light against the truth's irradiance shares.
* ``touches``: a :class:`sim.touch.TouchingHand` with its index fingertip on the surface at the
  named points and a sampled set, in two poses (``--pose``): ``normal``, the finger along the
  inward normal; ``above``, the finger halfway between that and straight down (a hand that
  comes from above, where the ceiling's light comes from). Per touch a camera looks at the
  contact along the normal (``--fov-mm`` either side, ``--camera-px`` pixels); from the room's
  light-drop truth for P1 (the single bright unit) and P25: the surface area (mm^2, from the
  surface points each camera pixel sees) losing more than 50 % and more than 90 % of its light,
  the same within 60 mm of the contact (``local_``: the fingertip's own shadow rather than the
  palm's and forearm's), the largest drop, and the largest drop farther than 15 mm from the
  contact; the coverage (count, effective number) at the contact, the mean count within 30 mm
  of it, and whether P1 lights the contact at all (where it does not, there is no light to lose
  and P1's drop there is 0).
* ``spearman``: per pose, Spearman's rho (scipy.stats.spearmanr) between the coverage at the
  contact and the P25 shadow area over the touches, with n and the p-value: negative = more
  projectors, smaller shadows (the paper's observation).

Shadow areas are what the touch's camera sees within its field of view: P1's large shadows are
clipped by it (a lower bound); P25's stay well inside.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import replace

import numpy as np
from scipy import stats

from bench.machine import machine
from coordinator.calibration.threed import Pinhole as CoordPinhole
from coordinator.coverage import CoverageModel, Projector
from coordinator.coverage_gl import vertex_normals
from sim.geometry import Pinhole, intrinsics, look_at
from sim.precompute import MESH
from sim.room import Room
from sim.scene import SUBSETS, CameraSpec, reference_scene
from sim.touch import TouchingHand, inside

#: named contacts: (name, ray origin, ray direction) cast onto the bust (it faces +y, stands on z = 0)
NAMED = (
    ("head", (0.0, 30.0, 1000.0), (0.0, 0.0, -1.0)),
    ("chest", (0.0, 1000.0, 200.0), (0.0, -1.0, 0.0)),
    ("back_of_head", (0.0, -1000.0, 430.0), (0.0, 1.0, 0.0)),
)
CAMERA_DISTANCE_MM = 450.0
FAR_FROM_CONTACT_MM = 15.0
NEAR_CONTACT_MM = 30.0
#: the fingertip's own shadow: the part of a shadow within this distance of the contact
LOCAL_MM = 60.0


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--touches", type=int, default=15, help="sampled touch points besides the named ones (default 15)")
    parser.add_argument("--projector-scale", type=float, default=0.25, help="projector resolution vs 1280x800 (default 0.25)")
    parser.add_argument("--camera-px", type=int, default=200, help="each touch camera's side, pixels (default 200)")
    parser.add_argument("--fov-mm", type=float, default=150.0, help="a touch camera sees this far either side of the contact (default 150)")
    parser.add_argument("--texture", type=int, default=512, help="coverage texture side, texels (default 512)")
    parser.add_argument("--compare-px", type=int, default=320, help="side of the cameras the coverage is compared through (default 320)")
    parser.add_argument("--pose", choices=("normal", "above", "both"), default="both",
                        help="the finger along the inward normal, from above (halfway to straight down), or both (default)")
    parser.add_argument("--quick", action="store_true", help="a smoke run: 4 sampled touches, small cameras and textures")
    parser.add_argument("--seed", type=int, default=0)


def _log(text: str) -> None:
    print(f"bench bust: {text}", file=sys.stderr, flush=True)


# ---------------------------------------------------------------------- geometry helpers
def pixel_areas(points: np.ndarray, kind: np.ndarray, *, jump: float = 4.0) -> np.ndarray:
    """mm^2 of surface each camera pixel sees, from the surface points of neighbouring pixels.

    ``|dP/dx x dP/dy|`` with central differences where both neighbours see the same kind of
    surface without a depth jump (a step longer than ``jump`` times the median step), one-sided
    where only one does; pixels with no usable neighbour along an axis get the median area.

    Parameters
    ----------
    points : (H, W, 3) float world mm, NaN where nothing
    kind : (H, W) uint8, 0 where nothing

    Returns
    -------
    (H, W) float64, 0 where nothing
    """
    P = np.asarray(points, np.float64)
    valid = (kind > 0) & np.all(np.isfinite(P), axis=-1)
    steps = []
    for axis in (0, 1):
        d = np.linalg.norm(np.diff(P, axis=axis), axis=-1)
        both = valid[1:] & valid[:-1] if axis == 0 else valid[:, 1:] & valid[:, :-1]
        same = (kind[1:] == kind[:-1]) if axis == 0 else (kind[:, 1:] == kind[:, :-1])
        steps.append((d, both & same))
    typical = np.median(np.concatenate([d[ok] for d, ok in steps])) if any(ok.any() for _, ok in steps) else 1.0
    grads = []
    for axis, (d, ok) in enumerate(steps):
        ok = ok & (d < jump * typical)
        diff = np.diff(np.nan_to_num(P), axis=axis)
        fwd = np.zeros_like(P)
        bwd = np.zeros_like(P)
        has_f = np.zeros(valid.shape, bool)
        has_b = np.zeros(valid.shape, bool)
        if axis == 0:
            fwd[:-1], has_f[:-1] = diff, ok
            bwd[1:], has_b[1:] = diff, ok
        else:
            fwd[:, :-1], has_f[:, :-1] = diff, ok
            bwd[:, 1:], has_b[:, 1:] = diff, ok
        g = np.where((has_f & has_b)[..., None], (fwd + bwd) / 2, np.where(has_f[..., None], fwd, bwd))
        grads.append((g, has_f | has_b))
    (gy, oky), (gx, okx) = grads
    area = np.linalg.norm(np.cross(gx, gy), axis=-1)
    good = valid & okx & oky
    fill = float(np.median(area[good])) if good.any() else 0.0
    return np.where(valid, np.where(good, area, fill), 0.0)


def ray_mesh(origin, direction, triangles: np.ndarray) -> tuple[int, np.ndarray]:
    """Nearest hit of one ray with triangles (F, 3, 3) (Möller-Trumbore): (face, barycentric (3,)); face -1 on a miss."""
    o = np.asarray(origin, np.float64)
    d = np.asarray(direction, np.float64)
    d = d / np.linalg.norm(d)
    v0, e1, e2 = triangles[:, 0], triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0]
    p = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, p)
    ok = np.abs(det) > 1e-12
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = o - v0
    u = np.einsum("ij,ij->i", s, p) * inv
    q = np.cross(s, e1)
    v = (q @ d) * inv
    t = np.einsum("ij,ij->i", e2, q) * inv
    hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-6)
    if not hit.any():
        return -1, np.zeros(3)
    k = int(np.flatnonzero(hit)[np.argmin(t[hit])])
    return k, np.array([1 - u[k] - v[k], u[k], v[k]])


def surface_at(mesh, normals: np.ndarray, face: int, bary: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Point (3,) and interpolated unit normal (3,) of barycentric ``bary`` on ``face``."""
    f = mesh.faces[face]
    X = bary @ mesh.vertices[f].astype(np.float64)
    n = bary @ normals[f].astype(np.float64)
    return X, n / np.linalg.norm(n)


def touch_points(mesh, *, sampled: int, seed: int, poses: tuple[str, ...] = ("normal",)) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """The named contacts and ``sampled`` more, area-weighted over the surface, where a hand fits:
    above the plinth, not under an overhang, the hand clear of the bust (no vertex inside it farther
    than 20 mm from the contact) and of the table."""
    normals = vertex_normals(mesh.vertices, mesh.faces)
    tri = mesh.triangles()
    out = []
    for name, o, d in NAMED:
        face, bary = ray_mesh(o, d, tri)
        if face < 0:
            raise RuntimeError(f"the ray for {name} misses the mesh")
        out.append((name, *surface_at(mesh, normals, face, bary)))
    rng = np.random.default_rng(seed)
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    tries = 0
    while len(out) < len(NAMED) + sampled and tries < 50 * (sampled + 1):
        tries += 1
        face = int(rng.choice(len(area), p=area / area.sum()))
        a, b = rng.random(2)
        if a + b > 1:
            a, b = 1 - a, 1 - b
        X, n = surface_at(mesh, normals, face, np.array([1 - a - b, a, b]))
        if X[2] < 60 or n[2] < -0.3:
            continue
        far = np.linalg.norm(mesh.vertices - X, axis=1) > 20
        hands = [TouchingHand(X, n, direction=finger(pose, n)) for pose in poses]
        if any(h.lowest_z() < 5 or inside(h, mesh.vertices[far]).any() for h in hands):
            continue
        out.append((f"s{len(out) - len(NAMED):02d}", X, n))
    return out


def look_camera(name: str, eye, target, *, px: int, half_mm: float) -> CameraSpec:
    """A square camera at ``eye`` looking at ``target``, ``half_mm`` either side at the target."""
    eye, target = np.asarray(eye, np.float64), np.asarray(target, np.float64)
    view = target - eye
    up = (0.0, 0.0, 1.0) if abs(view[2]) < 0.9 * np.linalg.norm(view) else (0.0, 1.0, 0.0)
    R, t = look_at(eye, target, up=up)
    f = (px / 2) * float(np.linalg.norm(view)) / half_mm
    dev = Pinhole(intrinsics((px, px), focal=f), R, t, (px, px))
    return CameraSpec(name, dev, dev, 1.0)


# ---------------------------------------------------------------------- coverage vs truth
def true_projectors(room: Room, slots: list[str]) -> list[Projector]:
    out = []
    for s in slots:
        p = room.truth.projector(s)
        out.append(Projector(s, CoordPinhole(p.K, p.R, p.t, p.size), 1.0))
    return out


def comparison_room(scene, *, px: int) -> Room:
    """The bust seen by five cameras: the ceiling camera and four around it (front, right, back, left)."""
    lo, hi = scene.mesh.bounds
    c = (lo + hi) / 2
    cams = [replace(scene.cameras[0], pinhole=scene.cameras[0].native.scaled((px, px * 3 // 4)))]
    for name, az in (("front", 0.0), ("right", 90.0), ("back", 180.0), ("left", 270.0)):
        a = math.radians(az)
        eye = c + 1100.0 * np.array([math.sin(a) * math.cos(0.35), math.cos(a) * math.cos(0.35), math.sin(0.35)])
        cams.append(look_camera(name, eye, c, px=px, half_mm=380.0))
    return Room(replace(scene, cameras=tuple(cams)), noise=False)


def compare_coverage(room: Room, model: CoverageModel, cov) -> dict:
    """The coverage against the room's truth through every camera of ``room``."""
    cams = room.scene.cameras
    slots = list(cov.slots)
    pix_agree, pix_n, pt_agree = 0, 0, 0
    texel_votes: dict[int, list[int]] = {}
    share_err = []
    per_camera = {}
    w = cov.size[0]
    for k, cam in enumerate(cams):
        surf = room.truth.surface(k)
        m = surf.kind == MESH
        truth = room.truth.illumination_count(k)[m]
        pc = model.at_points(surf.points[m], surf.normals[m])
        rc = cov.lookup(surf.uv[m])
        tc = cov.count[rc[:, 0], rc[:, 1]]
        irr = np.stack([room.truth.irradiance(s, k, occluders=False)[m] for s in slots]).astype(np.float64)
        with np.errstate(invalid="ignore", divide="ignore"):
            ts = irr / irr.sum(axis=0)
        same = pc.count == truth
        share_err.append(np.abs(ts - pc.share)[:, same & (truth > 0)].ravel())
        flat = rc[:, 0] * w + rc[:, 1]
        for t_id, t_count in zip(flat.tolist(), truth.tolist()):
            texel_votes.setdefault(t_id, []).append(t_count)
        per_camera[cam.name] = {"pixels": int(m.sum()), "points_agree": round(float(same.mean()), 4),
                                "pixels_agree": round(float((tc == truth).mean()), 4)}
        pix_agree += int((tc == truth).sum())
        pt_agree += int(same.sum())
        pix_n += int(m.sum())
    flat_count = cov.count.ravel()
    texel_ok = [flat_count[t] == np.bincount(v).argmax() for t, v in texel_votes.items()]
    err = np.concatenate(share_err)
    return {
        "cameras": per_camera,
        "pixels": pix_n,
        "points_agree": round(pt_agree / pix_n, 4),
        "pixels_agree": round(pix_agree / pix_n, 4),
        "visible_texels": len(texel_ok),
        "texels_agree": round(float(np.mean(texel_ok)), 4),
        "share_abs_err": {"p50": float(np.percentile(err, 50)), "p99": float(np.percentile(err, 99)), "max": float(err.max())},
        "note": "true poses, equal gains; the truth's irradiance includes each unit's peak output (+-5 %), which poses do not tell",
    }


# ---------------------------------------------------------------------- touches
def finger(pose: str, n: np.ndarray) -> np.ndarray | None:
    """The index finger's direction for a pose: ``normal`` along the inward normal; ``above`` halfway
    between it and straight down (a hand that comes from above, where the ceiling's light comes from)."""
    if pose == "normal":
        return None
    g = -n - np.array([0.0, 0.0, 1.0])
    return g / np.linalg.norm(g) if np.linalg.norm(g) > 1e-6 else -n


def _shadow(room: Room, area: np.ndarray, m: np.ndarray, dist: np.ndarray) -> dict:
    out = {}
    far = m & (dist > FAR_FROM_CONTACT_MM)
    local = m & (dist <= LOCAL_MM)
    for subset in ("P1", "P25"):
        room.set_active(SUBSETS[subset])
        drop = room.truth.light_drop()
        out[subset] = {"area_over_50_mm2": round(float(area[m & (drop > 0.5)].sum()), 1),
                       "area_over_90_mm2": round(float(area[m & (drop > 0.9)].sum()), 1),
                       "local_area_over_50_mm2": round(float(area[local & (drop > 0.5)].sum()), 1),
                       "local_area_over_90_mm2": round(float(area[local & (drop > 0.9)].sum()), 1),
                       "max_drop": round(float(drop[m].max()), 4),
                       "max_drop_beyond_15mm": round(float(drop[far].max()), 4) if far.any() else None}
    return out


def touch_study(scene, model: CoverageModel, single: CoverageModel, points, *, poses: tuple[str, ...], px: int,
                half_mm: float) -> list[dict]:
    """Per touch point: its coverage, and per hand pose the shadow for P1 and P25 (module docstring)."""
    rows = []
    for i, (name, X, n) in enumerate(points):
        t0 = time.perf_counter()
        cam = look_camera(f"touch-{name}", X + CAMERA_DISTANCE_MM * n, X, px=px, half_mm=half_mm)
        room = Room(replace(scene, cameras=(cam,)), noise=False)
        surf = room.truth.surface()
        m = surf.kind == MESH
        area = pixel_areas(surf.points, surf.kind)
        dist = np.linalg.norm(surf.points.astype(np.float64) - X, axis=-1)
        pc = model.at_points(X[None], n[None])
        near = m & (dist <= NEAR_CONTACT_MM)
        near_pc = model.at_points(surf.points[near], surf.normals[near])
        row = {"name": name, "point_mm": [round(float(v), 1) for v in X], "normal": [round(float(v), 3) for v in n],
               "coverage": {"count": int(pc.count[0]), "effective": round(float(pc.effective[0]), 2),
                            "max_share_pct": round(100 * float(pc.share[:, 0].max()), 1),
                            "near_count_mean": round(float(near_pc.count.mean()), 2) if near.any() else None},
               "p1_reaches_contact": bool(single.at_points(X[None], n[None]).count[0] > 0),
               "camera_mesh_mm2": round(float(area[m].sum()), 1)}
        for pose in poses:
            room.set_occluders([TouchingHand(X, n, direction=finger(pose, n))])
            row[pose] = _shadow(room, area, m, dist)
        row["seconds"] = round(time.perf_counter() - t0, 2)
        _log(f"touch {i + 1}/{len(points)} {name}: count {row['coverage']['count']}, P25 >50%: "
             + ", ".join(f"{pose} {row[pose]['P25']['area_over_50_mm2']:.0f} mm^2" for pose in poses))
        rows.append(row)
    return rows


def spearman(rows: list[dict], key: str, pose: str, area: str) -> dict:
    """Spearman's rho between the coverage figure ``key`` and the P25 shadow ``area`` of ``pose``."""
    x = [r["coverage"][key] for r in rows]
    y = [r[pose]["P25"][area] for r in rows]
    if len(rows) < 3 or len(set(x)) < 2 or len(set(y)) < 2:
        return {"rho": None, "p": None, "n": len(rows)}
    res = stats.spearmanr(x, y)
    return {"rho": round(float(res.statistic), 3), "p": float(res.pvalue), "n": len(rows)}


def run(args: argparse.Namespace) -> int:
    if args.quick:
        args.touches, args.camera_px, args.texture, args.compare_px = min(args.touches, 4), 96, 256, 200
        args.projector_scale = min(args.projector_scale, 0.125)
    if args.touches < 0 or args.camera_px < 16 or args.texture < 16 or args.compare_px < 32 or args.fov_mm <= 0:
        raise SystemExit("need --touches >= 0, --camera-px >= 16, --texture >= 16, --compare-px >= 32, --fov-mm > 0")
    poses = ("normal", "above") if args.pose == "both" else (args.pose,)
    t0 = time.perf_counter()
    scene = reference_scene(projector_scale=args.projector_scale, camera_scale=0.125, surface="bust", seed=args.seed)
    mesh = scene.mesh
    slots = SUBSETS["P25"]
    room = comparison_room(scene, px=args.compare_px)
    _log(f"coverage of {len(slots)} projectors on a {args.texture}^2 texture")
    tc = time.perf_counter()
    model = CoverageModel(mesh.vertices, mesh.faces, mesh.uvs, true_projectors(room, slots))
    single = CoverageModel(mesh.vertices, mesh.faces, mesh.uvs, true_projectors(room, SUBSETS["P1"]))
    try:
        cov = model.texture((args.texture, args.texture))
        coverage_s = time.perf_counter() - tc
        _log("comparing with the room's truth")
        comparison = compare_coverage(room, model, cov)
        del room
        points = touch_points(mesh, sampled=args.touches, seed=args.seed, poses=poses)
        _log(f"{len(points)} touches")
        rows = touch_study(scene, model, single, points, poses=poses, px=args.camera_px, half_mm=args.fov_mm)
    finally:
        model.close()
        single.close()
    summary = cov.summary()
    doc = {
        "benchmark": "bust",
        "machine": machine(),
        "params": {"touches": len(rows), "sampled": args.touches, "poses": list(poses), "projector_scale": args.projector_scale,
                   "camera_px": args.camera_px, "fov_mm": args.fov_mm, "texture": args.texture,
                   "compare_px": args.compare_px, "quick": args.quick, "seed": args.seed},
        "coverage": {"seconds": round(coverage_s, 2), "surface_mm2": summary["surface_mm2"],
                     "count_mean": summary["count_mean"], "count_min": summary["count_min"],
                     "count_median": summary["count_median"], "vs_truth": comparison},
        "touches": rows,
        "spearman": {pose: {
            "count_vs_area_over_50": spearman(rows, "count", pose, "area_over_50_mm2"),
            "count_vs_area_over_90": spearman(rows, "count", pose, "area_over_90_mm2"),
            "count_vs_local_area_over_50": spearman(rows, "count", pose, "local_area_over_50_mm2"),
            "count_vs_local_area_over_90": spearman(rows, "count", pose, "local_area_over_90_mm2"),
            "near_count_vs_area_over_50": spearman(rows, "near_count_mean", pose, "area_over_50_mm2"),
            "effective_vs_area_over_50": spearman(rows, "effective", pose, "area_over_50_mm2"),
        } for pose in poses},
        "seconds": round(time.perf_counter() - t0, 1),
    }
    print(json.dumps(doc, indent=2))
    return 0
