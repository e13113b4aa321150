"""The ``calibrate`` and ``alignment`` coordinator jobs.

``calibrate`` stages (each reports progress per stage and projector):

1. **exposure** - every projector black, then every projector white, per
   camera: fails early and clearly when a camera is under-exposed.
2. **cameras** - the table -> camera mapping of every camera (known points
   from the rig file or a points file, or a ChArUco board lying on the table),
   and for 3D surfaces each camera's pose in the world and the mesh's
   registration. Persisted in ``calibration/cameras.json``.
3. **projectors** -
   *sequential* (the paper's method, the reference): per projector, white and
   black references and the Gray-code patterns; decoded pixels give
   table <-> projector correspondences (planar) or, cast onto the mesh,
   world <-> projector correspondences (3D); a robust fit gives the pose.
   *multiplexed* (planar; captures independent of the projector count): every
   projector at once, coded dots then an interleaved lattice
   (:mod:`coordinator.calibration.multiplex`).

Each projector's pose is stored with ``rig.update_slot(..., source="calibration")``
and pushed to its node as soon as it is computed, with its figures in
``calibration/<slot>.json``. A run that stops half-way (Ctrl-C, a failed
projector, a crash) resumes: the next run with the same settings skips the
projectors this run already calibrated (``force`` starts afresh). A run with
``record`` saves every capture (``record/camera<i>/000001.png``, ...) so that
``cameras = ["folder:record/camera0"]`` replays it offline.

Parameters (JSON; defaults from rig.toml's ``[calibration]`` table, see
:func:`Options.from_params`)::

    mode          "multiplexed" (planar default) or "sequential"
    surface       "table" or "mesh" (default: "mesh" when a mesh is given)
    slots         projectors to calibrate (default: every connected one)
    table_mm      [W, H] of the table (default [1200, 600]); content spans it
    table_points  points file, or inline [[x_mm, y_mm, u_px, v_px], ...] (camera 0)
    charuco       {squares_x, squares_y, square_mm, marker_mm, dictionary, origin_mm}
    mesh          OBJ/PLY file (3D); landmarks: points file (frame "world" or "model")
    intrinsics    {camera index: 3x3 K} known camera intrinsics (3D)
    use_table     3D: also use the table plane around the object (default true)
    settle_s      wait after every node swapped a pattern in, before capturing (0.1)
    min_pixels    fewest decoded camera pixels a projector needs (2000)
    min_contrast  white - black below this is shadow (0.004 of full scale)
    max_saturated over-exposure limit: fraction of lit pixels saturated (0.02)
    table_only    only map the table (e.g. from a ChArUco board), save it, stop; a later run without
                  table_points/charuco reuses the saved mapping (so the board can be removed first)
    force, record, keep_going, seed, rounds
"""
from __future__ import annotations

import hashlib
import json
import math
import time
import tomllib
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from coordinator.calibration import graycode, multiplex, planar, threed
from coordinator.calibration.errors import CalibrationError
from coordinator.calibration.points import PointSet, inline_table_points, parse_points, read_points
from coordinator.camera import CameraError, CaptureRecorder
from coordinator.jobs import JobError
from coordinator.rig import HomographyPose, Mesh, ProjectionPose
from coordinator.store import atomic_write_json

SATURATED = 0.995           # a channel at or above this is saturated
UNDER_EXPOSED = 0.02        # every projector white must reach at least this (fraction of full scale)
MIN_LIT_PIXELS = 50         # fewer lit camera pixels than this: the projector is not seen
MIN_COARSE_DOTS = 6         # multiplexed stage 1: fewest decoded dots for a coarse pose
MIN_LATTICE_DOTS = 12       # multiplexed stage 2: fewest measured dots for the final pose
LATTICE_DOTS_WANTED = 40    # multiplexed stage 2: add rounds when a projector would get fewer dots than this

class _Abort(JobError):
    """A problem no other projector can avoid (a camera's exposure): the run stops."""


_KNOWN = {"mode", "surface", "slots", "table_mm", "table_points", "charuco", "mesh", "landmarks", "intrinsics",
          "use_table", "settle_s", "min_pixels", "min_contrast", "max_saturated", "force", "record", "keep_going",
          "seed", "rounds", "table_only"}


