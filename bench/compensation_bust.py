"""`shadowless bench compensation_bust`: blur compensation on the bust (a mesh rig) in the virtual room.

The coordinator's ``response``, ``transport`` and ``compensate`` jobs run in-process against the
reference room with the procedural bust (:func:`sim.scene.reference_scene` ``surface="bust"``)
through :class:`shadowless.room_driver.RoomDriver`, which renders content on a mesh pose as a
node's mesh shader does (:func:`imaging.compensation.texture_space.mesh_warp`). Content is
the bust's texture: an even-density uv atlas (:func:`sim.mesh.bust` ``atlas=``) whose size follows
from the camera's sampling of the surface (:func:`texture_size_for`). By default the rig's poses and the camera's pose are the room's truth
(:func:`make_bust_rig`; 3D calibration is measured by ``bench calibration``); ``--calibrate``
runs the sequential 3D calibration first instead (about 20 s per projector).

Reported: the light transport (captures for the 25- and the 1-projector rig: the same grid, so
the same count; its error against the room's truth, per camera over the texels that camera measured,
:func:`mesh_transport_errors`), the texels the camera sees and measures, and the captured PSNR / SSIM over the
visible surface of none / the per-projector baseline / ours, with the side-by-side picture
(``--out``). ``--cameras 3``: the room's three cameras (:data:`sim.scene.RING_CAMERAS`) measure
together; the big rig is also compensated from the ceiling camera alone, and both results are
scored from the three cameras over the same surface (:mod:`bench.compensation_bust_cameras`). This module is also the test kit of
``tests/coordinator/compensation/test_mesh_*.py``. It may import ``sim``; the coordinator never does.
"""
from __future__ import annotations

import argparse
import asyncio
import json
import shutil
import sys
import tempfile
import time
from contextlib import nullcontext
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from bench.calibration import landmarks_from_truth, make_rig, table_points_from_truth
from bench.compensation_bust_oracle import bust_oracle
from bench.compensation_room import demo_image
from bench.machine import machine
from coordinator.calibration.runs import save_cameras
from imaging.calibration.threed import depth_range
from coordinator.compensation.image_param import encode_image_array
from coordinator.compensation.mesh_cameras import camera_blocks
from imaging.compensation.mesh_geometry import measured_texels
from imaging.compensation.texture_space import DeviceView, MeshCaster, padded, padding_index, texels_per_pixel
from imaging.compensation.transport import transport_error
from coordinator.rig import ProjectionPose, Rig, mesh_with_id
from protos import cli_types
from protos.spaces import bilinear_taps
from shadowless.room_driver import RoomDriver
from sim.mesh import bust, save_mesh
from sim.room import Room
from sim.scene import SUBSETS, reference_scene

__all__ = ["make_bust_rig", "bust_room", "mesh_lookup_matrix", "truth_mesh_transport", "mesh_transport_errors",
           "texture_size_for"]


# ---------------------------------------------------------------------- the test kit
def mesh_lookup_matrix(view: DeviceView, content_size: tuple[int, int]) -> sp.csr_matrix:
    """A node's content lookup on a mesh pose as a matrix: ``(w*h, W*H)`` CSR float64, projector px x texel
    (the bilinear weights of :func:`protos.spaces.bilinear_taps` at each pixel's texel coordinates, 0 off
    the mesh): what :func:`imaging.compensation.texture_space.mesh_warp` applies."""
    h, w = view.shape
    x = np.nan_to_num(view.x, nan=-10.0)
    y = np.nan_to_num(view.y, nan=-10.0)
    rows, cols, vals = [], [], []
    for index, weight in bilinear_taps(x, y, content_size):
        ok = weight > 0
        rows.append(np.flatnonzero(ok))
        cols.append(index[ok])
        vals.append(weight[ok])
    cw, ch = content_size
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(w * h, cw * ch))


