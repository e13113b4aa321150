"""`bench uniformity`'s in-process parts: a rig in the virtual room blended by the coordinator's own jobs.

The jobs (``calibrate`` or the room's true poses, ``response`` or LUTs from the true gammas, then
``blend``) run against :class:`sim.room.Room` through :class:`shadowless.room_driver.RoomDriver`,
which renders what every node outputs with the node's own pipeline (its blend maps included), so
the figures measure the method, not gRPC or the node processes (the failover and the watchdog are
measured with real processes: :mod:`bench.uniformity_live`).

:func:`blended_rig` blends one rig and returns the captures a figure needs: a flat white and a flat
grey before the blend and after it, the blend's target and covered region brought to the camera's
size, the room's count of projectors reaching each pixel, and the job's result.
"""
from __future__ import annotations

import dataclasses
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bench.calibration import make_rig, table_points_from_truth
from bench.compensation_room import points_doc
from bench.uniformity_measure import resize_to
from bench.uniformity_scenes import Missing, require
from coordinator.jobs import JobError
from coordinator.rig import HomographyPose, Rig
from shadowless.room_driver import RoomDriver
from sim.room import Room

__all__ = ["Blended", "blended_rig", "blend_params", "stored_target", "pick_exposure", "mean_capture", "truth_luts"]


def _log(msg: str) -> None:
    print(f"[bench uniformity] {msg}", file=sys.stderr, flush=True)


@dataclass
class Blended:
    """What one blended rig gives the figures (camera-sized arrays, (H, W[, 3]) float32)."""

    slots: list[str]
    result: dict                       # the blend job's wire result
    captures: int                      # captures the blend job took
    seconds: float                     # its wall time
    exposure: float                    # the exposure every figure capture used
    white_before: np.ndarray
    white_after: np.ndarray
    grey_before: np.ndarray
    grey_after: np.ndarray
    target: np.ndarray | None          # the blend's white target above black (None: the stored contributions cannot give it)
    black: np.ndarray | None           # the black floor the blend raises every point to
    covered: np.ndarray                # (H, W) bool: the blend covers it and the room lights it
    count: np.ndarray                  # (H, W) int: projectors reaching each pixel (the room's truth)
    applied: float                     # largest relative change of a noise-free white render with maps on/off
    notes: list[str] = field(default_factory=list)

    def expected(self, level: float) -> np.ndarray | None:
        """What the blend means the camera to see for flat content ``level``: ``level * target + black``."""
        if self.target is None:
            return None
        return level * self.target + (0.0 if self.black is None else self.black)


def truth_luts(room: Room, slots: list[str]) -> dict[str, np.ndarray]:
    """Each slot's inverse-response LUT from the room's true gammas: (3, 1024) float32."""
    grid = np.linspace(0.0, 1.0, 1024)
    return {s: np.stack([grid ** (1.0 / g) for g in room.truth.projector(s).gamma]).astype(np.float32) for s in slots}


def mean_capture(room: Room, frames: int, exposure: float) -> np.ndarray:
    """The mean of ``frames`` captures of camera 0 at ``exposure``: (H, W, 3) float32."""
    acc = None
    for _ in range(max(1, frames)):
        c = room.capture(0, exposure=exposure).astype(np.float64)
        acc = c if acc is None else acc + c
    return (acc / max(1, frames)).astype(np.float32)


def pick_exposure(room: Room, lit: np.ndarray) -> float:
    """An exposure at which the brightest lit pixel of the frames now shown sits near 0.85 of full
    scale (the overlaps of a wall are twice as bright as the rest: the camera must not clip them)."""
    base = room.truth.camera(0).exposure
    linear = room.render_linear(0, exposure=base)
    top = float(np.percentile(linear[lit].max(axis=-1), 99.9)) if lit.any() else 0.0
    return base if top <= 0 else base * min(1.0, 0.85 / top)


