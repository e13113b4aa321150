"""Figures of one light-drop map: how deep, how wide and how hard a hand's shadow is on the table.

A light-drop map (``sim.truth``'s ground truth, or a measurement) holds, per camera pixel, the
fraction of the rig's light a point of the table lost. The figures, each over the table only:

* ``max``: the largest drop;
* ``mean``: the mean drop over the affected area (drop > 1 %);
* ``area_below_50_mm2``: table area left with less than half its light;
* ``umbra_mm2``: table area that lost at least 90 %;
* ``transition_mm``: the median distance from the 10 %-of-max contour to the region within 90 % of
  the max; 0 is a hard edge, a synthetic-aperture shadow fades in over tens of mm (None when the
  drop never passes 2 %);
* ``max_step``: the largest drop difference between neighbouring pixels that both see the table.

``bench room`` and the demo report them; the tests check them on maps whose figures are known.
"""
from __future__ import annotations

import cv2
import numpy as np


def drop_statistics(drop: np.ndarray, on_table: np.ndarray, px_area: np.ndarray) -> dict:
    """The figures above of one light-drop map, as a dict of rounded floats.

    ``drop``: (H, W) float, the fraction of light lost per camera pixel; ``on_table``: (H, W) bool,
    the pixels that see the table; ``px_area``: (H, W) float, mm^2 of table each pixel covers.
    """
    d = np.where(on_table, drop.astype(np.float64), 0.0)
    peak = float(d.max())
    affected = d > 0.01
    # Steps between neighbouring pixels that both see the table (not across its border).
    both_y = on_table[1:] & on_table[:-1]
    both_x = on_table[:, 1:] & on_table[:, :-1]
    step = max(float(np.abs(np.diff(d, axis=0))[both_y].max(initial=0.0)), float(np.abs(np.diff(d, axis=1))[both_x].max(initial=0.0)))
    stats = {
        "max": round(peak, 4),
        "mean": round(float(d[affected].mean()), 4) if affected.any() else 0.0,
        "area_below_50_mm2": round(float(px_area[d > 0.5].sum()), 1),
        "umbra_mm2": round(float(px_area[d >= 0.9].sum()), 1),
        "transition_mm": None,
        "max_step": round(step, 4),
    }
    if peak > 0.02:
        core = (d >= 0.9 * peak).astype(np.uint8)
        outer = d >= 0.1 * peak
        # The contour of the 10 % region inside the table (the table's own border is no contour).
        eroded = cv2.erode((outer | ~on_table).astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        edge = outer & ~eroded
        dist = cv2.distanceTransform((1 - core).astype(np.uint8), cv2.DIST_L2, 5)
        pitch = np.sqrt(px_area)
        vals = (dist * pitch)[edge.astype(bool) & on_table]
        if len(vals):
            stats["transition_mm"] = round(float(np.median(vals)), 2)
    return stats
