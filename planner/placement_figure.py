"""The placement's picture: the table from above, once per placement, each panel coloured by how
many projectors reach the object's surface (its top-most point per pixel), with the footprints of
every placement outlined (the chosen one red, the others dark grey), mm axes and a colour bar.
PNG through OpenCV.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from planner.placement import Placement
from protos.wording import count as counted

__all__ = ["placement_picture", "count_colour"]

UNREACHED_BGR = (150, 150, 150)
TABLE_BGR = (238, 238, 238)


def count_colour(count: np.ndarray, max_count: int) -> np.ndarray:
    """(n, 3) uint8 BGR of counts (n,) int: viridis from 1 to ``max_count``, grey for 0."""
    c = np.asarray(count)
    level = np.clip(np.round(255.0 * (c - 1) / max(1, max_count - 1)), 0, 255).astype(np.uint8)
    bgr = cv2.applyColorMap(level.reshape(-1, 1), cv2.COLORMAP_VIRIDIS).reshape(-1, 3)
    bgr[c <= 0] = UNREACHED_BGR
    return bgr


def _footprint(vertices: np.ndarray, p: Placement) -> np.ndarray:
    xy = p.to_room(np.asarray(vertices, np.float64))[:, :2]
    return cv2.convexHull(xy.astype(np.float32)).reshape(-1, 2)


def placement_picture(path: str | Path, table_size: tuple[float, float], vertices: np.ndarray,
                      panels: Sequence[tuple[str, Placement, np.ndarray, np.ndarray]], *, max_count: int,
                      scale: float = 0.6) -> None:
    """Write the picture.

    Parameters
    ----------
    table_size : (w, h) mm, the table centred on the origin
    vertices : (V, 3) the object in its own frame
    panels : (label, placement, room points (n, 3) float64, count (n,) int) per panel; the
        last panel's placement is the chosen one (outlined red everywhere)
    max_count : the colour bar's top (the number of projectors)
    scale : pixels per mm
    """
    tw, th = table_size
    margin_l, margin_t, margin_b = 56, 30, 40
    W, H = math.ceil(tw * scale), math.ceil(th * scale)
    pw, ph = W + margin_l + 16, H + margin_t + margin_b
    placements = [p for _, p, _, _ in panels]
    out = []
    for label, placement, pts, count in panels:
        img = np.full((ph, pw, 3), 255, np.uint8)

        def px(x, y):
            return margin_l + (x + tw / 2) * scale, margin_t + (th / 2 - y) * scale   # +y up

        cv2.rectangle(img, (margin_l, margin_t), (margin_l + W, margin_t + H), TABLE_BGR, -1)
        order = np.argsort(pts[:, 2], kind="stable")        # the top-most point drawn last
        colours = count_colour(count[order], max_count)
        u, v = px(pts[order, 0], pts[order, 1])
        r = max(1, round(scale * 4))
        for (x, y), col in zip(np.stack([u, v], axis=1).astype(np.int32), colours):
            cv2.rectangle(img, (int(x) - r, int(y) - r), (int(x) + r, int(y) + r), tuple(int(c) for c in col), -1)
        for q in placements:
            hull = _footprint(vertices, q)
            hx, hy = px(hull[:, 0], hull[:, 1])
            poly = np.stack([hx, hy], axis=1).round().astype(np.int32)
            chosen = q is placements[-1]
            cv2.polylines(img, [poly], True, (40, 40, 220) if chosen else (60, 60, 60), 2 if chosen else 1, cv2.LINE_AA)
            cx, cy = px(q.x, q.y)
            cv2.drawMarker(img, (round(cx), round(cy)), (40, 40, 220) if chosen else (60, 60, 60), cv2.MARKER_CROSS, 10, 1)
        cv2.rectangle(img, (margin_l, margin_t), (margin_l + W, margin_t + H), (90, 90, 90), 1)
        # mm axes
        for x in range(-int(tw // 2) // 100 * 100, int(tw // 2) + 1, 200):
            X, _ = px(x, 0)
            cv2.line(img, (round(X), margin_t + H), (round(X), margin_t + H + 5), (0, 0, 0), 1)
            cv2.putText(img, str(x), (round(X) - 12, margin_t + H + 18), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (0, 0, 0), 1, cv2.LINE_AA)
        for y in range(-int(th // 2) // 100 * 100, int(th // 2) + 1, 100):
            _, Y = px(0, y)
            cv2.line(img, (margin_l - 5, round(Y)), (margin_l, round(Y)), (0, 0, 0), 1)
            cv2.putText(img, str(y), (4, round(Y) + 4), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (0, 0, 0), 1, cv2.LINE_AA)
        cv2.putText(img, "x mm", (margin_l + W // 2 - 14, ph - 6), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
        cv2.putText(img, "y mm", (4, margin_t - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
        reached = count[count > 0]
        title = f"{label}: {placement}; every lit point reached by at least {counted(int(reached.min()) if len(reached) else 0, 'projector')}"
        cv2.putText(img, title, (margin_l + 60, margin_t - 10), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (0, 0, 0), 1, cv2.LINE_AA)
        out.append(img)
    # the colour bar: 0 (grey) .. max_count
    bar = np.full((ph, 90, 3), 255, np.uint8)
    top, bottom = margin_t, margin_t + H
    for k in range(max_count + 1):
        y0 = bottom - round((k + 1) * (bottom - top) / (max_count + 1))
        y1 = bottom - round(k * (bottom - top) / (max_count + 1))
        col = tuple(int(c) for c in count_colour(np.array([k]), max_count)[0])
        cv2.rectangle(bar, (10, y0), (30, y1), col, -1)
        if k in (0, 1, max_count) or k % 5 == 0:
            cv2.putText(bar, str(k), (36, (y0 + y1) // 2 + 4), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(bar, "projectors", (4, bottom + 18), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(bar, "reaching", (4, bottom + 32), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (0, 0, 0), 1, cv2.LINE_AA)
    if not cv2.imwrite(str(path), np.hstack(out + [bar])):
        raise OSError(f"cannot write {path}")