def blend_params(wanted: dict) -> dict:
    """The blend job's parameters among ``wanted`` that its options declare (the rest are left out, so the
    benchmark runs against whichever options the job has)."""
    registry = require("coordinator.jobs.registry", "the job registry")
    if "blend" not in registry.JOBS:
        raise Missing("the blend job (coordinator/blending/blend_job.py) is not registered in this build")
    try:
        spec = registry.resolve("blend")
    except Exception as exc:     # the module named but absent, or failing to import
        raise Missing(f"the blend job cannot be loaded: {exc}") from None
    names = {f.name for f in dataclasses.fields(spec.options)}
    return {k: v for k, v in wanted.items() if k in names}


def stored_target(rig_path: Path, camera_size: tuple[int, int], *, headroom, lost=frozenset(),
                  lamp_gains=None) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None]:
    """What the blend expects the camera to see, recomputed from the contributions the job stored (no
    capture), at the camera's size: the white target above black ((H, W, 3) float32), the black floor
    the maps raise it to ((H, W, 3) float32, the floor's luminance in the blend's white) and the covered
    region ((H, W) bool); (None, None, None) when the store or the numerics are not in this build.

    A flat level ``v`` is expected to give ``v * target + black``. ``headroom`` is the one asked of
    the job (None: "auto"), so the same target comes out."""
    store = importlib_optional("coordinator.blend_store")
    solve = importlib_optional("imaging.blending.solve")
    contributions = importlib_optional("imaging.blending.contributions")
    if store is None or solve is None or contributions is None:
        return None, None, None
    loaded = store.load_contributions(rig_path)
    if loaded is None:
        return None, None, None
    c = contributions.Contributions.from_arrays(*loaded)
    kw = {"lost": frozenset(lost), "headroom": headroom}
    if lamp_gains:
        kw["lamp_gains"] = lamp_gains
    sol = solve.compute_blend(c, **kw)
    target = resize_to(np.asarray(sol.target, np.float32), camera_size)
    black = getattr(sol, "black_target", None)
    if black is None:
        black = np.zeros(target.shape, np.float32)
    else:
        wp = np.asarray(getattr(sol, "white_point", np.ones(3)), np.float32)
        black = resize_to(np.asarray(black, np.float32), camera_size)[:, :, None] * wp[None, None, :]
    covered = resize_to(np.asarray(sol.covered, bool), camera_size)
    return target, black.astype(np.float32), covered


def importlib_optional(name: str):
    import importlib
    try:
        return importlib.import_module(name)
    except ModuleNotFoundError:
        return None


def _flat(driver: RoomDriver, rig: Rig, level: float) -> None:
    cw, ch = rig.config.content_width, rig.config.content_height
    driver.render_content(np.full((ch, cw, 3), level, np.float32))


def _applied(driver: RoomDriver, rig: Rig, room: Room, slots: list[str], exposure: float) -> float:
    """How much the blend maps change a noise-free flat white render: the largest relative change
    (0 means the in-process rig does not apply them)."""
    _flat(driver, rig, 1.0)
    on = room.render_linear(0, exposure=exposure)
    kept = {s: rig.slot(s).blend for s in slots}
    try:
        for s in slots:
            driver.update_slot(s, blend=None)
        _flat(driver, rig, 1.0)
        off = room.render_linear(0, exposure=exposure)
    finally:
        for s, b in kept.items():
            driver.update_slot(s, blend=b)
    scale = float(np.percentile(off, 99)) or 1.0
    return float(np.abs(on - off).max() / scale)


