"""`shadowless bench specular`: the highlights a glossy table shows an observer under P1, P9 and P25.

The paper observes that 25 projectors suppress specular reflections: each lens is one
twenty-fifth as bright as a single projector giving the same light, so each highlight (a
reflection of one lens) is one twenty-fifth as bright. This benchmark measures it in the virtual
room with a glossy table (:mod:`sim.specular`, Blinn-Phong, ``--gloss``) seen by an observer at a
chosen point (:mod:`sim.observer`, ``--observer``).

Set-up (stated before any figure was measured):

* The reference rig without mounting jitter, every lens of the 5 x 5 array equal (peak 1); the
  single bright unit ``p1`` at the array's centre. Every projector shows full white.
* **Matched brightness**: every configuration gives the same diffuse light at the table's centre
  (as the room's ``p1`` is defined): the lamps of the brighter configurations are dimmed to the
  dimmest one's level there. The check, ``diffuse_over_P1``, is measured at that point.
* The observer's linear signal (no noise, no clipping) is rendered twice, with the gloss and
  without; their difference is the **specular excess**. ``d`` is the diffuse signal at the table's
  centre. The **peak** is the largest excess over ``d``; the **area** is the table area (mm^2,
  each pixel's footprint) where the excess is above ``--threshold`` x ``d``; the **highlights** are
  the 8-connected regions of that area.

The closed form (the table is a plane z = 0, the lens a point light at its optical centre):

* Lens ``i``'s highlight peaks at its mirror point ``x_i`` (where ``N.H = 1``: the eye sees the
  lens's mirror image through the table), so its peak over ``d`` is
  ``P_i = k_s (n + 8) / 8 * E_i(x_i) / (albedo * sum_j E_j(c))`` with ``E`` the irradiance of
  :func:`sim.optics.irradiance_factor` times the lens's power and ``c`` the table's centre. For N
  equal lenses in one place this is ``1/N`` of P1's: **a highlight from one of N equal lenses
  carries 1/N of the light**. The array's lenses are not in one place: a lens off the centre adds
  less light at ``c`` than on its own highlight, so the configuration's peak,
  ``max_i P_i``, is a little above ``1/N`` of P1's; ``closed_form`` is that ratio with the
  lenses' geometry, ``one_over_n`` the plain ``1/N``.
* **Area.** Near its peak the lobe is a Gaussian in the half-vector angle a, ``(N.H)^n ~
  exp(-n a^2 / 2)``, so a highlight of peak ``P`` is above ``tau`` where ``sin^2 a < 1 -
  (tau / P)^(2/n)``, an ellipse on the table of area ``pi sin^2 a / |det J|`` (``J`` the
  derivative of the half vector's tangential part along the table): about ``(2 pi / n) ln(P /
  tau) / |det J|``. Each highlight therefore shrinks only as the logarithm of its peak, while
  their count grows as N: the total area grows roughly as ``N ln(P_1 / (N tau)) / ln(P_1 / tau)``
  times P1's, until ``P_1 / N`` falls below ``tau`` and every highlight vanishes at once.
  Valid while the highlights stay apart (``neighbour_lobe_share``: the largest share of a
  highlight's peak that the other lenses' lobes add there). Where they overlap (a rougher coat,
  ``--gloss table:0.1:0.05``), ``closed_form_overlapping`` adds the other lenses' lobes at each
  mirror point, and the highlights merge into one glow (``highlights_merged``).

JSON: per configuration the measured and closed-form peak and area, the highlight count, the
per-highlight errors; ``P25_peak_over_P1``, ``closed_form_error`` (the largest relative error of a
measured peak ratio against the closed form), the issue's target (P25's peak at most 1.2 x P1's
/ 25) and whether it is met, and ``lobe_check`` (the render against a brute-force evaluation of
the BRDF at a few pixels of P1's highlight).
"""
from __future__ import annotations

import argparse
import json
import math
import time
from dataclasses import replace

import cv2
import numpy as np

from bench.machine import machine
from sim.observer import OBSERVER_SIZE, parse_point, with_observer
from sim.optics import irradiance_factor
from sim.room import Room
from sim.scene import SUBSETS, Scene, reference_scene
from sim.specular import Gloss, parse_gloss

