"""`shadowless plan --placement`: where to put the object so that the most projectors reach its
worst point and hands shade the least of it.

The planner sits above the coordinator's coverage model and may not import it; this wiring
judges each placement with it (:class:`coordinator.coverage.CoverageModel`, what `shadowless
coverage` runs) and hands the judge to the planner's search (:mod:`planner.placement`).

Judging a placement: the object's surface is sampled once per texel of its UV texture (the
coverage tool's samples), in the object's own frame; a placement moves the projectors into that
frame instead of the object into the room (the same images), so each placement costs one shadow
map per projector and the reach test, not a new sampling. The chosen placement and the default
one are then judged again at the coverage tool's settings (``--texture``, ``--shadow-scale``,
the layout's resolutions unless ``--resolution``), and the better of the search's best few and
the default wins: the answer is never worse than the default under the tool that checks it.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from coordinator.coverage import CoverageModel, Projector, texel_area
from coordinator.coverage_gl import CoverageRaster
from imaging.calibration.threed import Pinhole
from planner import cli as plan_cli
from planner.placement import Placement, Score, area_quantile, hand_shadow, placed_layout_text, reference_layout, search
from planner.placement_figure import placement_picture
from protos import cli_types
from protos.layout import LayoutFileError, parse_layout
from protos.wording import count
from protos.spaces import scale_intrinsics
from sim.mesh import bust, load_mesh

PLACEMENT_HELP = """\
object placement (--placement): where to put the object on the table
  shadowless plan --placement                          # the bust under the 5x5 ceiling rig
  shadowless plan --placement --room rig.toml --seconds 30 --layout placed.toml --picture placed.png
  shadowless rig init rigs/placed --layout placed.toml --resolution 320x200
  shadowless coverage --rig-dir rigs/placed --planned --texture 128x128   # the coverage tool checks the placement
