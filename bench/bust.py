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
* ``touches``: a person touches the bust with a fingertip at the named points (head, chest, lower
  back of the head, as in the paper's figure) and at ``--touches`` more, spread over the surface a
  hand can reach (farthest-point sampling: head, face, sides, back of the head, neck, shoulders,
  chest, back), under P1 (the single bright unit) and P25.

  The pose (``--pose reach``, the default) is a natural one: the participant stands on the
  contact's side of the bust, the shoulder ``--shoulder-distance`` (600 mm) from the bust's axis
  and ``--shoulder-z`` (650 mm) above the table top (a shoulder 1.4 m above the floor, the bust on
  a 0.75 m table; the projectors are 1.4 m above the table top, so a shoulder "1.4 m high" in
  world units would sit in the projector array), and reaches in: the index finger along the
  reach, tilted into the surface as far as a fingertip touch needs (at least 35 degrees from the
  tangent plane), the back of the hand up, the upper arm joining the elbow to the shoulder
  (:meth:`sim.touch.TouchingHand.reaching`). ``normal`` and ``above`` are the earlier, unnatural
  poses (the finger along the inward normal; halfway between that and straight down), kept to
  compare.

  The viewer looks at the contact along the normal from 450 mm (``--fov-mm`` either side,
  ``--camera-px`` pixels), and sees the hand where the hand is in the way.

  **The shadow region (stated before any figure was measured).** What an observer calls the
  shadow of a touch is the dark patch next to the fingertip: the connected region of surface
  around the contact whose light drops by more than half (``drop > 0.5``: a patch at most half as
  bright as the picture around it, which nobody misses), counted only where the viewer sees the
  surface (where the viewer sees the hand there is no shadow to see). In the viewer's image: the
  8-connected components of mesh pixels with drop > 0.5 (hand pixels included, so a region the
  finger's silhouette cuts in two stays one) that have a pixel within 20 mm of the contact; their
  area (mm^2, from the surface points each pixel sees) over the pixels where the viewer sees the
  surface. The drop is the room's truth, ``1 - kept / total`` light at each surface point. P1's
  regions may reach the edge of the view (then they are a lower bound: ``clipped``).

  Per touch (the issue's table): that area and the maximum drop the viewer sees, for P1 and P25;
  the coverage at the contact (count of projectors reaching it, effective number, the largest
  share, mean count within 30 mm); the incidence (degrees between the normal and the direction to
  the array's centre); the region of the bust; whether P1 lights the contact; the secondary
  measure (the same region at drop > 0.3); the area of the region the hand hides.

  ``planar``: the same touches on the table (four points, the person at its front edge) under
  the same measure, the paper's reference ("shadow regions larger than those observed on the
  planar surface").
* ``spearman``: per pose, Spearman's rho (scipy.stats.spearmanr) of the coverage count at the
  contact against the P25 shadow area, with p and n. ``primary``: the measure above.
  ``secondary_drop_over_30``: the same region at drop > 0.3. ``secondary_hidden_included``: the
  region's whole area, the part the hand hides from the viewer included (added after a 7-touch
  smoke run showed that a viewer along the normal of a surface facing the ceiling looks along the
  light, so the hand hides most of its own shadow there; the primary measure stays as stated).
  Negative = fewer projectors, larger
  shadows (the paper's observation). ``explain`` (figures to say why, not measures of the
  shadow): the incidence against the area and against the count; the width of the cone of light
  reaching the contact (``light_spread_deg``, the share-weighted RMS angle of the projectors'
  directions about their mean) against the area and the count; the contact's height against the
  area; how many contacts P1 lights; the areas by count and by region.
"""
from __future__ import annotations

import argparse
import json
import math
import time
from dataclasses import replace

import numpy as np

from bench.bust_touch import (
    POSES,
    SHOULDER_DISTANCE_MM,
    SHOULDER_Z_MM,
    bust_rows,
    log,
    look_camera,
    planar_rows,
    summarize,
    touch_points,
)
from bench.machine import machine
from imaging.calibration.threed import Pinhole as CoordPinhole
from coordinator.coverage import CoverageModel, Projector
from sim.precompute import MESH
from sim.room import Room
from sim.scene import SUBSETS, reference_scene

EXAMPLES = """examples:
  shadowless bench bust --quick                  a smoke run (4 sampled touches, small cameras)
  nice shadowless bench bust --touches 45        the study: 48 touches, P1 and P25, coverage vs shadow
  shadowless bench bust --pose reach normal      the natural reach and the finger along the normal
"""


def configure(parser: argparse.ArgumentParser) -> None:
    parser.epilog = EXAMPLES
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("--touches", type=int, default=45, help="sampled touch points besides the 3 named ones (default 45)")
    parser.add_argument("--pose", nargs="+", choices=POSES, default=["reach"],
                        help="hand poses: reach (the person beside the bust reaches in; the study's pose), normal "
                             "(finger along the inward normal), above (halfway to straight down); default reach")
    parser.add_argument("--shoulder-distance", type=float, default=SHOULDER_DISTANCE_MM,
                        help=f"the participant's shoulder from the bust's axis, mm (default {SHOULDER_DISTANCE_MM:.0f})")
    parser.add_argument("--shoulder-z", type=float, default=SHOULDER_Z_MM,
                        help=f"the shoulder above the table top, mm (default {SHOULDER_Z_MM:.0f}: 1.4 m above a floor 0.75 m below the table top)")
    parser.add_argument("--projector-scale", type=float, default=0.25, help="projector resolution vs 1280x800 (default 0.25)")
    parser.add_argument("--camera-px", type=int, default=200, help="each touch camera's side, pixels (default 200)")
    parser.add_argument("--fov-mm", type=float, default=150.0, help="a touch camera sees this far either side of the contact (default 150)")
    parser.add_argument("--texture", type=int, default=512, help="coverage texture side, texels (default 512)")
    parser.add_argument("--compare-px", type=int, default=320, help="side of the cameras the coverage is compared through (default 320)")
    parser.add_argument("--quick", action="store_true", help="a smoke run: 4 sampled touches, small cameras and textures")
    parser.add_argument("--seed", type=int, default=0)


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


# ---------------------------------------------------------------------- run
def run(args: argparse.Namespace) -> int:
    if args.quick:
        args.touches, args.camera_px, args.texture, args.compare_px = min(args.touches, 4), 96, 256, 200
        args.projector_scale = min(args.projector_scale, 0.125)
    if args.touches < 0 or args.camera_px < 16 or args.texture < 16 or args.compare_px < 32 or args.fov_mm <= 0:
        raise SystemExit("need --touches >= 0, --camera-px >= 16, --texture >= 16, --compare-px >= 32, --fov-mm > 0")
    if args.shoulder_distance <= 200 or args.shoulder_z <= 0:
        raise SystemExit("need --shoulder-distance > 200 (outside the bust) and --shoulder-z > 0")
    poses = tuple(dict.fromkeys(args.pose))
    shoulder = {"distance": args.shoulder_distance, "z": args.shoulder_z}
    t0 = time.perf_counter()
    scene = reference_scene(projector_scale=args.projector_scale, camera_scale=0.125, surface="bust", seed=args.seed)
    mesh = scene.mesh
    subsets = {"P1": SUBSETS["P1"], "P25": SUBSETS["P25"]}
    room = comparison_room(scene, px=args.compare_px)
    log(f"coverage of {len(subsets['P25'])} projectors on a {args.texture}^2 texture")
    tc = time.perf_counter()
    model = CoverageModel(mesh.vertices, mesh.faces, mesh.uvs, true_projectors(room, subsets["P25"]))
    single = CoverageModel(mesh.vertices, mesh.faces, mesh.uvs, true_projectors(room, subsets["P1"]))
    try:
        cov = model.texture((args.texture, args.texture))
        coverage_s = time.perf_counter() - tc
        log("comparing with the room's truth")
        comparison = compare_coverage(room, model, cov)
        del room
        points = touch_points(mesh, sampled=args.touches, seed=args.seed, poses=poses, **shoulder)
        log(f"{len(points)} touches on the bust")
        rows = bust_rows(scene, model, single, points, subsets, poses=poses, px=args.camera_px, half_mm=args.fov_mm, **shoulder)
    finally:
        model.close()
        single.close()
    log("the same touches on the table")
    table = reference_scene(projector_scale=args.projector_scale, camera_scale=0.125, surface="table", seed=args.seed)
    planar = planar_rows(table, subsets, poses=poses, px=args.camera_px, half_mm=args.fov_mm, **shoulder)
    summary = cov.summary()
    doc = {
        "benchmark": "bust",
        "machine": machine(),
        "params": {"touches": len(rows), "sampled": args.touches, "poses": list(poses), **{f"shoulder_{k}_mm": v for k, v in shoulder.items()},
                   "projector_scale": args.projector_scale, "camera_px": args.camera_px, "fov_mm": args.fov_mm,
                   "texture": args.texture, "compare_px": args.compare_px, "quick": args.quick, "seed": args.seed},
        "coverage": {"seconds": round(coverage_s, 2), "surface_mm2": summary["surface_mm2"],
                     "count_mean": summary["count_mean"], "count_min": summary["count_min"],
                     "count_median": summary["count_median"], "vs_truth": comparison},
        "touches": rows,
        "planar": planar,
        "spearman": {pose: summarize(rows, planar, pose) for pose in poses},
        "seconds": round(time.perf_counter() - t0, 1),
    }
    print(json.dumps(doc, indent=2))
    return 0