def truth_mesh_transport(room: Room, rig: Rig, slots: list[str], *, camera: int = 0) -> sp.csr_matrix:
    """The mesh rig's true light transport, texel -> camera px, as the jobs measure it:
    :func:`bench.compensation_room.truth_transport` with each node's lookup through its mesh pose, of the
    texture with its chart edges padded (:func:`~imaging.compensation.texture_space.padding_index`), as
    the jobs send every image, dot patterns included: a texel's column holds its padding texels' light."""
    content = (rig.config.content_width, rig.config.content_height)
    views = {}
    mesh = rig.slot(slots[0]).pose.mesh
    with MeshCaster(mesh.vertices, mesh.uvs, mesh.faces) as caster:
        pad = padding_index(np.isfinite(caster.atlas(content)).all(axis=2))
    for s in slots:
        st, pose = rig.slot(s), rig.slot(s).pose
        with MeshCaster(pose.mesh.vertices, pose.mesh.uvs, pose.mesh.faces) as caster:
            views[s] = caster.view(pose.matrix, (st.width, st.height), content, near=pose.near_mm, far=pose.far_mm)
    n = len(pad)
    padding = sp.csr_matrix((np.ones(n), (np.arange(n), pad)), shape=(n, n))     # texel j shows texel pad[j]
    total = None
    for s in slots:
        st = rig.slot(s)
        B = mesh_lookup_matrix(views[s], content) @ padding
        part = (sp.csr_matrix(room.truth.transport(s, camera), dtype=np.float64) @ B) \
            * (st.gain * float(np.mean(1 - room.truth.projector(s).black)))
        total = part if total is None else total + part
    return sp.csr_matrix(total, dtype=np.float32)


def mesh_transport_errors(L: sp.spmatrix, truths: list[sp.spmatrix]) -> dict:
    """A measured (stacked) mesh ``L`` against the truth of each of its cameras, each camera over the texels
    it measured: ``{"per_camera": [...], "stacked": e}`` relative Frobenius errors.

    A camera's rows of ``L`` hold only the texels it has a window for; the light of the others (seen at a
    grazing angle, too large for a window, seen by another camera only) reaches it all the same, on pixels
    the solve does not weigh. So camera ``k``'s truth counts in texel ``j``'s column only when ``L``
    measured ``j`` in camera ``k``; ``stacked`` is the error of the whole ``L`` against those columns.
    """
    blocks = camera_blocks(L, len(truths))
    kept, per = [], []
    for block, truth in zip(blocks, truths):
        m = measured_texels(block)
        t = sp.csr_matrix(sp.csr_matrix(truth, dtype=np.float64) @ sp.diags(m.astype(np.float64)))
        kept.append(t)
        per.append(transport_error(sp.csr_matrix(block.tocsc()[:, m]), sp.csr_matrix(t.tocsc()[:, m])))
    cols = measured_texels(L)
    stacked = transport_error(sp.csr_matrix(sp.csc_matrix(L)[:, cols]),
                              sp.csr_matrix(sp.vstack(kept, format="csc")[:, cols]))
    return {"per_camera": per, "stacked": stacked}


def texture_size_for(room: Room, *, camera: int = 0, px_per_texel: float = 2.5, aspect: tuple[int, int] = (4, 3)
                     ) -> tuple[int, int]:
    """The bust's texture size (W, H) at which a texel the camera sees spans about ``px_per_texel`` camera px.

    A texel spanning many camera pixels wastes the camera's resolution on a coarse content; one
    smaller than a pixel cannot be measured apart from its neighbours. The median over the surface
    the camera sees (cosine of the viewing angle >= 0.25), of the camera px per texel of a
    reference atlas, scales the reference size; W is a multiple of ``4 * aspect[0]``.
    """
    ref = (16 * aspect[0], 16 * aspect[1])
    b = bust(atlas=ref)
    c = room.truth.camera(camera)
    P = c.K @ np.column_stack([c.R, np.asarray(c.t).reshape(3)])
    with MeshCaster(b.vertices, b.uvs, b.faces) as caster:
        view = caster.view(P, tuple(c.size), ref)
    area = texels_per_pixel(view)
    ok = view.on_mesh & (view.cos >= 0.25) & np.isfinite(area) & (area > 0)
    side = 1.0 / np.sqrt(float(np.median(area[ok])))            # camera px per reference texel
    unit = 4 * aspect[0]
    w = max(unit, int(round(ref[0] * side / px_per_texel / unit)) * unit)
    return w, w * aspect[1] // aspect[0]