async def blended_rig(room: Room, slots: list[str], path: Path, *, content_size: tuple[int, int], poses: str,
                      luts: str, frames: int, headroom, map_scale: int | None, mesh_rig=None) -> Blended:
    """Align ``slots`` (the room's true poses or the calibrate job), linearise them (true LUTs or the
    response job), capture flat white and grey, run the blend job, capture them again.

    ``mesh_rig``: a function ``(path, room, slots) -> Rig`` making a mesh rig already posed (the bust);
    planar rigs are made here.
    """
    notes: list[str] = []
    room.set_active(slots)
    params = blend_params({"settle_s": 0.0, "headroom": "auto" if headroom is None else headroom,
                           **({} if map_scale is None else {"map_scale": map_scale}),
                           # a mesh rig's blend, where the job offers it on request
                           **({"experimental_mesh": True} if mesh_rig is not None else {})})
    if mesh_rig is not None and "experimental_mesh" in params:
        notes.append("the blend job's experimental mesh mode (experimental_mesh)")
    if mesh_rig is not None:
        rig = mesh_rig(path, room, slots)
    else:
        rig = make_rig(path, room, slots, content_size=content_size)
    driver = RoomDriver(room, rig)
    if mesh_rig is None:
        points = points_doc(table_points_from_truth(room, click_noise_px=0.3))
        # the content spans the room's surface (the wall's is not the 5x5 table's 1200 x 600 mm)
        table_mm = [float(v) for v in room.scene.table.size]
        if poses == "calibrate":
            t = time.perf_counter()
            cal = await driver.run("calibrate", {"mode": "multiplexed", "table_points": points, "settle_s": 0.0,
                                                "table_mm": table_mm})
            _log(f"{len(slots)} projectors: calibrated ({cal['captures']} captures, {time.perf_counter() - t:.0f} s)")
        else:
            for s in slots:
                H = room.truth.content_to_projector_homography(s, content_size)
                rig.update_slot(s, pose=HomographyPose(H / H[2, 2]), source="truth")
            await driver.run("calibrate", {"table_only": True, "table_points": points, "settle_s": 0.0,
                                           "table_mm": table_mm})
            notes.append("poses: the room's truth (the table mapped into the camera from clicked marks)")
    if luts == "response":
        t = time.perf_counter()
        resp = await driver.run("response", {"settle_s": 0.0})
        _log(f"{len(slots)} projectors: responses ({time.perf_counter() - t:.0f} s, linear {resp['linearity']['linear']})")
    elif mesh_rig is None or any(rig.slot(s).lut is None for s in slots):
        for s, lut in truth_luts(room, slots).items():
            rig.update_slot(s, lut=lut, source="truth")
        notes.append("LUTs: inverse of the room's true gammas")
    count = room.truth.illumination_count(0)
    lit = count > 0
    _flat(driver, rig, 1.0)
    exposure = pick_exposure(room, lit)
    white_before = mean_capture(room, frames, exposure)
    _flat(driver, rig, 0.5)
    grey_before = mean_capture(room, frames, exposure)
    c0 = driver.captures
    t = time.perf_counter()
    try:
        result = await driver.run("blend", params)
    except JobError as exc:
        if mesh_rig is not None and "planar" in str(exc):     # a job that measures planar rigs only
            raise Missing(f"the blend job does not measure a mesh rig in this build: {exc}") from None
        raise
    seconds = time.perf_counter() - t
    captures = driver.captures - c0
    _log(f"{len(slots)} projectors: blended ({captures} captures, {seconds:.1f} s)")
    if not any(rig.slot(s).blend is not None for s in slots):
        raise Missing("the blend job set no slot's blend maps")
    applied = _applied(driver, rig, room, slots, exposure)
    if applied < 1e-3:
        raise Missing("the in-process rig (shadowless/room_driver.py) does not apply blend maps: captures with and "
                      "without them are the same")
    _flat(driver, rig, 1.0)
    white_after = mean_capture(room, frames, exposure)
    _flat(driver, rig, 0.5)
    grey_after = mean_capture(room, frames, exposure)
    size = room.camera_size(0)
    target, black, covered = stored_target(rig.path, size, headroom=headroom)
    if covered is None:
        covered = lit
        notes.append("target: flat over the lit region (the stored contributions could not give the blend's target)")
    return Blended(slots=list(slots), result=result, captures=captures, seconds=seconds, exposure=exposure,
                   white_before=white_before, white_after=white_after, grey_before=grey_before, grey_after=grey_after,
                   target=target, black=black, covered=covered & lit, count=count, applied=applied, notes=notes)