#: The glossy coat unless told: a varnished table (k_s 0.1, roughness 0.02: its highlights stay apart).
DEFAULT_GLOSS = "table:0.1:0.02"
#: The observer unless told: an eye 900 mm above the table, leaning over its middle.
DEFAULT_OBSERVER = "0,-60,900"
#: Highlight area: where the specular excess is above this share of the diffuse level.
DEFAULT_THRESHOLD = 0.25
#: The configurations unless told (P9 is the dense centre 3 x 3).
DEFAULT_SUBSETS = ("P1", "P9D", "P25")
#: The issue's target: P25's peak at most this times P1's / 25.
TARGET_FACTOR = 1.2

EXAMPLES = """examples:
  shadowless bench specular                                   P1, P9 (dense) and P25, a varnished table
  shadowless bench specular --gloss table:0.05:0.05           a satin table
  shadowless bench specular --observer 0,-200,700 --threshold 0.5
"""


def configure(parser: argparse.ArgumentParser) -> None:
    parser.epilog = EXAMPLES
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("--gloss", default=DEFAULT_GLOSS, metavar="table:STRENGTH:ROUGHNESS",
                        help=f"the table's coat, table:STRENGTH:ROUGHNESS (strength 0..1, the share of the light the lobe "
                             f"reflects; roughness 0..1, 0.02 varnish, 0.05 satin; default {DEFAULT_GLOSS})")
    parser.add_argument("--observer", default=DEFAULT_OBSERVER, metavar="X,Y,Z",
                        help=f"the observer's eye X,Y,Z in mm (table centre at 0,0,0, projectors 1400 mm up; default {DEFAULT_OBSERVER})")
    parser.add_argument("--observer-px", default=f"{OBSERVER_SIZE[0]}x{OBSERVER_SIZE[1]}", metavar="WxH",
                        help="the observer's image, WIDTHxHEIGHT pixels (default %(default)s)")
    parser.add_argument("--threshold", type=float, default=DEFAULT_THRESHOLD, metavar="F",
                        help=f"a highlight is where the specular excess is above this share of the diffuse level (default {DEFAULT_THRESHOLD})")
    parser.add_argument("--subsets", default=",".join(DEFAULT_SUBSETS), metavar="NAMES",
                        help=f"configurations, comma-separated, the first the reference (names: {', '.join(SUBSETS)}; default %(default)s)")
    parser.add_argument("--projector-scale", type=float, default=0.25, metavar="S", help="projector resolution vs 1280x800 (default 0.25)")
    parser.add_argument("--picture", metavar="FILE.png",
                        help="also write what the observer sees under each configuration, side by side (log scale: "
                             "black, the diffuse light, P1's peak white)")


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in str(text).lower().split("x"))
    except ValueError:
        raise ValueError(f"observer image {text!r} must be WIDTHxHEIGHT, e.g. 480x360") from None
    if w < 8 or h < 8:
        raise ValueError(f"observer image {text!r} must be at least 8x8 pixels")
    return w, h


def label(name: str) -> str:
    """The configuration's name in the JSON: "P9D" -> "P9" (the dense 3 x 3), others as they are."""
    return "P9" if name == "P9D" else name


# ---------------------------------------------------------------- the rig


def equal_lens_scene(projector_scale: float) -> Scene:
    """The reference rig, table only, no jitter, every array lens of peak 1 and ``p1`` as bright at the
    table's centre as the 25 together."""
    scene = reference_scene(projector_scale, 0.125, surface="table", jitter=False)
    centre, up = np.zeros(3), np.array([0.0, 0.0, 1.0])
    rig = [replace(p, peak=1.0) for p in scene.projectors if p.slot != "p1"]
    total = sum(float(irradiance_factor(p.native.center, p.native.axis, centre, up, falloff=p.falloff)) for p in rig)
    p1 = scene.projector("p1")
    own = float(irradiance_factor(p1.native.center, p1.native.axis, centre, up, falloff=p1.falloff))
    return replace(scene, projectors=tuple(rig) + (replace(p1, peak=total / own),))


def centre_light(scene: Scene, slots) -> float:
    """Sum of the lenses' irradiance x peak at the table's centre (closed form)."""
    centre, up = np.zeros(3), np.array([0.0, 0.0, 1.0])
    return sum(p.peak * float(irradiance_factor(p.native.center, p.native.axis, centre, up, falloff=p.falloff))
               for p in (scene.projector(s) for s in slots))


