"""`shadowless bench board`: how well the printed ChArUco board maps the table into the camera.

For each sheet size, the board ``shadowless rig board`` lays out on it lies on the virtual room's
table as the room's camera sees it: the capture times the board's reflectance through the room's
true table -> camera homography (:func:`bench.calibration.board_albedo`; the room's table takes no
texture of its own). The coordinator's ``calibrate`` job (``table_only``, no points nor board given)
finds the rig's board.json board by itself, and the mapping it saves is compared with the room's
truth over the whole 1200x600 mm table (RMS and max camera px). Beside it, the default A3 board
in a synthetic 1944x1458 view drawn with OpenCV (:func:`board_view`: the page warped through a
perspective table -> camera homography, supersampled, with sensor noise), which the room's camera
cannot offer: corners found and their RMS distance to where the homography puts them.
"""
from __future__ import annotations

import argparse
import asyncio
import json
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from bench.calibration import board_albedo, make_rig
from bench.machine import machine
from imaging.calibration.board import PAPERS, BoardPage, board_page, page_image, spec_dict
from imaging.calibration.planar import apply_homography, detect_charuco, homography_difference
from protos import cli_types
from shadowless.room_driver import RoomDriver

#: a 1944x1458 camera above the table's front edge looking down at an angle (the room's, 3x finer)
OBLIQUE_CAMERA = np.array([[1.435, 0.0614, 970.5], [0.0, -1.383, 727.5], [0.0, 1.898e-4, 1.0]])
OBLIQUE_SIZE = (1944, 1458)


class _BoardCamera:
    """A room camera whose captures see a board's black and white squares on the table."""

    supports_exposure = False

    def __init__(self, camera, albedo: np.ndarray):
        self.camera, self.albedo = camera, albedo

    def capture(self, *, exposure=None):
        return self.camera.capture(exposure=exposure) * self.albedo[:, :, None]

    def close(self):
        self.camera.close()


def driver_with_board(room, rig, albedo: np.ndarray) -> RoomDriver:
    """The room's rig driver whose cameras see ``albedo`` ((H, W) float32 reflectance) on the table."""

    class BoardOnTable(RoomDriver):
        def open_camera(self, spec):
            return _BoardCamera(super().open_camera(spec), albedo)

    return BoardOnTable(room, rig)


def board_view(page: BoardPage, table_to_camera: np.ndarray, size: tuple[int, int], *, dpi: float = 300.0,
               supersample: int = 4, noise: float = 0.01, seed: int = 0) -> np.ndarray:
    """A camera's view of the printed page lying on the table: (H, W) float32 in 0..1.

    The page image at ``dpi`` (:func:`page_image`) is mapped page px -> table mm (the board where its
    description puts it) -> camera px by ``table_to_camera`` (3x3), drawn ``supersample`` times finer
    and area-averaged down to ``size`` (w, h); black paper reflects 6 % of what white does, and
    Gaussian noise of ``noise`` is added."""
    img = page_image(page, dpi=dpi)
    ox, oy = page.offset_mm
    k = 25.4 / dpi
    origin = page.spec.origin_mm
    page_to_table = np.array([[k, 0, origin[0] - ox + 0.5 * k], [0, -k, origin[1] + oy - 0.5 * k], [0, 0, 1]])
    ss = supersample
    up = np.array([[ss, 0, (ss - 1) / 2], [0, ss, (ss - 1) / 2], [0, 0, 1.0]])
    w, h = size
    fine = cv2.warpPerspective(img, up @ np.asarray(table_to_camera, np.float64) @ page_to_table, (w * ss, h * ss),
                               flags=cv2.INTER_AREA, borderValue=255)
    seen = cv2.resize(fine, (w, h), interpolation=cv2.INTER_AREA).astype(np.float32) / 255.0
    seen = 0.05 + 0.8 * seen
    return seen + np.random.default_rng(seed).normal(0, noise, seen.shape).astype(np.float32)


def configure(parser: argparse.ArgumentParser) -> None:
    parser.description = __doc__.split("\n\n")[1].replace("\n", " ")
    parser.add_argument("--papers", type=cli_types.names, default="A3,A2,A1,A0",
                        help=f"sheet sizes to lay on the room's table (default A3,A2,A1,A0; of {', '.join(PAPERS)})")
    parser.add_argument("--camera-scale", type=cli_types.number(0.05, 1), default=0.25,
                        help="room camera resolution scale (default 0.25: 648x486)")
    parser.add_argument("--seed", type=int, default=0, help="room seed (sensor noise)")


def run(args: argparse.Namespace) -> int:
    from sim.room import Room
    from sim.scene import reference_scene

    unknown = [p for p in args.papers if p not in PAPERS]
    if unknown:
        raise SystemExit(f"shadowless bench board: unknown paper {', '.join(unknown)} (known: {', '.join(PAPERS)})")
    room = Room(reference_scene(camera_scale=args.camera_scale), seed=args.seed)
    truth = room.truth.table_to_camera_homography()
    grid = np.array([[x, y] for x in np.linspace(-600, 600, 13) for y in np.linspace(-300, 300, 7)])
    px_per_mm = float(np.linalg.norm(apply_homography(truth, np.array([[1.0, 0.0]]))
                                     - apply_homography(truth, np.array([[0.0, 0.0]]))))
    papers = {}
    for paper in args.papers:
        page = board_page(paper)
        with tempfile.TemporaryDirectory() as tmp:
            rig = make_rig(Path(tmp) / "rig", room, ["r2c2"])
            (rig.path / "board.json").write_text(json.dumps(spec_dict(page.spec)))
            driver = driver_with_board(room, rig, board_albedo(room, page.spec))
            t0 = time.monotonic()
            try:
                asyncio.run(driver.run("calibrate", {"table_only": True, "settle_s": 0}))
            except Exception as exc:  # noqa: BLE001 - a sheet too small to read is a result
                papers[paper] = {"square_mm": page.spec.square_mm, "found": False, "error": str(exc)}
                continue
            doc = json.loads((rig.path / "calibration" / "cameras.json").read_text())["cameras"][0]
            rms, mx = homography_difference(np.array(doc["table_to_camera"]), truth, grid)
            papers[paper] = {"square_mm": page.spec.square_mm, "square_camera_px": round(page.spec.square_mm * px_per_mm, 1),
                             "found": True, "fit_rms_px": round(float(doc["table_rms_px"]), 4),
                             "table_rms_px": round(rms, 4), "table_max_px": round(mx, 4),
                             "seconds": round(time.monotonic() - t0, 2)}
    page = board_page()
    t_xy, px = detect_charuco(board_view(page, OBLIQUE_CAMERA, OBLIQUE_SIZE), page.spec)
    err = np.linalg.norm(px - apply_homography(OBLIQUE_CAMERA, t_xy), axis=1)
    doc = {"benchmark": "board", "machine": machine(),
           "parameters": {"papers": list(args.papers), "camera": list(room.camera_size(0)), "seed": args.seed,
                          "table_mm": [1200, 600], "camera_px_per_mm_at_centre": round(px_per_mm, 3)},
           "room": papers,
           "default_board_oblique": {"camera": list(OBLIQUE_SIZE), "corners": int(len(t_xy)),
                                     "of": (page.spec.squares_x - 1) * (page.spec.squares_y - 1),
                                     "rms_px": round(float(np.sqrt(np.mean(err ** 2))), 4),
                                     "max_px": round(float(err.max()), 4)}}
    print(json.dumps(doc, indent=2))
    return 0
