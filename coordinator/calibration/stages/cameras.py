"""Stage 2, cameras: how every camera sees the table (and, on a mesh, the world and the object).

Per camera, the table -> camera homography comes from known table points, a ChArUco
board found in the all-white capture, or the mapping an earlier run saved. On a mesh,
each camera is also posed in the world (:func:`imaging.calibration.threed.pose_camera`)
and the mesh is registered from landmarks given in its own frame. The result goes to
``calibration/cameras.json``.
"""
from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from imaging.calibration import planar, threed
from imaging.calibration.errors import CalibrationError
from imaging.calibration.points import PointSet
from coordinator.calibration.runs import rounded, save_cameras
from coordinator.calibration.stages.state import State
from coordinator.jobs import JobError
from coordinator.rig import mesh_with_id


async def map_cameras(st: State) -> None:
    """Fill ``st.setup`` and save it (calibration/cameras.json)."""
    ctx, opts, inputs, setup = st.ctx, st.opts, st.inputs, st.setup
    ncam = len(st.cameras)
    for i in st.cameras:
        setup.sizes[i] = (st.white[i].shape[1], st.white[i].shape[0])
    ctx.progress("cameras", "", 0, ncam, "table -> camera mapping")
    world_sets: dict[int, list[PointSet]] = {i: [] for i in st.cameras}
    for s in inputs.table_points:
        if s.camera not in world_sets:
            raise JobError(f"table points name camera {s.camera}, but the job has {ncam} camera(s)")
        world_sets[s.camera].append(s)
    if inputs.charuco is not None:
        for i in st.cameras:
            try:
                txy, px = await ctx.compute(planar.detect_charuco, st.white[i], inputs.charuco)
            except CalibrationError as exc:
                if inputs.table_points:
                    ctx.log(f"camera {i}: {exc}; using the table points")
                    continue
                raise JobError(f"camera {i}: {exc}") from exc
            world_sets[i].append(PointSet("world", i, tuple(f"charuco {k}" for k in range(len(txy))),
                                          np.column_stack([txy, np.zeros(len(txy))]), px))
    if inputs.auto_board is not None:
        for i in st.cameras:
            await _look_for_board(st, i, world_sets[i])
    for i in st.cameras:
        for s in world_sets[i]:
            check_points_inside(s.pixels, setup.sizes[i], i)
        on_table = [s for s in world_sets[i] if s.planar]
        if sum(len(s) for s in on_table) >= 4:
            xy = np.vstack([s.xyz[:, :2] for s in on_table])
            px = np.vstack([s.pixels for s in on_table])
            try:
                fit = planar.table_to_camera_from_points(xy, px)
            except CalibrationError as exc:
                raise JobError(f"camera {i}: {exc}") from exc
            setup.table_to_camera[i] = fit.H
            setup.table_rms[i] = fit.rms
    for i, saved in st.saved_table.items():
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
        await _pose_cameras_and_mesh(st, world_sets)
    ctx.progress("cameras", "", ncam, ncam, "ok")
    save_cameras(ctx.rig.path, _cameras_doc(st))


async def _look_for_board(st: State, i: int, found: list[PointSet]) -> None:
    """Without known points or a board given: look for the board on the table in camera ``i``'s white
    capture (the rig's board.json, or the default printed board). Found, its corners map the table;
    not found, the mapping an earlier run saved serves (or, on a mesh, the landmarks), and with
    neither the job ends with one line saying what to do."""
    ctx, opts, inputs = st.ctx, st.opts, st.inputs
    try:
        txy, px = await ctx.compute(planar.detect_charuco, st.white[i], inputs.auto_board)
    except CalibrationError as exc:
        if i in st.saved_table or (opts.surface == "mesh" and inputs.landmarks and not opts.table_only):
            return                  # the saved mapping (logged when used) or the landmarks
        raise JobError(f"camera {i}: the table -> camera mapping needs known points or a ChArUco board on the table, "
                       f"and no board was found ({inputs.auto_board_source}: {_first_clause(exc)}); lay the printed "
                       "board (`shadowless rig board`) flat on the table in the camera's view, or give table points "
                       "clicked in the camera image") from exc
    ctx.log(f"camera {i}: found {inputs.auto_board_source} on the table ({len(txy)} corners): the table is mapped "
            "from it" + ("" if opts.table_only else "; remove it before calibrating if projectors fail over it"))
    found.append(PointSet("world", i, tuple(f"charuco {k}" for k in range(len(txy))),
                          np.column_stack([txy, np.zeros(len(txy))]), px))