def matched_lamps(scene: Scene, configs: dict[str, list[str]]) -> dict[str, float]:
    """The lamp of every configuration's lenses for the same diffuse light at the table's centre (all <= 1)."""
    light = {name: centre_light(scene, slots) for name, slots in configs.items()}
    level = min(light.values())
    return {name: level / v for name, v in light.items()}


# ---------------------------------------------------------------- the closed form


def mirror_point(lens: np.ndarray, eye: np.ndarray) -> np.ndarray:
    """(3,) where ``eye`` sees ``lens``'s mirror image in the table plane z = 0."""
    image = np.array([lens[0], lens[1], -lens[2]])
    t = eye[2] / (eye[2] + lens[2])
    return eye + t * (image - eye)


def _half_tangent(lens: np.ndarray, eye: np.ndarray, x: float, y: float) -> np.ndarray:
    p = np.array([x, y, 0.0])
    li = (lens - p) / np.linalg.norm(lens - p)
    vi = (eye - p) / np.linalg.norm(eye - p)
    h = (li + vi) / np.linalg.norm(li + vi)
    return h[:2]


def highlight_closed_form(lens, axis, falloff: float, power: float, eye, *, strength: float, roughness: float,
                          diffuse: float, threshold: float) -> dict:
    """Lens's highlight on the table: where (mm), its peak over the diffuse level and its area above threshold.

    Parameters
    ----------
    lens, axis : (3,) float64
        The lens's centre (mm) and unit axis.
    power : float
        Its peak x lamp.
    diffuse : float
        albedo x the configuration's irradiance at the table's centre (the diffuse level before the gain).
    """
    lens, eye = np.asarray(lens, np.float64), np.asarray(eye, np.float64)
    n = 2.0 / roughness**2 - 2.0
    x = mirror_point(lens, eye)
    e = power * float(irradiance_factor(lens, axis, x, np.array([0.0, 0.0, 1.0]), falloff=falloff))
    peak = strength * (n + 8.0) / 8.0 * e / diffuse
    area = 0.0
    if peak > threshold:
        s2 = 1.0 - (threshold / peak) ** (2.0 / n)
        h = 0.05
        J = np.column_stack([(_half_tangent(lens, eye, x[0] + h, x[1]) - _half_tangent(lens, eye, x[0] - h, x[1])) / (2 * h),
                             (_half_tangent(lens, eye, x[0], x[1] + h) - _half_tangent(lens, eye, x[0], x[1] - h)) / (2 * h)])
        area = math.pi * s2 / abs(float(np.linalg.det(J)))
    return {"point": x, "irradiance": e, "peak": peak, "area_mm2": area}


def lobe_at(lens, eye, point, *, strength: float, roughness: float) -> float:
    """``pi f_s`` of one lens at one table point, written out with the math module (the brute-force reference)."""
    n = 2.0 / roughness**2 - 2.0
    lx, ly, lz = (float(lens[k]) - float(point[k]) for k in range(3))
    vx, vy, vz = (float(eye[k]) - float(point[k]) for k in range(3))
    dl, dv = math.sqrt(lx * lx + ly * ly + lz * lz), math.sqrt(vx * vx + vy * vy + vz * vz)
    hx, hy, hz = lx / dl + vx / dv, ly / dl + vy / dv, lz / dl + vz / dv
    if lz <= 0 or vz <= 0:
        return 0.0
    n_dot_h = hz / math.sqrt(hx * hx + hy * hy + hz * hz)  # the table's normal is +z
    return strength * (n + 8.0) / 8.0 * n_dot_h**n


# ---------------------------------------------------------------- measuring


def _bilinear(img: np.ndarray, x: float, y: float) -> float:
    x0, y0 = int(math.floor(x)), int(math.floor(y))
    fx, fy = x - x0, y - y0
    return float((1 - fx) * (1 - fy) * img[y0, x0] + fx * (1 - fy) * img[y0, x0 + 1]
                 + (1 - fx) * fy * img[y0 + 1, x0] + fx * fy * img[y0 + 1, x0 + 1])


def _pixel_areas(room: Room, camera: int) -> np.ndarray:
    """(H, W) float64 table mm^2 each observer pixel covers (0 where it sees nothing)."""
    view = room.view(camera)
    W, H = room.camera_size(camera)
    out = np.zeros((H, W))
    x0, y0, x1, y1 = view.roi
    out[y0:y1, x0:x1] = np.where(np.isfinite(view.cam_area), view.cam_area, 0.0)
    return out