def bust_room(*, projector_scale: float = 0.25, camera_scale: float = 0.25, seed: int = 0, aperture: float = 10.0,
              noise: bool = True, cameras: int = 1) -> Room:
    """The reference 5x5 room with the procedural bust at the table centre (``cameras``: 1 or 3)."""
    return Room(reference_scene(projector_scale=projector_scale, camera_scale=camera_scale, surface="bust", seed=seed,
                                aperture=aperture, cameras=cameras), seed=seed, noise=noise)


def make_bust_rig(path: Path, room: Room, slots: list[str], *, content_size: tuple[int, int] = (128, 96),
                  cameras: int = 1, luts: bool = False) -> Rig:
    """A mesh rig posed from the room's truth: every slot's true 3x4 projection with the bust and each camera's
    true pinhole in ``calibration/cameras.json``, as 3D calibration writes them; with ``luts`` each slot's
    inverse-response LUT from its true gamma (instead of the ``response`` job).

    The rig's bust is the room's surface with an even-density uv atlas for ``content_size``
    (:func:`sim.mesh.bust` ``atlas=``), as a scan's texture would be; the room renders light on the
    geometry only, so its own (cylindrical) uvs do not matter."""
    if room.scene.mesh_source != "builtin:bust":
        raise ValueError("make_bust_rig needs the room's builtin bust (bust_room)")
    rig = make_rig(path, room, slots, content_size=content_size)
    b = bust(atlas=content_size)
    mesh = mesh_with_id(b.vertices, b.uvs, b.faces)
    for s in slots:
        P = room.truth.projector(s).P
        near, far = depth_range(P, mesh.vertices)
        rig.update_slot(s, pose=ProjectionPose(P, mesh, near, far), source="calibration")
        if luts:
            grid = np.linspace(0.0, 1.0, 1024)
            gamma = room.truth.projector(s).gamma
            rig.update_slot(s, lut=np.stack([grid ** (1.0 / g) for g in gamma]).astype(np.float32), source="truth")
    doc = {"content_size": list(content_size), "table_mm": list(room.scene.table.size), "cameras": []}
    for i in range(cameras):
        c = room.truth.camera(i)
        doc["cameras"].append({"camera": i, "size": list(c.size),
                               "pinhole": {"K": c.K.tolist(), "R": c.R.tolist(), "t": c.t.tolist(),
                                           "size": list(c.size)}})
    save_cameras(rig.path, doc)
    return rig


async def calibrated_bust_rig(path: Path, room: Room, slots: list[str], *, content_size: tuple[int, int]) -> tuple[Rig, dict]:
    """A mesh rig from the ``calibrate`` job (sequential Gray codes on the bust, table points and landmarks
    clicked with noise from the room's truth)."""
    path.mkdir(parents=True, exist_ok=True)
    save_mesh(bust(atlas=content_size), path / "bust.obj")
    table_points_from_truth(room, path / "table.json", click_noise_px=0.3)
    landmarks_from_truth(room, path / "landmarks.json", count=20, click_noise_px=0.5)
    rig = make_rig(path / "rig", room, slots, content_size=content_size)
    out = await RoomDriver(room, rig).run("calibrate", {"mesh": str(path / "bust.obj"), "settle_s": 0.0,
                                                            "table_points": str(path / "table.json"),
                                                            "landmarks": str(path / "landmarks.json")})
    return rig, out


