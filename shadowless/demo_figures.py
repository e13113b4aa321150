"""The demo's pictures, made to be read without the README: every panel captioned on the picture,
and the light drop on the table in millimetres with its colour bar.

From captures the demo already has: the camera shots of P1 and P25 and the room's light-drop maps.
The compensation's picture is the compensate job's own (``compensation/quality.png``, drawn by
:func:`imaging.compensation.quality_figure.compensation_figure`), which the demo copies.

Pictures are (H, W, 3) uint8 BGR (what ``cv2.imwrite`` takes).
"""
from __future__ import annotations

import cv2
import numpy as np

from imaging.calibration.heatmap_figure import heatmap_figure, put_text
from imaging.compensation.quality_figure import GAP, caption_band, column, panel, row

__all__ = ["teaser_figure", "light_drop_figure", "drop_on_table", "TEASER_CAPTIONS"]


def camera_view(img: np.ndarray) -> np.ndarray:
    """A camera capture, (H, W, 3) linear float RGB, as 8-bit BGR for viewing (gamma 2.2)."""
    v = np.clip(np.asarray(img, np.float32), 0, 1) ** (1 / 2.2)
    return cv2.cvtColor((v * 255 + 0.5).astype(np.uint8), cv2.COLOR_RGB2BGR)


# ------------------------------------------------------------------------------------------ teaser
#: (setup, hand) -> caption lines of the teaser's tiles ({h}: the hand's height in m)
TEASER_CAPTIONS = {
    ("P1", False): ["P1: one bright projector at the centre", "(the usual setup), no hand"],
    ("P1", True): ["P1: one bright projector at the centre,", "hand {h:g} m above the table"],
    ("P25", False): ["P25: the 5 x 5 ceiling array, 25 projectors", "(synthetic aperture), no hand"],
    ("P25", True): ["P25: the 5 x 5 ceiling array, 25 projectors,", "hand {h:g} m above the table"],
}


def teaser_figure(shots: dict[tuple[str, bool], np.ndarray], hand_height_mm: float) -> np.ndarray:
    """P1 against P25, without and with the hand: the camera's four shots ((H, W, 3) linear float RGB,
    keyed (setup, hand)) in a 2 x 2 grid, each captioned, under a title saying what is compared."""
    h = hand_height_mm / 1000.0
    rows = [row([panel(camera_view(shots[(n, hand)]), [t.format(h=h) for t in TEASER_CAPTIONS[(n, hand)]])
                 for hand in (False, True)]) for n in ("P1", "P25")]
    title = caption_band(rows[0].shape[1], [
        "The same image from the same total light: one projector (P1, top) against 25 (P25, bottom),",
        f"seen by the room's camera over the 1200 x 600 mm table; right: a hand {h:g} m above the table.",
    ], scale=0.55)
    return column([title] + rows)


# -------------------------------------------------------------------------------------- light drop
def table_grid_to_camera(camera_p: np.ndarray, table_mm: tuple[float, float], mm_per_px: float) -> np.ndarray:
    """(3, 3) float64: a table grid's pixel (column, row; row 0 at +y, the far edge) to camera pixels.
    The grid covers the table, ``mm_per_px`` a pixel, its pixel centres at half steps."""
    tw, th = table_mm
    grid_to_table = np.array([[mm_per_px, 0.0, -tw / 2 + mm_per_px / 2],
                              [0.0, -mm_per_px, th / 2 - mm_per_px / 2],
                              [0.0, 0.0, 1.0]])
    return np.asarray(camera_p, np.float64)[:, [0, 1, 3]] @ grid_to_table


def drop_on_table(drop: np.ndarray, camera_p: np.ndarray, table_mm=(1200.0, 600.0), mm_per_px: float = 2.0) -> np.ndarray:
    """A light-drop map in camera pixels ((H, W) float, fraction lost) resampled on the table:
    (th / mm_per_px, tw / mm_per_px) float32, row 0 at the far edge (+y)."""
    size = (int(round(table_mm[0] / mm_per_px)), int(round(table_mm[1] / mm_per_px)))
    m = table_grid_to_camera(camera_p, table_mm, mm_per_px)
    return cv2.warpPerspective(np.asarray(drop, np.float32), m, size, flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                               borderMode=cv2.BORDER_REPLICATE)


def light_drop_figure(drops: dict[str, np.ndarray], camera_p: np.ndarray, *, hand_mm: tuple[float, float],
                      hand_height_mm: float, table_mm=(1200.0, 600.0), mm_per_px: float = 2.0) -> tuple[np.ndarray, dict]:
    """The light drop of each setup (``drops``: name -> (H, W) camera-pixel map, fraction of the rig's
    light lost) on the table in mm, 0..100 % on one colour bar, the hand's position marked; side by side
    under a title. Returns the picture and each map's layout (:func:`heatmap_figure`'s, by name)."""
    tw, th = table_mm
    layouts, figures = {}, []
    for name, drop in drops.items():
        values = 100.0 * np.clip(drop_on_table(drop, camera_p, table_mm, mm_per_px), 0.0, 1.0)
        png, layout = heatmap_figure(values, (-tw / 2, tw / 2, th / 2, -th / 2), units="table mm", full_scale=100.0,
                                     title=f"{name}: light lost per point of the table", bar_units="% lost",
                                     no_data=None, open_ended=False)
        fig = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
        mx0, my0, mx1, my1 = layout["map"]
        hx = mx0 + (hand_mm[0] + tw / 2) / tw * (mx1 - mx0)
        hy = my0 + (th / 2 - hand_mm[1]) / th * (my1 - my0)
        at = (int(round(hx)), int(round(hy)))
        cv2.drawMarker(fig, at, (255, 255, 255), cv2.MARKER_CROSS, 18, 4, cv2.LINE_AA)
        cv2.drawMarker(fig, at, (0, 0, 0), cv2.MARKER_CROSS, 18, 2, cv2.LINE_AA)
        put_text(fig, "hand", (at[0] - 12, at[1] - 14), align="right", colour=(255, 255, 255), scale=0.5,
                 outline=(0, 0, 0))
        layouts[name] = layout
        figures.append(fig)
    title = caption_band(sum(f.shape[1] for f in figures) + GAP * (len(figures) - 1), [
        f"Light drop: how much of the rig's light a hand {hand_height_mm / 1000:g} m above the table (+ marks its palm) "
        "takes from each point of the table.",
        "0 % (dark blue): untouched; 100 % (dark red): no light at all, a hard shadow. Same scale for both setups.",
    ], scale=0.55)
    return column([title, row(figures)]), layouts