def _render(room: Room, slots: list[str], lamp: float, camera: int) -> np.ndarray:
    room.set_active(slots)
    for s in slots:
        room.set_lamp(s, lamp)
    return room.render_linear(camera)[:, :, 1].astype(np.float64)


def specular_figures(*, gloss: Gloss, observer, observer_px=OBSERVER_SIZE, threshold: float = DEFAULT_THRESHOLD,
                     subsets=DEFAULT_SUBSETS, projector_scale: float = 0.25, picture: str | None = None) -> dict:
    """Everything the benchmark reports (the JSON document without the machine), for the configurations
    named in ``subsets`` (the first is the reference the ratios are taken to); with ``picture``, also the
    observer's views side by side in that PNG file."""
    if gloss.surface != "table":
        raise ValueError(f"bench specular measures a glossy table; --gloss {gloss} is on the {gloss.surface}")
    if not 0 < observer[2] < 1400:
        raise ValueError(f"the observer's eye must be above the table and below the projectors (0 < Z < 1400 mm), got Z = {observer[2]:g}")
    t0 = time.perf_counter()
    base = with_observer(equal_lens_scene(projector_scale), observer, size=observer_px)
    obs = len(base.cameras) - 1
    plain, glossy = Room(base, noise=False), Room(replace(base, gloss=(gloss,)), noise=False)
    for room in (plain, glossy):
        for s in room.all_slots:
            w, h = room.projector_size(s)
            room.set_frame(s, np.full((h, w, 3), 255, np.uint8))
    configs = {name: list(SUBSETS[name]) for name in subsets}
    lamps = matched_lamps(base, configs)
    cam = base.camera(obs)
    pinhole = cam.pinhole
    eye = pinhole.center
    gain = cam.gain * cam.exposure
    albedo = base.table.albedo
    tw, th = base.table.size
    centre_px, _ = pinhole.project(np.zeros((1, 3)))
    areas = _pixel_areas(glossy, obs)
    n = gloss.exponent
    results, lobe_check, reference, views = {}, None, None, []
    for name, slots in configs.items():
        lamp = lamps[name]
        diffuse_img = _render(plain, slots, lamp, obs)
        glossy_img = _render(glossy, slots, lamp, obs)
        excess = glossy_img - diffuse_img
        views.append((label(name), glossy_img))
        d = _bilinear(diffuse_img, float(centre_px[0, 0]), float(centre_px[0, 1]))
        d_closed = albedo * lamp * centre_light(base, slots)
        mask = (excess > threshold * d).astype(np.uint8)
        count, labels = cv2.connectedComponents(mask, connectivity=8)
        lenses, merged = [], 0
        seen_labels: dict[int, int] = {}
        for s in slots:
            p = base.projector(s)
            hl = highlight_closed_form(p.native.center, p.native.axis, p.falloff, p.peak * lamp, eye, strength=gloss.strength,
                                       roughness=gloss.roughness, diffuse=d_closed, threshold=threshold)
            x = hl["point"]
            on_table = abs(x[0]) <= tw / 2 and abs(x[1]) <= th / 2
            pix, _ = pinhole.project(x[None, :])
            px, py = int(round(pix[0, 0])), int(round(pix[0, 1]))
            in_view = on_table and 1 <= px < pinhole.size[0] - 1 and 1 <= py < pinhole.size[1] - 1
            row = {"slot": s, "mirror_point_mm": [round(float(v), 1) for v in x[:2]], "in_view": bool(in_view),
                   "peak_closed_form": hl["peak"], "area_mm2_closed_form": hl["area_mm2"]}
            if in_view:
                # its peak: the largest excess within 3 pixels of where the closed form puts it
                row["peak"] = float(excess[max(py - 3, 0):py + 4, max(px - 3, 0):px + 4].max()) / d
                lab = int(labels[py, px])
                row["area_mm2"] = float(areas[labels == lab].sum()) if lab else 0.0
                row["_label"] = lab
                if lab:
                    seen_labels[lab] = seen_labels.get(lab, 0) + 1
                row["peak_error"] = row["peak"] / row["peak_closed_form"] - 1.0
                # the other lenses' lobes at this highlight's peak, as a share of its own
                own = lobe_at(p.native.center, eye, x, strength=gloss.strength, roughness=gloss.roughness) * hl["irradiance"]
                others = sum(lobe_at(q.native.center, eye, x, strength=gloss.strength, roughness=gloss.roughness)
                             * q.peak * lamp * float(irradiance_factor(q.native.center, q.native.axis, x, np.array([0.0, 0.0, 1.0]), falloff=q.falloff))
                             for q in (base.projector(o) for o in slots if o != s))
                row["neighbour_lobe_share"] = others / own if own > 0 else None
            lenses.append(row)
        merged = sum(v for v in seen_labels.values() if v > 1)
        for r in lenses:  # a region holding several lenses' highlights is no one lens's area
            if seen_labels.get(r.pop("_label", 0), 0) > 1:
                r["area_mm2"] = None
        visible = [r for r in lenses if r["in_view"]]
        peak = float(excess.max()) / d
        peak_closed = max((r["peak_closed_form"] for r in visible), default=0.0)
        results[name] = {
            "subset": name, "lenses": len(slots), "lamp": lamp,
            "diffuse_level": d, "diffuse_closed_form_error": d / (gain * d_closed) - 1.0,
            "peak": peak, "peak_closed_form": peak_closed, "peak_error": peak / peak_closed - 1.0 if peak_closed else None,
            "peak_at_mm": [round(float(v), 1) for v in _surface_point(pinhole, np.unravel_index(int(np.argmax(excess)), excess.shape))],
            "area_px": int(mask.sum()), "area_mm2": float(areas[mask.astype(bool)].sum()),
            "area_mm2_closed_form": float(sum(r["area_mm2_closed_form"] for r in visible)),
            "highlights": int(count - 1), "highlights_closed_form": int(sum(1 for r in visible if r["peak_closed_form"] > threshold)),
            "highlights_merged": merged, "lenses_not_in_view": len(lenses) - len(visible),
            "per_highlight_peak_error_max": max((abs(r["peak_error"]) for r in visible), default=None),
            # where the lobes overlap: each highlight's peak with the other lenses' lobes there added
            "peak_closed_form_overlapping": max((r["peak_closed_form"] * (1.0 + (r["neighbour_lobe_share"] or 0.0)) for r in visible), default=0.0),
            "neighbour_lobe_share_max": max((r["neighbour_lobe_share"] or 0.0 for r in visible), default=None),
            "per_lens": lenses,
        }
        if reference is None:
            reference = name
            lobe_check = _lobe_check(excess, pinhole, base, slots, lamp, gain, gloss)
    ref = results[reference]
    for name, r in results.items():
        r["peak_over_reference"] = r["peak"] / ref["peak"]
        r["closed_form"] = r["peak_closed_form"] / ref["peak_closed_form"]
        r["one_over_n"] = ref["lenses"] / r["lenses"]
        r["closed_form_error"] = r["peak_over_reference"] / r["closed_form"] - 1.0
        r["error_vs_one_over_n"] = r["peak_over_reference"] / r["one_over_n"] - 1.0
        r["closed_form_overlapping"] = r["peak_closed_form_overlapping"] / ref["peak_closed_form_overlapping"]
        r["closed_form_overlapping_error"] = r["peak_over_reference"] / r["closed_form_overlapping"] - 1.0
        r["area_over_reference"] = r["area_mm2"] / ref["area_mm2"] if ref["area_mm2"] else None
        r["area_error"] = r["area_mm2"] / r["area_mm2_closed_form"] - 1.0 if r["area_mm2_closed_form"] else None
        # the area's rule of thumb: N highlights, each of area proportional to ln(peak / threshold)
        r["area_over_reference_log_law"] = (r["lenses"] * math.log(r["peak_closed_form"] / threshold) / math.log(ref["peak_closed_form"] / threshold)
                                            if r["peak_closed_form"] > threshold and ref["peak_closed_form"] > threshold else 0.0)
        r["diffuse_over_reference"] = r["diffuse_level"] / ref["diffuse_level"]
    doc = {
        "benchmark": "specular",
        "gloss": {"surface": gloss.surface, "strength": gloss.strength, "roughness": gloss.roughness,
                  "model": "Blinn-Phong, energy-normalised: k_s (n + 8) / (8 pi) (N.H)^n", "exponent_n": n},
        "observer_mm": [float(v) for v in eye], "observer_px": list(pinhole.size), "threshold": threshold,
        "reference": reference, "configurations": {label(k): v for k, v in results.items()},
        "lobe_check": lobe_check,
        "closed_form_error": max((abs(r["closed_form_error"]) for k, r in results.items() if k != reference), default=0.0),
    }
    if reference == "P1" and "P25" in results:
        ratio = results["P25"]["peak_over_reference"]
        doc["P25_peak_over_P1"] = ratio
        doc["P25_peak_over_P1_target_max"] = TARGET_FACTOR / 25
        doc["P25_target_met"] = bool(ratio <= TARGET_FACTOR / 25)
    doc["closed_form_within_5_percent"] = bool(doc["closed_form_error"] <= 0.05)
    if picture:
        write_picture(picture, views, diffuse=ref["diffuse_level"], top=ref["peak"] + 1.0)
        doc["picture"] = str(picture)
    doc["seconds"] = round(time.perf_counter() - t0, 2)
    return doc