# ---------------------------------------------------------------------- the benchmark
def configure(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Blur compensation on the bust (a mesh rig: content is the mesh's texture) in the virtual room, through\n"
        "the coordinator's jobs in-process: light transport in texture space (every projector at once; the\n"
        "baseline one projector at a time), the weighted solve, and the captured quality over the visible\n"
        "surface of none / baseline / ours. One JSON document."
    )
    parser.epilog = ("examples:\n  shadowless bench compensation_bust --quick\n"
                     "  shadowless bench compensation_bust --quick --baseline   # ours against the baseline, 4 projectors\n"
                     "  shadowless bench compensation_bust --quick --cameras 3   # three cameras vs the ceiling one\n"
                     "  shadowless bench compensation_bust --content-size 128x96 --out /tmp/bust\n"
                     "  shadowless bench compensation_bust --calibrate   # 3D calibration first (slow)")
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("--quick", action="store_true",
                        help="4 projectors and 1, no baseline unless --baseline: a smoke run (a few minutes)")
    parser.add_argument("--projector-scale", type=float, default=0.5, help="room projector resolution (default 0.5)")
    parser.add_argument("--camera-scale", type=float, default=0.25, help="room camera resolution (default 0.25)")
    parser.add_argument("--content-size", type=cli_types.size, default=None, metavar="WxH",
                        help="texture size (default: a texel the camera sees spans about 2.5 camera px; 304x228 at "
                             "--camera-scale 0.25)")
    parser.add_argument("--aperture", type=float, default=10.0, help="projector lens aperture, mm (defocus; default 10)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--radius", type=int, default=None, help="PSF recovery radius (default: from the geometry)")
    parser.add_argument("--frames", type=int, default=1, help="captures averaged per dot pattern (default 1)")
    parser.add_argument("--baseline-frames", type=int, default=None,
                        help="captures averaged per dot pattern of the baseline's L_i (default: --frames)")
    parser.add_argument("--baseline", action=argparse.BooleanOptionalAction, default=None,
                        help="the per-projector baseline (and, with one camera, the oracle) beside ours (default: on, "
                             "off with --quick)")
    parser.add_argument("--cameras", type=int, choices=(1, 3), default=1,
                        help="the room's cameras that measure together: 1 (the ceiling camera) or 3 (plus two around "
                             "the bust; the ceiling camera alone is compared, scored from all three)")
    parser.add_argument("--calibrate", action="store_true", help="3D-calibrate the rig first instead of the true poses")
    parser.add_argument("--response", action="store_true",
                        help="measure the responses (`response --mode full`) instead of the LUTs from the true gammas")
    parser.add_argument("--max-iter", type=int, default=300)
    parser.add_argument("--eval-frames", type=int, default=8, help="captures averaged per evaluated result (default 8)")
    parser.add_argument("--no-oracle", dest="oracle", action="store_false",
                        help="skip the oracle (with the baseline and one camera: both methods solved again with the "
                             "measured and the room's true transports, scored through the true one)")
    parser.add_argument("--out", type=Path, default=None, help="copy the side-by-side picture and the rig's JSON here")
    parser.add_argument("--keep", type=Path, default=None, metavar="DIR",
                        help="build the rigs in DIR (new or empty) and keep them, measured transports included, to "
                             "study further (default: a temporary directory, removed)")


def _log(msg: str) -> None:
    print(f"[bench compensation_bust] {msg}", file=sys.stderr, flush=True)


async def _rig_run(room: Room, slots: list[str], workdir: Path, args, *, baseline: bool, compare: bool = False) -> dict:
    """One rig's transport and compensation; with ``compare`` (several cameras) the ceiling camera's alone first,
    then both results scored from every camera."""
    k = args.cameras
    out: dict = {"projectors": len(slots), "cameras": k}
    cs = tuple(args.content_size)
    t = time.perf_counter()
    if args.calibrate:
        rig, cal = await calibrated_bust_rig(workdir, room, slots, content_size=cs)
        out["calibration"] = {"captures": cal.get("captures"), "wall_s": round(time.perf_counter() - t, 2)}
    else:
        rig = make_bust_rig(workdir / "rig", room, slots, content_size=cs, luts=not args.response, cameras=k)
        out["calibration"] = "the room's true poses (projectors and camera)"
    driver = RoomDriver(room, rig, cameras=k)
    if args.response:
        c0 = driver.captures
        resp = await driver.run("response", {"settle_s": 0.0, "mode": "full"})
        out["response"] = {"captures": driver.captures - c0, "linearity": resp["linearity"]}
    else:
        out["response"] = "LUTs from the room's true gammas"
    params = {"settle_s": 0.0, "frames": args.frames, **({"radius": args.radius} if args.radius else {})}
    cp = {"image": encode_image_array(demo_image(cs), "astronaut.png"), "evaluate": True, "settle_s": 0.0,
          "eval_frames": args.eval_frames, "max_iter": args.max_iter, **params}
    one_x = None
    if compare:
        c0 = driver.captures
        t = time.perf_counter()
        res = await driver.run("compensate", cp)          # the ceiling camera alone: measures its own L first
        one_x = rig.content.image.copy()
        out["one_camera"] = {"texture": res["texture"], "quality_from_its_camera": res["quality"]["ours"],
                             "captures": driver.captures - c0, "wall_s": round(time.perf_counter() - t, 2)}
        _log(f"N={len(slots)}: compensated from the ceiling camera alone ({json.dumps(res['quality']['ordering'])})")
    if k > 1:
        params["camera_indices"] = list(range(k))
        cp["camera_indices"] = list(range(k))
    c0 = driver.captures
    t = time.perf_counter()
    tr = await driver.run("transport", params)
    truths = await asyncio.to_thread(lambda: [truth_mesh_transport(room, rig, slots, camera=c) for c in range(k)])
    from imaging.compensation.transport import load_transport

    L, meta = load_transport(rig.path / "compensation" / "transport.npz")
    exposure = float(meta.get("exposure", 1.0))        # L is in the units of the exposure it was measured at
    errs = mesh_transport_errors(L, [t * np.float32(exposure) for t in truths])
    err = errs["stacked"]
    out["transport"] = {"captures": driver.captures - c0, "wall_s": round(time.perf_counter() - t, 2),
                        "patterns": tr["patterns"], "spacing": tr["spacing"], "radius": tr["radius"],
                        "edge_energy": tr["edge_energy"], "texture": tr["texture"], "exposure": exposure,
                        "white_peak": tr.get("white_peak"), "dot_gain": tr.get("dot_gain"),
                        "relative_error_measured_columns": round(err, 5),
                        "relative_error_per_camera": [round(e, 5) for e in errs["per_camera"]]}
    _log(f"N={len(slots)}: transport ({out['transport']['captures']} captures, error {err:.4f})")
    if baseline:
        cp.update(baseline=True, baseline_exposure=float(len(slots)), baseline_frames=args.baseline_frames or args.frames)
    c0 = driver.captures
    t = time.perf_counter()
    res = await driver.run("compensate", cp)
    out["compensate"] = {k: res[k] for k in ("solve", "texture", "quality", "baseline", "baseline_over_ours_seconds")
                         if k in res}
    out["compensate"]["captures"] = driver.captures - c0
    out["compensate"]["wall_s"] = round(time.perf_counter() - t, 2)
    _log(f"N={len(slots)}: compensated ({json.dumps(res['quality']['ordering'])})")
    if baseline and k == 1 and args.oracle:
        _log(f"N={len(slots)}: oracle solves (measured and true transports, scored through the true one)")
        t = time.perf_counter()
        out["compensate"]["oracle"] = await asyncio.to_thread(
            bust_oracle, lambda which: truth_mesh_transport(room, rig, which), rig, slots, res, max_iter=args.max_iter)
        out["compensate"]["oracle"]["wall_s"] = round(time.perf_counter() - t, 2)
    if compare:
        from bench.compensation_bust_cameras import score_from_cameras

        x = rig.content.image.copy()
        mesh = rig.slot(slots[0]).pose.mesh
        with MeshCaster(mesh.vertices, mesh.uvs, mesh.faces) as caster:
            pad = padding_index(np.isfinite(caster.atlas(cs)).all(axis=2))
        none = padded(np.clip(demo_image(cs).astype(np.float32) / 255 * np.float32(res["none_scale"]), 0, 1), pad)
        out["scored_from_every_camera"] = await asyncio.to_thread(
            score_from_cameras, driver, demo_image(cs), {"none": none, "one_camera": one_x, "cameras": x},
            level=float(res["target_level"]), frames=args.eval_frames)
        _log(f"N={len(slots)}: scored from every camera")
    out["rig_dir"] = str(rig.path)
    return out


def run(args: argparse.Namespace) -> int:
    if args.calibrate and args.cameras > 1:
        raise SystemExit("--calibrate poses the ceiling camera only; --cameras 3 uses the "
                         "room's true poses")
    if args.keep is not None and args.keep.exists() and any(args.keep.iterdir()):
        raise SystemExit(f"--keep {args.keep} is not empty")
    t0 = time.perf_counter()
    room = bust_room(projector_scale=args.projector_scale, camera_scale=args.camera_scale, seed=args.seed,
                     aperture=args.aperture, cameras=args.cameras)
    if args.content_size is None:
        args.content_size = texture_size_for(room)
    big = ["r1c1", "r1c3", "r3c1", "r3c3"] if args.quick else list(SUBSETS["P25"])
    baseline = (not args.quick) if args.baseline is None else args.baseline
    doc: dict = {"benchmark": "compensation_bust", "machine": machine(),
                 "parameters": {**{k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()
                                   if not k.startswith("_") and k not in ("command", "bench")},
                                "projector_size": list(room.projector_size("r0c0")), "camera_size": list(room.camera_size(0))}}
    with (nullcontext(str(args.keep)) if args.keep is not None
          else tempfile.TemporaryDirectory(prefix="bench-compensation-bust-")) as tmp:
        rigs = {str(len(big)): asyncio.run(_rig_run(room, big, Path(tmp) / "big", args, baseline=baseline,
                                                    compare=args.cameras > 1))}
        # the same dot grid for one projector (the radius follows the projectors' pixel size otherwise)
        one = argparse.Namespace(**{**vars(args), "radius": rigs[str(len(big))]["transport"]["radius"]})
        rigs["1"] = asyncio.run(_rig_run(room, ["r2c2"], Path(tmp) / "one", one, baseline=False))
        if args.out is not None:
            args.out.mkdir(parents=True, exist_ok=True)
            src = Path(rigs[str(len(big))]["rig_dir"]) / "compensation"
            for f in ("quality.png", "quality.json", "result.json", "transport.json"):
                if (src / f).exists():
                    shutil.copy(src / f, args.out / f)
        if args.keep is None:
            for r in rigs.values():
                r.pop("rig_dir", None)
    doc["rigs"] = rigs
    q = rigs[str(len(big))]["compensate"]["quality"]
    targets: dict = {"quality_order": {"none_psnr": q["none"]["psnr"], "ours_psnr": q["ours"]["psnr"],
                                       "ours_minus_none_db": q["ordering"]["ours_minus_none_db"]},
                     "transport_captures_N_vs_1": [rigs[str(len(big))]["transport"]["captures"],
                                                   rigs["1"]["transport"]["captures"]]}
    if "baseline" in q:
        d = q["ordering"]
        targets["quality_order"].update(baseline_psnr=q["baseline"]["psnr"],
                                        ours_minus_baseline_db=d["ours_minus_baseline_db"],
                                        baseline_minus_none_db=d["baseline_minus_none_db"],
                                        met=d["ours_minus_baseline_db"] >= -0.05 and d["baseline_minus_none_db"] > 1.0
                                        and d["ours_minus_none_db"] > 1.0)
        oracle = rigs[str(len(big))]["compensate"].get("oracle")
        if oracle:
            targets["ours_minus_baseline_through_truth_db"] = {
                k: oracle[k]["ours_minus_baseline_db"] for k in ("true_transport", "measured_transport")}
    if args.cameras > 1:
        r = rigs[str(len(big))]
        sc = r["scored_from_every_camera"]
        targets["cameras_vs_ceiling_camera"] = {
            "measured_share": [r["compensate"]["texture"]["measured_share"], r["one_camera"]["texture"]["measured_share"]],
            "compensated_texels": [r["compensate"]["texture"]["compensated"], r["one_camera"]["texture"]["compensated"]],
            "psnr_from_every_camera": {k: sc[k]["psnr"] for k in ("none", "one_camera", "cameras")},
            "ssim_from_every_camera": {k: sc[k]["ssim"] for k in ("none", "one_camera", "cameras")},
            "met": sc["cameras"]["psnr"] > sc["one_camera"]["psnr"] > sc["none"]["psnr"]}
    doc["targets"] = targets
    doc["wall_s"] = round(time.perf_counter() - t0, 1)
    print(json.dumps(doc, indent=2, default=float))
    return 0