def _first_clause(exc: Exception) -> str:
    """``the ChArUco board was not found in the camera image (0 corners, need 6)`` of a longer message."""
    return str(exc).split(":")[0]


def _cameras_doc(st: State) -> dict:
    setup = st.setup
    doc: dict[str, Any] = {"run": st.run.run_id, "saved_at": time.time(), "table_mm": list(st.opts.table_mm),
                           "content_size": list(st.content_size), "cameras": []}
    for i in st.cameras:
        entry: dict[str, Any] = {"camera": i, "size": list(setup.sizes[i])}
        if i in setup.table_to_camera:
            entry["table_to_camera"] = setup.table_to_camera[i].tolist()
            entry["table_rms_px"] = rounded(setup.table_rms[i])
        if i in setup.devices:
            entry["pinhole"] = setup.devices[i].to_dict()
            entry["pose_rms_px"] = rounded(setup.device_rms[i])
        doc["cameras"].append(entry)
    if setup.rig_mesh is not None:
        doc["mesh"] = {"id": setup.rig_mesh.mesh_id, "file": st.inputs.mesh_path,
                       "registration_rms_px": rounded(setup.mesh_rms or math.nan)}
    return doc


def check_points_inside(px: np.ndarray, size: tuple[int, int], camera: int) -> None:
    """Refuse known points outside the camera's image (a points file made for another camera)."""
    w, h = size
    out = (px[:, 0] < -0.5) | (px[:, 1] < -0.5) | (px[:, 0] > w - 0.5) | (px[:, 1] > h - 0.5)
    if out.any():
        raise JobError(f"camera {camera}: {int(out.sum())} known point(s) lie outside its {w}x{h} image: "
                       "the points file was made for another camera or resolution")


async def _pose_cameras_and_mesh(st: State, world_sets: dict[int, list[PointSet]]) -> None:
    ctx, inputs, setup = st.ctx, st.inputs, st.setup
    try:
        mesh = threed.load_mesh(inputs.mesh_path)
    except CalibrationError as exc:
        raise JobError(str(exc)) from exc
    if mesh.uvs is None:
        raise JobError(f"mesh {inputs.mesh_path} has no texture coordinates: export it with UVs (the content is its texture)")
    model_sets = [s for s in inputs.landmarks if s.frame == "model"]
    for s in inputs.landmarks:
        if s.camera not in setup.sizes:
            raise JobError(f"landmarks name camera {s.camera}, but the job has {len(setup.sizes)} camera(s)")
        check_points_inside(s.pixels, setup.sizes[s.camera], s.camera)
        if s.frame == "world":
            world_sets.setdefault(s.camera, []).append(s)
    for i, sets in world_sets.items():
        if not sets:
            continue
        K = inputs.intrinsics.get(i)
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
                                                   fixed_intrinsics=set(inputs.intrinsics))
        except CalibrationError as exc:
            raise JobError(str(exc)) from exc
        setup.devices.update(devices)
        mesh = mesh.transformed(R, t)
        setup.mesh_rms = rms
        ctx.log(f"mesh registered from {sum(len(s) for s in model_sets)} landmarks (rms {rms:.2f} px)")
    setup.mesh = mesh
    setup.rig_mesh = mesh_with_id(mesh.vertices, mesh.uvs, mesh.faces)