def write_picture(path: str, views: list[tuple[str, np.ndarray]], *, diffuse: float, top: float) -> None:
    """The observer's views side by side, each (H, W) float64 signal on a log scale: 0 black, ``top`` x
    ``diffuse`` white, named in its corner."""
    panels = []
    for name, img in views:
        v = np.log1p(np.maximum(img, 0.0) / diffuse) / math.log1p(top)
        panel = np.clip(v * 255.0, 0, 255).astype(np.uint8)
        panel = cv2.cvtColor(panel, cv2.COLOR_GRAY2BGR)
        cv2.putText(panel, name, (8, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (0, 200, 255), 2, cv2.LINE_AA)
        panels.append(panel)
    if not cv2.imwrite(str(path), np.concatenate(panels, axis=1)):
        raise ValueError(f"cannot write the picture {path}")


def _surface_point(pinhole, yx) -> np.ndarray:
    """(2,) table mm (x, y) an observer pixel ``(row, col)`` sees."""
    ray = pinhole.rays(np.array([[float(yx[1]), float(yx[0])]]))[0]
    c = pinhole.center
    return (c + (-c[2] / ray[2]) * ray)[:2]


def _lobe_check(excess: np.ndarray, pinhole, scene: Scene, slots: list[str], lamp: float, gain: float, gloss: Gloss) -> dict:
    """The rendered excess of the reference configuration (one lens) at five pixels of its highlight (its peak
    and where it falls to about 1/2, 1/10, 1/100 and 1/1000 of it) against the BRDF written out per pixel."""
    if len(slots) != 1:
        return {"skipped": "the reference configuration has more than one lens"}
    p = scene.projector(slots[0])
    top = float(excess.max())
    flat = excess.reshape(-1)
    picks = [int(np.argmax(flat))] + [int(np.argmin(np.abs(flat - top * f))) for f in (0.5, 0.1, 0.01, 0.001)]
    W = excess.shape[1]
    rows, worst = [], 0.0
    for k in picks:
        y, x = divmod(k, W)
        ray = pinhole.rays(np.array([[float(x), float(y)]]))[0]
        c = pinhole.center
        point = c + (-c[2] / ray[2]) * ray
        e = p.peak * lamp * float(irradiance_factor(p.native.center, p.native.axis, point, np.array([0.0, 0.0, 1.0]), falloff=p.falloff))
        expected = gain * e * lobe_at(p.native.center, c, point, strength=gloss.strength, roughness=gloss.roughness)
        err = float(flat[k]) / expected - 1.0
        worst = max(worst, abs(err))
        rows.append({"pixel": [x, y], "share_of_peak": float(flat[k]) / top, "rendered": float(flat[k]), "brute_force": expected, "error": err})
    return {"pixels": rows, "max_error": worst}


def run(args: argparse.Namespace) -> int:
    try:
        gloss = parse_gloss(args.gloss)
        observer = parse_point(args.observer, what="observer")
        size = _size(args.observer_px)
        subsets = [s.strip() for s in args.subsets.split(",") if s.strip()]
        unknown = [s for s in subsets if s not in SUBSETS]
        if unknown or not subsets:
            raise ValueError(f"unknown configuration {', '.join(unknown) or '(none)'}; the names are {', '.join(SUBSETS)}")
        if not 0 < args.threshold:
            raise ValueError(f"--threshold must be above 0, got {args.threshold}")
        doc = specular_figures(gloss=gloss, observer=observer, observer_px=size, threshold=args.threshold,
                               subsets=subsets, projector_scale=args.projector_scale, picture=args.picture)
    except ValueError as exc:
        raise SystemExit(f"shadowless bench specular: {exc}") from None
    doc["machine"] = machine()
    print(json.dumps(doc, indent=2))
    return 0