The projectors stay; the object moves on the table (x, y) and turns about the vertical (no tilt).
Best: the most projectors reaching its worst-reached point (the coverage tool's count_min), then
on all but the worst 5 % of the surface (count_p5), then the least surface left unlit or where a pointing hand takes more than half of the light (hands
around the object at 250 and 420 mm, from six directions), then the most projectors on average.
The search judges placements at --search-texture and --search-resolution; the best three and the
default are judged again at the check's settings, and the default wins unless one beats it there.
"""


@dataclass
class Room:
    """What a placement is judged in: the layout document, the object's mesh in its own frame, the projectors."""

    doc: dict
    vertices: np.ndarray      # (V, 3) float32
    faces: np.ndarray         # (F, 3) uint32
    uvs: np.ndarray           # (V, 2) float32
    devices: list[tuple[str, Pinhole]]   # room frame, native sizes
    table_size: tuple[float, float]
    default: Placement = Placement()   # where the layout puts the object (its [mesh] position and yaw_deg)


def load_room(path: str | None) -> Room:
    """The layout at ``path`` (default: :func:`planner.placement.reference_layout`); its object
    (the bust when it names none) in its own frame, scaled but neither moved nor turned; where the
    layout puts it (its z offset is dropped: the object stands on the table) is the default placement."""
    if path is None:
        doc = reference_layout()
        base = Path.cwd()
    else:
        try:
            doc = tomllib.loads(Path(path).read_text())
        except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
            raise SystemExit(f"cannot read layout {path}: {exc}") from None
        base = Path(path).parent
    try:
        layout = parse_layout(doc, base=base, path=Path(path) if path else None)
    except (LayoutFileError, ValueError, TypeError, KeyError) as exc:
        raise SystemExit(f"layout {path}: {exc}") from None
    spec = layout.mesh
    if spec is None or spec.builtin == "bust":
        m = bust()
        v, f, uv = m.vertices, m.faces, m.uvs
    else:
        try:
            m = load_mesh(spec.path)
        except (OSError, ValueError) as exc:
            raise SystemExit(f"cannot read the layout's mesh {spec.path}: {exc}") from None
        v, f, uv = m.vertices, m.faces, m.uvs
        if uv is None:
            raise SystemExit(f"mesh {spec.path} has no texture coordinates: coverage is counted per texel")
    scale = spec.scale if spec is not None else 1.0
    if doc.get("mesh") is None:
        doc = {**doc, "mesh": {"builtin": "bust"}}
    devices = [(d.name, Pinhole(d.K, d.R, d.t, d.size)) for d in layout.projectors]
    table = layout.table.size if layout.table is not None else (1200.0, 600.0)
    default = Placement(float(spec.position[0]), float(spec.position[1]), spec.yaw_deg) if spec is not None and spec.placed else Placement()
    return Room(doc, (np.asarray(v, np.float64) * scale).astype(np.float32), np.asarray(f, np.uint32),
                np.asarray(uv, np.float32), devices, tuple(table), default)


class Judge:
    """Scores placements of ``room``'s object with the coverage model.

    Parameters
    ----------
    resolution : (w, h) or None
        Projector images sampled at this size (None: the layout's).
    texture : (w, h) texels sampled over the object
    shadow_scale : shadow-map pixels per projector pixel and axis
    hand_samples : about how many texels the hand-shadow proxy samples
    """

    def __init__(self, room: Room, *, resolution: tuple[int, int] | None, texture: tuple[int, int], shadow_scale: int,
                 hand_samples: int = 500):
        self.room, self.shadow_scale = room, shadow_scale
        self.devices = [(s, d if resolution is None else Pinhole(scale_intrinsics(d.K, d.size, resolution), d.R, d.t, resolution))
                        for s, d in room.devices]
        raster = CoverageRaster(room.vertices, room.faces, room.uvs)
        try:
            pts, nrm, face, hit = raster.texels(texture)
            area = np.zeros(hit.shape, np.float64)
            area[hit] = texel_area(raster.vertices, raster.faces, raster.uvs, texture)[face[hit]]
        finally:
            raster.close()
        mask = hit & (area > 0)
        self.points = pts[mask].astype(np.float64)
        self.normals = nrm[mask].astype(np.float64)
        self.area = area[mask]
        stride = max(1, len(self.points) // hand_samples)
        self.hand_idx = np.arange(0, len(self.points), stride)
        self.evaluations = 0
        self._counts: dict[Placement, np.ndarray] = {}

    def coverage(self, p: Placement):
        """(count (n,) int, irradiance (S, n) float64) of the texels with the object at ``p``."""
        projectors = []
        for slot, d in self.devices:
            R, t = p.device_in_object_frame(d.R, d.t)
            projectors.append(Projector(slot, Pinhole(d.K, R, t, d.size)))
        with CoverageModel(self.room.vertices, self.room.faces, self.room.uvs, projectors, shadow_scale=self.shadow_scale) as model:
            pc = model.at_points(self.points, self.normals)
        return pc.count, pc.irradiance

    def __call__(self, p: Placement) -> Score:
        self.evaluations += 1
        count, E = self.coverage(p)
        self._counts[p] = count
        lit = count > 0
        a = self.area
        total = float(a.sum())
        idx = self.hand_idx
        centers = np.array([p.to_room(d.center[None])[0] for _, d in self.devices])
        world = p.to_room(self.points[idx])
        shadow = hand_shadow(world, a[idx], E[:, idx], centers, p)
        return Score(int(count[lit].min()) if lit.any() else 0, 100.0 * float(a[~lit].sum()) / total, shadow,
                     float((count * a)[lit].sum() / a[lit].sum()) if lit.any() else 0.0, area_quantile(count[lit], a[lit], 0.05))

    def count_map(self, p: Placement) -> tuple[np.ndarray, np.ndarray]:
        """(room points (n, 3) float64, count (n,) int) for the picture."""
        count = self._counts[p] if p in self._counts else self.coverage(p)[0]
        return p.to_room(self.points), count


def configure(parser: argparse.ArgumentParser) -> None:
    plan_cli.configure(parser)
    parser.epilog = (parser.epilog or "") + "\n" + PLACEMENT_HELP
    g = parser.add_argument_group("object placement (with --placement; --layout and --picture default to placement.toml, placement.png)")
    g.add_argument("--placement", action="store_true", help="place the object under a given rig instead of planning projectors")
    g.add_argument("--room", type=cli_types.existing_file, metavar="LAYOUT",
                   help="the layout whose projectors stay and whose object moves (default: the 5x5 ceiling rig with the bust)")
    g.add_argument("--seconds", type=cli_types.number(1, 3600), default=40.0, metavar="S", help="time budget of the search; the final check comes after it (default 40)")
    g.add_argument("--step", type=cli_types.number(10, 1000), default=200.0, metavar="MM", help="coarse grid spacing (default 200)")
    g.add_argument("--turns", type=cli_types.int_range(1, 72), default=6, metavar="N", help="coarse turns of the object, evenly over 360 deg (default 6)")
    g.add_argument("--rounds", type=cli_types.int_range(0, 10), default=3, metavar="N",
                   help="finer rounds after the coarse grid, each halving the steps (default 3)")
    g.add_argument("--search-texture", type=cli_types.size, default=(64, 64), metavar="WxH", help="texels while searching (default 64x64)")
    g.add_argument("--search-resolution", type=cli_types.size, default=(320, 200), metavar="WxH",
                   help="projector images while searching (default 320x200)")
    g.add_argument("--texture", type=cli_types.size, default=(128, 128), metavar="WxH",
                   help="texels of the final check, as `shadowless coverage --texture` (default 128x128)")
    g.add_argument("--check-resolution", type=cli_types.size, default=(320, 200), metavar="WxH",
                   help="projector images of the final check, as `rig init --layout FILE --resolution WxH` gives (default 320x200)")
    g.add_argument("--shadow-scale", type=cli_types.int_range(1, 8), default=2, metavar="N",
                   help="shadow-map pixels per projector pixel of the final check, as `shadowless coverage` (default 2)")


def run(args: argparse.Namespace) -> int:
    if not args.placement:
        return plan_cli.run(args)
    return run_placement(args)


def _say(text: str) -> None:
    print(f"placement: {text}", file=sys.stderr, flush=True)


def run_placement(args: argparse.Namespace) -> int:
    doc = place(args, say=_say)
    if args.json:
        print(json.dumps(doc, indent=1))
        return 0
    c, d = doc["chosen"], doc["default"]
    for label, s in (("chosen", c), ("default", d)):
        print(f"{label}: x {s['x_mm']:.0f} mm, y {s['y_mm']:.0f} mm, yaw {s['yaw_deg']:.0f} deg: every lit point reached by at least "
              f"{count(s['count_min'], 'projector')} ({s['count_p5']} on all but the worst 5 %), {s['unlit_pct']:.1f}% unlit, "
              f"{s['hand_shadow_pct']:.1f}% under a hand's deep shadow, {s['count_mean']:.2f} projectors on average")
    print(f"searched {doc['evaluated']} placements in {doc['search_seconds']:.1f} s"
          f"{' (time budget reached)' if doc['stopped_early'] else ''}; wrote {doc['layout']} and {doc['picture']}")
    print(f"check it: {doc['check_command']}")
    return 0


def place(args: argparse.Namespace, *, say=lambda text: None) -> dict:
    """Search, check, write the layout and the picture; the figures (JSON-able)."""
    t0, cpu0 = time.perf_counter(), time.process_time()
    layout_out = Path("placement.toml" if args.layout == "plan.toml" else args.layout)
    picture_out = Path("placement.png" if args.picture == "plan.png" else args.picture)
    room = load_room(args.room)
    say(f"{len(room.devices)} projectors, object of {len(room.faces)} triangles on a "
        f"{room.table_size[0]:.0f} x {room.table_size[1]:.0f} mm table")
    quick = Judge(room, resolution=tuple(args.search_resolution), texture=tuple(args.search_texture), shadow_scale=1)
    default = room.default
    result = search(quick, room.vertices, room.table_size, step_mm=args.step, yaws=args.turns, rounds=args.rounds, seconds=args.seconds,
                    include=(default,), progress=say)
    say(f"searched {len(result.evaluated)} placements in {result.seconds:.1f} s"
        + (" (time budget reached)" if result.stopped_early else ""))
    final = Judge(room, resolution=tuple(args.check_resolution),
                  texture=tuple(args.texture), shadow_scale=args.shadow_scale)
    top = [p for p, _ in sorted(result.evaluated, key=lambda ps: ps[1].key, reverse=True)[:3]]
    checked = {default: final(default)}
    for p in top:
        if p not in checked:
            checked[p] = final(p)
    say(f"checked the best {len(top)} and the default at the coverage tool's settings")
    chosen = max(checked, key=lambda p: checked[p].key)   # dicts keep order: the default wins ties
    res = f"{args.check_resolution[0]}x{args.check_resolution[1]}"
    header = (f"placed by shadowless plan --placement: {chosen}\n"
              f"check: shadowless rig init DIR --layout {layout_out.name} --resolution {res} && shadowless coverage --rig-dir DIR --planned "
              f"--texture {args.texture[0]}x{args.texture[1]} --shadow-scale {args.shadow_scale}")
    layout_out.write_text(placed_layout_text(room.doc, chosen, header=header))
    pts_d, cnt_d = final.count_map(default)
    pts_c, cnt_c = final.count_map(chosen)
    placement_picture(picture_out, room.table_size, room.vertices, [("default", default, pts_d, cnt_d), ("chosen", chosen, pts_c, cnt_c)],
                      max_count=len(room.devices))
    doc = {
        "room": args.room or "reference 5x5 ceiling rig, bust", "projectors": len(room.devices),
        "chosen": {**chosen.as_dict(), **checked[chosen].as_dict()},
        "default": {**default.as_dict(), **checked[default].as_dict()},
        "min_coverage_chosen": checked[chosen].count_min, "min_coverage_default": checked[default].count_min,
        "evaluated": len(result.evaluated), "search_seconds": round(result.seconds, 1), "stopped_early": result.stopped_early,
        "search": {"texture": list(args.search_texture), "resolution": list(args.search_resolution), "shadow_scale": 1},
        "check": {"texture": list(args.texture), "resolution": list(args.check_resolution),
                  "shadow_scale": args.shadow_scale},
        "tilt": "none: the object stands on its base",
        "layout": str(layout_out), "picture": str(picture_out), "seconds": round(time.perf_counter() - t0, 1),
        "cpu_seconds": round(time.process_time() - cpu0, 1),
        "check_command": f"shadowless rig init DIR --layout {layout_out} --resolution {res} && shadowless coverage --rig-dir DIR "
                         f"--planned --texture {args.texture[0]}x{args.texture[1]} --shadow-scale {args.shadow_scale}",
    }
    return doc