# ---------------------------------------------------------------------- options
@dataclass
class Options:
    mode: str = "multiplexed"
    surface: str = "table"
    slots: list[str] | None = None
    table_mm: tuple[float, float] = (1200.0, 600.0)
    table_points: list[PointSet] = field(default_factory=list)
    charuco: planar.CharucoSpec | None = None
    mesh_path: str | None = None
    landmarks: list[PointSet] = field(default_factory=list)
    intrinsics: dict[int, np.ndarray] = field(default_factory=dict)
    use_table: bool = True
    settle_s: float = 0.1
    min_pixels: int = 2000
    min_contrast: float = 0.004
    max_saturated: float = 0.02
    force: bool = False
    record: str | None = None
    keep_going: bool = True
    seed: int = 0
    rounds: int = 4
    table_only: bool = False
    saved_table: dict[int, dict] = field(default_factory=dict)   # camera -> {"H", "size"} from calibration/cameras.json
    fingerprint: str = ""

    @classmethod
    def from_params(cls, params: dict, rig_dir: Path) -> "Options":
        """Merge rig.toml's ``[calibration]`` table with the job's parameters (which win) and validate."""
        unknown = sorted(set(params) - _KNOWN)
        if unknown:
            raise JobError(f"unknown calibration parameter(s) {', '.join(unknown)} (known: {', '.join(sorted(_KNOWN))})")
        section: dict = {}
        toml = rig_dir / "rig.toml"
        if toml.exists():
            try:
                section = tomllib.loads(toml.read_text()).get("calibration", {})
            except tomllib.TOMLDecodeError as exc:
                raise JobError(f"{toml}: not valid TOML: {exc}") from exc
            if not isinstance(section, dict):
                raise JobError(f"{toml}: [calibration] must be a table")
            bad = sorted(set(section) - _KNOWN)
            if bad:
                raise JobError(f"{toml}: unknown [calibration] key(s) {', '.join(bad)}")
        merged = {**section, **params}

        def path_of(value: object, what: str) -> Path:
            """Absolute paths as given; relative ones against the rig directory (where rig.toml names them)."""
            if not isinstance(value, str) or not value:
                raise JobError(f"{what} must be a file path")
            p = Path(value)
            return p if p.is_absolute() else rig_dir / p

        def point_sets(value: object, what: str) -> list[PointSet]:
            if isinstance(value, dict):      # a points document sent inline (the CLI reads local files)
                return parse_points(value, source=what)
            return read_points(path_of(value, what))

        o = cls()
        try:
            if "table_mm" in merged:
                tw, th = (float(v) for v in merged["table_mm"])
                if not (tw > 0 and th > 0):
                    raise ValueError
                o.table_mm = (tw, th)
            tp = merged.get("table_points")
            if isinstance(tp, list):
                o.table_points = inline_table_points(tp, source="table_points")
            elif tp is not None:
                sets = point_sets(tp, "table_points")
                if any(s.frame != "world" for s in sets):
                    raise JobError("table_points must be in the world frame (points on the table)")
                o.table_points = sets
            if merged.get("charuco") is not None:
                if not isinstance(merged["charuco"], dict):
                    raise JobError("charuco must be a table/object describing the board")
                o.charuco = planar.CharucoSpec.from_dict(merged["charuco"])
            if merged.get("mesh") is not None:
                o.mesh_path = str(path_of(merged["mesh"], "mesh"))
            if merged.get("landmarks") is not None:
                o.landmarks = point_sets(merged["landmarks"], "landmarks")
            for k, v in (merged.get("intrinsics") or {}).items():
                K = np.asarray(v, np.float64)
                if K.shape != (3, 3) or not np.all(np.isfinite(K)):
                    raise JobError(f"intrinsics for camera {k} must be a 3x3 matrix")
                o.intrinsics[int(k)] = K
            o.surface = str(merged.get("surface", "mesh" if o.mesh_path else "table"))
            if o.surface not in ("table", "mesh"):
                raise JobError(f"surface must be 'table' or 'mesh', got {o.surface!r}")
            if o.surface == "mesh" and not o.mesh_path:
                raise JobError("surface 'mesh' needs a mesh file (parameter or [calibration] mesh = \"object.obj\")")
            o.mode = str(merged.get("mode", "multiplexed" if o.surface == "table" else "sequential"))
            if o.mode not in ("sequential", "multiplexed"):
                raise JobError(f"mode must be 'sequential' or 'multiplexed', got {o.mode!r}")
            if o.mode == "multiplexed" and o.surface != "table":
                raise JobError("the multiplexed mode calibrates planar surfaces; use mode 'sequential' for a mesh")
            if merged.get("slots") is not None:
                if not isinstance(merged["slots"], list) or not all(isinstance(s, str) for s in merged["slots"]):
                    raise JobError("slots must be a list of slot names")
                o.slots = list(merged["slots"])
            o.use_table = bool(merged.get("use_table", True))
            o.settle_s = float(merged.get("settle_s", o.settle_s))
            o.min_pixels = int(merged.get("min_pixels", o.min_pixels))
            o.min_contrast = float(merged.get("min_contrast", o.min_contrast))
            o.max_saturated = float(merged.get("max_saturated", o.max_saturated))
            o.force = bool(merged.get("force", False))
            o.record = str(merged["record"]) if merged.get("record") else None
            o.keep_going = bool(merged.get("keep_going", True))
            o.seed = int(merged.get("seed", 0))
            o.rounds = int(merged.get("rounds", o.rounds))
        except CalibrationError as exc:
            raise JobError(str(exc)) from exc
        except (TypeError, ValueError) as exc:
            raise JobError(f"bad calibration parameter: {exc or 'a value has the wrong type'}") from exc
        if not 0 <= o.settle_s <= 30 or o.min_pixels < 12 or not 0 < o.min_contrast < 1 or not 0 < o.max_saturated <= 1:
            raise JobError("settle_s must be in 0..30, min_pixels >= 12, min_contrast and max_saturated in (0, 1]")
        if not 1 <= o.rounds <= 16:
            raise JobError("rounds must be in 1..16")
        o.table_only = bool(merged.get("table_only", False))
        if not o.table_points and o.charuco is None:
            o.saved_table = _saved_table(rig_dir)
            if o.table_only or not (o.saved_table or (o.surface == "mesh" and o.landmarks)):
                raise JobError("the table -> camera mapping needs known points: set table_points (a points file, or "
                               "[calibration] table_points = [[x_mm, y_mm, u_px, v_px], ...] in rig.toml) or a charuco "
                               "board (e.g. a first run with --charuco board.json --table-only, then remove the board)")
        o.fingerprint = o._fingerprint()
        return o

    def _fingerprint(self) -> str:
        h = hashlib.blake2b(digest_size=8)
        for part in (self.mode, self.surface, self.table_mm, self.use_table, self.seed, self.rounds,
                     self.charuco, self.mesh_path):
            h.update(repr(part).encode())
        for s in self.table_points + self.landmarks:
            h.update(s.frame.encode() + bytes([s.camera]) + s.xyz.tobytes() + s.pixels.tobytes())
        if self.mesh_path and Path(self.mesh_path).exists():
            h.update(Path(self.mesh_path).read_bytes())
        for i in sorted(self.saved_table):
            h.update(np.asarray(self.saved_table[i]["H"], np.float64).tobytes())
        return h.hexdigest()


def _saved_table(rig_dir: Path) -> dict[int, dict]:
    """The table -> camera mappings a previous run saved (calibration/cameras.json), by camera."""
    f = calibration_dir(rig_dir) / "cameras.json"
    if not f.exists():
        return {}
    try:
        doc = json.loads(f.read_text())
        return {int(c["camera"]): {"H": np.array(c["table_to_camera"], np.float64), "size": tuple(c["size"]),
                                   "saved_at": doc.get("saved_at")}
                for c in doc.get("cameras", []) if "table_to_camera" in c}
    except (OSError, json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
        raise JobError(f"{f}: cannot read the saved table mapping ({exc}); give table points or a board again") from exc


# ---------------------------------------------------------------------- persistence / resume
def calibration_dir(rig_dir: Path) -> Path:
    return Path(rig_dir) / "calibration"


@dataclass
class Run:
    run_id: str
    resumed: bool
    done: set[str]


def _start_run(rig_dir: Path, opts: Options, content_size: tuple[int, int], camera_specs: list[str]) -> Run:
    cdir = calibration_dir(rig_dir)
    fp = f"{opts.fingerprint}:{content_size}:{','.join(camera_specs)}"
    prev = None
    f = cdir / "run.json"
    if f.exists():
        try:
            prev = json.loads(f.read_text())
        except (OSError, json.JSONDecodeError):
            prev = None
    if prev and not opts.force and prev.get("status") != "complete" and prev.get("fingerprint") == fp:
        run_id = prev["run"]
        done = set()
        for p in cdir.glob("*.json"):
            if p.name in ("run.json", "cameras.json", "alignment.json"):
                continue
            try:
                doc = json.loads(p.read_text())
            except (OSError, json.JSONDecodeError):
                continue
            if doc.get("run") == run_id and doc.get("slot"):
                done.add(doc["slot"])
        atomic_write_json(f, {**prev, "status": "running", "resumed_at": time.time()})
        return Run(run_id, True, done)
    run_id = time.strftime("%Y%m%dT%H%M%S") + "-" + uuid.uuid4().hex[:6]
    atomic_write_json(f, {"run": run_id, "status": "running", "started_at": time.time(), "fingerprint": fp,
                          "mode": opts.mode, "surface": opts.surface})
    return Run(run_id, False, set())


def _finish_run(rig_dir: Path, run: Run, status: str) -> None:
    f = calibration_dir(rig_dir) / "run.json"
    try:
        doc = json.loads(f.read_text())
    except (OSError, json.JSONDecodeError):
        doc = {"run": run.run_id}
    atomic_write_json(f, {**doc, "status": status, "finished_at": time.time()})


def _push(ctx, slot: str, pose) -> None:
    """Persist a slot's pose and push it to its node."""
    ctx.set_pose(slot, pose, source="calibration")


def _round(x: float, nd: int = 4) -> float | None:
    return None if x is None or not math.isfinite(x) else round(float(x), nd)


# ---------------------------------------------------------------------- captures
class _Captures:
    """Show patterns and capture every camera (the capture discipline), counting and optionally recording."""

    def __init__(self, ctx, opts: Options, cameras: list[int]):
        self.ctx = ctx
        self.opts = opts
        self.cameras = cameras
        self.count = 0
        self.recorders: dict[int, CaptureRecorder] = {}
        if opts.record:
            for i in cameras:
                self.recorders[i] = CaptureRecorder(Path(opts.record) / f"camera{i}")

    async def shoot(self, images: dict[str, np.ndarray | None], *, require: list[str]) -> list[np.ndarray]:
        """Show ``images`` (projector space, others black), wait for every swap + settle, capture each camera."""
        await self.ctx.show(images, settle_s=self.opts.settle_s, require=require)
        out = []
        for i in self.cameras:
            try:
                img = await self.ctx.capture(i)
            except CameraError as exc:
                raise JobError(str(exc)) from exc
            img = np.asarray(img, np.float32)
            if img.ndim != 3 or img.shape[2] != 3:
                raise JobError(f"camera {i} delivered an image of shape {img.shape}; expected (H, W, 3)")
            if i in self.recorders:
                img = await self.ctx.compute(self.recorders[i].record, img)
            out.append(img)
        self.count += 1
        return out


def _full(size: tuple[int, int], value: int) -> np.ndarray:
    return np.full((size[1], size[0]), value, np.uint8)


def _saturated_fraction(white: np.ndarray, contrast: np.ndarray, min_contrast: float) -> float:
    sat = white.max(axis=2) >= SATURATED
    region = (contrast > min_contrast) | sat
    n = int(region.sum())
    return float(sat[region].sum()) / n if n else 0.0


# ---------------------------------------------------------------------- the job
async def calibrate(ctx, params: dict) -> dict:
    """Calibrate the rig's projectors (see the module docstring); returns per-slot figures."""
    t0 = time.monotonic()
    rig = ctx.rig
    opts = Options.from_params(dict(params), Path(rig.path))
    specs = list(getattr(ctx, "camera_specs", []) or [])
    if not specs:
        raise JobError("no camera: set `cameras = [\"room://HOST:PORT\"]` in rig.toml, start the coordinator "
                       "with --camera, or pass --camera to `shadowless calibrate`")
    live = ctx.live_slots()
    if opts.slots is None:
        slots = live
        if not slots:
            raise JobError("no projector is connected: start the nodes (see `shadowless status`)")
    else:
        unknown = [s for s in opts.slots if s not in rig.slots]
        if unknown:
            raise JobError(f"slot(s) {', '.join(unknown)} not in rig {rig.config.name!r} (slots: {', '.join(rig.slots)})")
        missing = [s for s in opts.slots if s not in live]
        if missing:
            raise JobError(f"projector(s) {', '.join(missing)} not connected: start their nodes (see `shadowless status`)")
        slots = list(opts.slots)
    content_size = (rig.config.content_width, rig.config.content_height)
    run = _start_run(Path(rig.path), opts, content_size, specs)
    todo = [s for s in slots if s not in run.done]
    ctx.log(f"calibration run {run.run_id} ({'resumed' if run.resumed else 'new'}): {opts.mode} mode, "
            f"{opts.surface} surface, {len(specs)} camera(s), {len(todo)} of {len(slots)} projector(s) to do"
            + (f" ({', '.join(sorted(run.done & set(slots)))} already done in this run)" if run.done & set(slots) else ""))
    cams = list(range(len(specs)))
    shots = _Captures(ctx, opts, cams)
    sizes = {s: ctx.projector_size(s) for s in slots}
    results: dict[str, dict] = {}
    failed: dict[str, str] = {}
    status = "interrupted"      # resumable, like "incomplete"; only "complete" makes the next run start afresh
    try:
        dark, white_all = await _exposure(ctx, shots, slots, sizes, opts)
        setup = await _cameras(ctx, shots, slots, sizes, opts, run, dark, white_all, content_size)
        if opts.table_only:
            todo = []
            ctx.log("table mapped (calibration/cameras.json); remove the board and run `shadowless calibrate` again")
        if todo:
            if opts.surface == "table" and opts.mode == "multiplexed":
                await _multiplexed(ctx, shots, todo, sizes, opts, run, setup, dark, content_size, results, failed)
            elif opts.surface == "table":
                await _sequential(ctx, shots, todo, sizes, opts, run, setup, content_size, results, failed)
            else:
                await _sequential_3d(ctx, shots, todo, sizes, opts, run, setup, results, failed)
        status = "complete" if not failed else "incomplete"
    finally:
        _finish_run(Path(rig.path), run, status)
    for s in slots:
        if s in run.done and s not in results:
            f = calibration_dir(Path(rig.path)) / f"{s}.json"
            try:
                results[s] = {**json.loads(f.read_text()), "resumed": True}
            except (OSError, json.JSONDecodeError):
                pass
    summary = {
        "run": run.run_id, "mode": opts.mode, "surface": opts.surface, "resumed": run.resumed,
        "captures": shots.count, "cameras": len(cams), "wall_s": round(time.monotonic() - t0, 3),
        "slots": {s: results[s] for s in slots if s in results}, "failed": failed,
        "camera_setup": setup.summary(),
    }
    if failed:
        ok = len(summary["slots"])
        raise JobError(f"calibrated {ok} of {len(slots)} projector(s) (saved; run again to retry the others); "
                       + "; ".join(failed.values()))
    return summary


async def _exposure(ctx, shots: _Captures, slots: list[str], sizes, opts: Options) -> tuple[list[np.ndarray], list[np.ndarray]]:
    ctx.progress("exposure", "", 0, 2, "every projector black")
    dark = await shots.shoot({s: _full(sizes[s], 0) for s in slots}, require=slots)
    ctx.progress("exposure", "", 1, 2, "every projector white")
    white = await shots.shoot({s: _full(sizes[s], 255) for s in slots}, require=slots)
    for i, (d, w) in enumerate(zip(dark, white)):
        level = float(np.percentile(graycode.luminance(w) - graycode.luminance(d), 99.0))
        if level < UNDER_EXPOSED:
            raise _Abort(f"camera {i} under-exposed (every projector at full white reaches only {100 * level:.1f} % "
                           "of full scale): raise the exposure or gain (or check that the projectors are on)")
        sat = float(np.mean(w.max(axis=2) >= SATURATED))
        if sat > opts.max_saturated:
            ctx.log(f"note: camera {i} saturates {100 * sat:.0f} % of its pixels when every projector is white; "
                    "calibration shows one projector's light at a time, but light-transport measurements may need less exposure")
    ctx.progress("exposure", "", 2, 2, "ok")
    return dark, white


# ---------------------------------------------------------------------- cameras
@dataclass
class CameraSetup:
    """Per camera: table -> camera homography (planar) and/or a posed pinhole (3D); plus the mesh (3D)."""

    table_to_camera: dict[int, np.ndarray] = field(default_factory=dict)
    table_rms: dict[int, float] = field(default_factory=dict)
    devices: dict[int, threed.Pinhole] = field(default_factory=dict)
    device_rms: dict[int, float] = field(default_factory=dict)
    sizes: dict[int, tuple[int, int]] = field(default_factory=dict)
    mesh: threed.MeshData | None = None
    rig_mesh: Mesh | None = None
    mesh_rms: float | None = None

    def summary(self) -> list[dict]:
        out = []
        for i in sorted(self.sizes):
            out.append({"camera": i, "size": list(self.sizes[i]),
                        "table_rms_px": _round(self.table_rms.get(i, math.nan)),
                        "pose_rms_px": _round(self.device_rms.get(i, math.nan))})
        return out


async def _cameras(ctx, shots: _Captures, slots, sizes, opts: Options, run: Run, dark, white_all,
                   content_size) -> CameraSetup:
    setup = CameraSetup()
    ncam = len(shots.cameras)
    for i in shots.cameras:
        setup.sizes[i] = (white_all[i].shape[1], white_all[i].shape[0])
    ctx.progress("cameras", "", 0, ncam, "table -> camera mapping")
    world_sets: dict[int, list[PointSet]] = {i: [] for i in shots.cameras}
    for s in opts.table_points:
        if s.camera not in world_sets:
            raise JobError(f"table points name camera {s.camera}, but the job has {ncam} camera(s)")
        world_sets[s.camera].append(s)
    if opts.charuco is not None:
        for i in shots.cameras:
            try:
                txy, px = await ctx.compute(planar.detect_charuco, white_all[i], opts.charuco)
            except CalibrationError as exc:
                if opts.table_points:
                    ctx.log(f"camera {i}: {exc}; using the table points")
                    continue
                raise JobError(f"camera {i}: {exc}") from exc
            world_sets[i].append(PointSet("world", i, tuple(f"charuco {k}" for k in range(len(txy))),
                                          np.column_stack([txy, np.zeros(len(txy))]), px))
    for i in shots.cameras:
        for s in world_sets[i]:
            _check_points_inside(s.pixels, setup.sizes[i], i)
        table_only = [s for s in world_sets[i] if s.planar]
        if len(table_only) and sum(len(s) for s in table_only) >= 4:
            xy = np.vstack([s.xyz[:, :2] for s in table_only])
            px = np.vstack([s.pixels for s in table_only])
            try:
                fit = planar.table_to_camera_from_points(xy, px)
            except CalibrationError as exc:
                raise JobError(f"camera {i}: {exc}") from exc
            setup.table_to_camera[i] = fit.H
            setup.table_rms[i] = fit.rms
    for i, saved in opts.saved_table.items():
        if i in setup.sizes and i not in setup.table_to_camera:
            if tuple(saved["size"]) != setup.sizes[i]:
                raise JobError(f"camera {i} now delivers {setup.sizes[i][0]}x{setup.sizes[i][1]} images but the saved table "
                               f"mapping was made at {saved['size'][0]}x{saved['size'][1]}: map the table again")
            setup.table_to_camera[i] = saved["H"]
            setup.table_rms[i] = math.nan
            ctx.log(f"camera {i}: using the table mapping saved by an earlier run")
    if opts.surface == "table":
        if not setup.table_to_camera:
            raise JobError("no camera has 4 or more known table points: the table -> camera mapping needs them")
    else:
        await _pose_cameras_and_mesh(ctx, setup, opts, world_sets)
    ctx.progress("cameras", "", ncam, ncam, "ok")
    doc = {"run": run.run_id, "saved_at": time.time(), "table_mm": list(opts.table_mm), "content_size": list(content_size),
           "cameras": []}
    for i in shots.cameras:
        entry: dict[str, Any] = {"camera": i, "size": list(setup.sizes[i])}
        if i in setup.table_to_camera:
            entry["table_to_camera"] = setup.table_to_camera[i].tolist()
            entry["table_rms_px"] = _round(setup.table_rms[i])
        if i in setup.devices:
            entry["pinhole"] = setup.devices[i].to_dict()
            entry["pose_rms_px"] = _round(setup.device_rms[i])
        doc["cameras"].append(entry)
    if setup.rig_mesh is not None:
        doc["mesh"] = {"id": setup.rig_mesh.mesh_id, "file": opts.mesh_path, "registration_rms_px": _round(setup.mesh_rms or math.nan)}
    atomic_write_json(calibration_dir(Path(ctx.rig.path)) / "cameras.json", doc)
    return setup


def _check_points_inside(px: np.ndarray, size: tuple[int, int], camera: int) -> None:
    w, h = size
    out = (px[:, 0] < -0.5) | (px[:, 1] < -0.5) | (px[:, 0] > w - 0.5) | (px[:, 1] > h - 0.5)
    if out.any():
        raise JobError(f"camera {camera}: {int(out.sum())} known point(s) lie outside its {w}x{h} image: "
                       "the points file was made for another camera or resolution")


async def _pose_cameras_and_mesh(ctx, setup: CameraSetup, opts: Options, world_sets: dict[int, list[PointSet]]) -> None:
    try:
        mesh = threed.load_mesh(opts.mesh_path)
    except CalibrationError as exc:
        raise JobError(str(exc)) from exc
    if mesh.uvs is None:
        raise JobError(f"mesh {opts.mesh_path} has no texture coordinates: export it with UVs (the content is its texture)")
    model_sets = [s for s in opts.landmarks if s.frame == "model"]
    for s in opts.landmarks:
        if s.camera not in setup.sizes:
            raise JobError(f"landmarks name camera {s.camera}, but the job has {len(setup.sizes)} camera(s)")
        _check_points_inside(s.pixels, setup.sizes[s.camera], s.camera)
        if s.frame == "world":
            world_sets.setdefault(s.camera, []).append(s)
    for i, sets in world_sets.items():
        if not sets:
            continue
        K = opts.intrinsics.get(i)
        own = [s for s in model_sets if s.camera == i]
        try:
            if K is None and all(s.planar for s in sets) and sum(len(s) for s in own) >= 8:
                # table points alone rarely fix a ceiling camera's focal length; the object's landmarks
                # (not coplanar, in its own frame) calibrate the intrinsics, the table then poses the camera
                K = (await ctx.compute(threed.pose_camera, own, setup.sizes[i])).device.K
            fit = await ctx.compute(threed.pose_camera, sets, setup.sizes[i], K=K)
        except CalibrationError as exc:
            raise JobError(f"camera {i}: {exc}") from exc
        setup.devices[i] = fit.device
        setup.device_rms[i] = fit.rms
        ctx.log(f"camera {i} posed from {sum(len(s) for s in sets)} known points (rms {fit.rms:.2f} px)")
    if not setup.devices:
        raise JobError("no camera could be posed in the world: give table points (or a ChArUco board) and/or "
                       "landmarks with world coordinates")
    if model_sets:
        try:
            R, t, rms = await ctx.compute(threed.register_mesh, model_sets, setup.devices)
            world_all = [s for sets in world_sets.values() for s in sets]
            devices, R, t, rms = await ctx.compute(threed.refine_scene, setup.devices, world_all, model_sets, R, t,
                                                   fixed_intrinsics=set(opts.intrinsics))
        except CalibrationError as exc:
            raise JobError(str(exc)) from exc
        setup.devices.update(devices)
        mesh = mesh.transformed(R, t)
        setup.mesh_rms = rms
        ctx.log(f"mesh registered from {sum(len(s) for s in model_sets)} landmarks (rms {rms:.2f} px)")
    setup.mesh = mesh
    h = hashlib.blake2b(digest_size=8)
    for a in (mesh.vertices, mesh.uvs, mesh.faces):
        h.update(np.ascontiguousarray(a).tobytes())
    setup.rig_mesh = Mesh(h.hexdigest(), mesh.vertices, mesh.uvs, mesh.faces)


# ---------------------------------------------------------------------- sequential (planar)
async def _gray_captures(ctx, shots: _Captures, slot: str, size, opts: Options, total_stage: str) -> tuple[list, list, list[list]]:
    layout = graycode.gray_layout(size)
    pats = graycode.gray_patterns(size)
    total = layout.count + 2
    ctx.progress(total_stage, slot, 0, total, "white reference")
    white = await shots.shoot({slot: _full(size, 255)}, require=[slot])
    ctx.progress(total_stage, slot, 1, total, "black reference")
    black = await shots.shoot({slot: _full(size, 0)}, require=[slot])
    for i, (w, b) in enumerate(zip(white, black)):
        contrast = graycode.luminance(w) - graycode.luminance(b)
        sat = _saturated_fraction(w, contrast, opts.min_contrast)
        if sat > opts.max_saturated:
            raise _Abort(f"camera {i} over-exposed ({100 * sat:.0f} % of the pixels {slot} lights are saturated): "
                           "lower the exposure")
    caps: list[list[np.ndarray]] = []
    for k, p in enumerate(pats):
        caps.append(await shots.shoot({slot: p}, require=[slot]))
        ctx.progress(total_stage, slot, k + 2, total, "gray codes")
    return white, black, caps


def _decode_all(white, black, caps, size, opts: Options) -> list[graycode.GrayDecode]:
    layout = graycode.gray_layout(size)
    return [graycode.decode_gray([c[i] for c in caps], white=white[i], black=black[i], layout=layout,
                                 min_contrast=opts.min_contrast) for i in range(len(white))]


def _seen_check(slot: str, decodes: list[graycode.GrayDecode], count: int, opts: Options) -> None:
    lit = sum(int(d.lit.sum()) for d in decodes)
    if lit < MIN_LIT_PIXELS or count == 0:
        peak = max(float(np.percentile(d.contrast, 99.9)) for d in decodes)
        raise JobError(f"projector {slot} not seen by the camera (its white reference raises no camera pixel by more "
                       f"than {100 * max(peak, 0):.1f} % of full scale): check that it is on, shows the patterns and is "
                       "aimed at the surface the camera sees")
    if count < opts.min_pixels:
        contrast = np.concatenate([d.contrast[d.lit] for d in decodes])
        if float(np.percentile(contrast, 95)) < 2.5 * opts.min_contrast:
            raise JobError(f"too few decoded pixels for {slot} ({count} < {opts.min_pixels}): its light reaches the camera "
                           f"at only {100 * float(np.percentile(contrast, 95)):.1f} % of full scale; the camera is "
                           "under-exposed for one projector: raise the exposure")
        raise JobError(f"too few decoded pixels for {slot} ({count} < {opts.min_pixels}): is most of its image off the "
                       "surface or blocked?")


def _gray_planar(decodes, setup: CameraSetup, slot: str, opts: Options):
    txy, proj, agg_t, agg_p = [], [], [], []
    for i, d in enumerate(decodes):
        if i not in setup.table_to_camera:
            continue
        cam, pj = d.correspondences()
        inv = np.linalg.inv(setup.table_to_camera[i])
        txy.append(planar.apply_homography(inv, cam))
        proj.append(pj)
        cm, pm = planar.pixel_centroids(cam, pj)
        agg_t.append(planar.apply_homography(inv, cm))
        agg_p.append(pm)
    txy, proj = np.vstack(txy), np.vstack(proj)
    _seen_check(slot, decodes, len(txy), opts)
    fit = planar.fit_homography(txy, proj, threshold=1.5)
    at, ap = np.vstack(agg_t), np.vstack(agg_p)
    r = np.linalg.norm(planar.apply_homography(fit.H, at) - ap, axis=1)
    r = r[r <= 1.5]
    return fit, r, len(txy)


async def _sequential(ctx, shots, todo, sizes, opts, run, setup, content_size, results, failed) -> None:
    H_c2t = planar.content_to_table(content_size, opts.table_mm)
    for n, slot in enumerate(todo):
        captures_before = shots.count
        try:
            white, black, caps = await _gray_captures(ctx, shots, slot, sizes[slot], opts, "gray codes")
            decodes = await ctx.compute(_decode_all, white, black, caps, sizes[slot], opts)
            fit, r, count = await ctx.compute(_gray_planar, decodes, setup, slot, opts)
        except _Abort:
            raise
        except (JobError, CalibrationError) as exc:
            if not opts.keep_going:
                raise JobError(str(exc)) from exc
            failed[slot] = str(exc)
            ctx.log(f"{slot}: {exc}")
            continue
        pose = planar.normalise(fit.H @ H_c2t)
        doc = _slot_doc(run, slot, opts, rms=float(np.sqrt(np.mean(r ** 2))) if len(r) else math.nan,
                        mx=float(r.max()) if len(r) else math.nan, points=len(r), raw_rms=fit.rms,
                        decoded=count, inliers=fit.count, captures=shots.count - captures_before)
        _save_slot(ctx, slot, HomographyPose(pose), doc)
        results[slot] = doc
        ctx.progress("projectors", slot, n + 1, len(todo), "calibrated", value=doc["rms_px"] or math.nan)


def _slot_doc(run: Run, slot: str, opts: Options, *, rms: float, mx: float, points: int, **extra) -> dict:
    doc = {"run": run.run_id, "slot": slot, "mode": opts.mode, "surface": opts.surface,
           "rms_px": _round(rms), "max_px": _round(mx), "points": int(points), "finished_at": time.time()}
    for k, v in extra.items():
        doc[k if not k.endswith("rms") else k + "_px"] = _round(v) if isinstance(v, float) else v
    return doc


def _save_slot(ctx, slot: str, pose, doc: dict) -> None:
    _push(ctx, slot, pose)
    atomic_write_json(calibration_dir(Path(ctx.rig.path)) / f"{slot}.json", doc)


# ---------------------------------------------------------------------- multiplexed (planar)
async def _multiplexed(ctx, shots, todo, sizes, opts, run, setup, dark_all, content_size, results, failed) -> None:
    cam = min(setup.table_to_camera)       # the lattice is planned and measured in one camera
    H_t2c = setup.table_to_camera[cam]
    H_c2t_img = np.linalg.inv(H_t2c)
    dark = dark_all[cam]
    coarse: dict[str, np.ndarray] = {}
    seen: dict[str, int] = {s: 0 for s in todo}
    pending = list(todo)
    for attempt in range(2):
        if not pending:
            break
        plan = multiplex.plan_coded_dots({s: sizes[s] for s in pending}, seed=opts.seed + attempt)
        caps = []
        stage = "coded dots" if attempt == 0 else "coded dots (retry)"
        for k in range(plan.captures):
            ctx.progress(stage, "", k, plan.captures, f"{len(pending)} projectors at once")
            imgs = plan.frames(k)
            caps.append((await shots.shoot(imgs, require=pending))[shots.cameras.index(cam)])
        ctx.progress(stage, "", plan.captures, plan.captures, "decoding")
        dec = await ctx.compute(multiplex.decode_coded_dots, caps, dark, plan)
        ctx.log(f"coded dots: {dec.blobs} blobs, {dec.collisions} overlapping, {dec.unknown} unknown codes")
        _check_dot_saturation(caps, dec, cam, opts)
        still = []
        for s in pending:
            m = dec.matches[s]
            seen[s] += m.count
            if m.count >= MIN_COARSE_DOTS:
                try:
                    fit = planar.fit_homography(planar.apply_homography(H_c2t_img, m.camera), m.projector, threshold=2.0)
                    if fit.count >= MIN_COARSE_DOTS:
                        coarse[s] = fit.H
                        continue
                except CalibrationError:
                    pass
            still.append(s)
        pending = still
    for s in pending:
        if seen[s] == 0:
            failed[s] = (f"projector {s} not seen by the camera (none of its coded dots was found): check that it is on, "
                         "shows the patterns and is aimed at the table")
        else:
            failed[s] = f"too few dots decoded for {s} ({seen[s]} < {MIN_COARSE_DOTS}): is most of its image off the table or blocked?"
        ctx.log(failed[s])
    if pending and not opts.keep_going:
        raise JobError("; ".join(failed[s] for s in pending))
    ok = [s for s in todo if s in coarse]
    if not ok:
        return
    lattice = multiplex.plan_lattice(coarse, H_t2c, sizes={s: sizes[s] for s in ok}, camera_size=setup.sizes[cam],
                                     table_mm=opts.table_mm, rounds=opts.rounds)
    per_slot = int(np.median([sum(len(r.centres[s]) for r in lattice.rounds) for s in ok]))
    if per_slot < LATTICE_DOTS_WANTED and opts.rounds < 16:
        # more projectors than one lattice holds at this camera resolution: add rounds (the only growth with N)
        need = min(16, math.ceil(opts.rounds * LATTICE_DOTS_WANTED / max(per_slot, 1)))
        if need > opts.rounds:
            ctx.log(f"lattice: {per_slot} dots per projector in {opts.rounds} rounds; using {need} rounds")
            lattice = multiplex.plan_lattice(coarse, H_t2c, sizes={s: sizes[s] for s in ok}, camera_size=setup.sizes[cam],
                                             table_mm=opts.table_mm, rounds=need)
    found: dict[str, list[multiplex.DotMatches]] = {s: [] for s in ok}
    start = shots.count
    for r in range(len(lattice.rounds)):
        ctx.progress("lattice", "", r, len(lattice.rounds), f"{len(ok)} projectors at once")
        cap = (await shots.shoot(lattice.frames(r), require=ok))[shots.cameras.index(cam)]
        ms = await ctx.compute(multiplex.measure_lattice, cap, dark, lattice, r)
        for s in ok:
            found[s].append(ms[s])
    ctx.progress("lattice", "", len(lattice.rounds), len(lattice.rounds), "fitting")
    H_c2t = planar.content_to_table(content_size, opts.table_mm)
    for n, s in enumerate(ok):
        camxy = np.vstack([m.camera for m in found[s]])
        proj = np.vstack([m.projector for m in found[s]])
        if len(camxy) < MIN_LATTICE_DOTS:
            failed[s] = f"too few lattice dots measured for {s} ({len(camxy)} < {MIN_LATTICE_DOTS}): is most of its image off the table?"
            ctx.log(failed[s])
            continue
        try:
            fit = planar.fit_homography(planar.apply_homography(H_c2t_img, camxy), proj, threshold=1.0)
        except CalibrationError as exc:
            failed[s] = f"{s}: {exc}"
            continue
        pose = planar.normalise(fit.H @ H_c2t)
        doc = _slot_doc(run, s, opts, rms=fit.rms, mx=fit.max, points=fit.count, coarse_dots=int(seen[s]),
                        captures=shots.count - start)
        _save_slot(ctx, s, HomographyPose(pose), doc)
        results[s] = doc
        ctx.progress("projectors", s, n + 1, len(ok), "calibrated", value=fit.rms)
    if failed and not opts.keep_going:
        raise JobError("; ".join(failed.values()))


def _check_dot_saturation(caps: list[np.ndarray], dec: multiplex.CodedDecode, camera: int, opts: Options) -> None:
    pts = np.vstack([m.camera for m in dec.matches.values() if m.count]) if any(m.count for m in dec.matches.values()) else None
    if pts is None:
        return
    peak = np.max(np.stack([c.max(axis=2) for c in caps]), axis=0)
    ix = np.clip(np.rint(pts[:, 0]).astype(int), 0, peak.shape[1] - 1)
    iy = np.clip(np.rint(pts[:, 1]).astype(int), 0, peak.shape[0] - 1)
    sat = float(np.mean(peak[iy, ix] >= SATURATED))
    if sat > max(opts.max_saturated, 0.2):
        raise _Abort(f"camera {camera} over-exposed ({100 * sat:.0f} % of the dots saturate it): lower the exposure")


# ---------------------------------------------------------------------- sequential (3D)
def _gray_3d(decodes, surfaces, setup: CameraSetup, slot: str, size, opts: Options):
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
    _seen_check(slot, decodes, len(X), opts)
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


async def _sequential_3d(ctx, shots, todo, sizes, opts, run, setup: CameraSetup, results, failed) -> None:
    def cast_all():
        out = {}
        with threed.SurfaceCaster(setup.mesh, table_mm=opts.table_mm if opts.use_table else None) as caster:
            for i, dev in setup.devices.items():
                pts, kind = caster.cast(dev)
                out[i] = (pts, kind, threed.edge_mask(pts, kind))
        return out

    try:
        surfaces = await ctx.compute(cast_all)
    except CalibrationError as exc:
        raise JobError(str(exc)) from exc
    for n, slot in enumerate(todo):
        before = shots.count
        try:
            white, black, caps = await _gray_captures(ctx, shots, slot, sizes[slot], opts, "gray codes")
            decodes = await ctx.compute(_decode_all, white, black, caps, sizes[slot], opts)
            fit, r, count, per_camera = await ctx.compute(_gray_3d, decodes, surfaces, setup, slot, sizes[slot], opts)
            near, far = threed.depth_range(fit.device.P, setup.rig_mesh.vertices)
        except _Abort:
            raise
        except (JobError, CalibrationError) as exc:
            if not opts.keep_going:
                raise JobError(str(exc)) from exc
            failed[slot] = str(exc)
            ctx.log(f"{slot}: {exc}")
            continue
        P = fit.device.P / np.linalg.norm(fit.device.P[2, :3])
        pose = ProjectionPose(P, setup.rig_mesh, near_mm=near, far_mm=far)
        doc = _slot_doc(run, slot, opts, rms=float(np.sqrt(np.mean(r ** 2))) if len(r) else math.nan,
                        mx=float(r.max()) if len(r) else math.nan, points=len(r), raw_rms=fit.rms, decoded=count,
                        inliers=fit.count, captures=shots.count - before, cameras=per_camera,
                        K=fit.device.K.tolist(), center_mm=fit.device.center.tolist())
        _save_slot(ctx, slot, pose, doc)
        results[slot] = doc
        ctx.progress("projectors", slot, n + 1, len(todo), "calibrated", value=doc["rms_px"] or math.nan)


# ---------------------------------------------------------------------- alignment
async def alignment_check(ctx, params: dict) -> dict:
    """Measure residual misalignment: see :mod:`coordinator.calibration.alignment`."""
    from coordinator.calibration.alignment import run_alignment

    return await run_alignment(ctx, params)

