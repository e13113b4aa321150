"""The planner's outputs: a layout file the room reads, and a picture of the plan.

The layout is the schema of :func:`sim.scene.load_layout` (projectors at their
native resolution and focal length, aimed at the surface's centre; one
ceiling camera), so ``shadowless room --layout FILE`` runs the planned rig.
The picture (PNG through OpenCV) shows the surface from above with every
candidate (grey; hollow when on a wall), the chosen ones (red,
numbered in the order the planner took them) and the proxy against the
budget.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from planner.candidates import up_for
from planner.surface import Surface
from sim.sop_shadows import Source


def _fmt(v) -> str:
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_fmt(x) for x in np.asarray(v).tolist()) + "]"
    return repr(round(float(v), 4))


def layout_text(sources: Sequence[Source], surface: Surface, *, table_size: tuple[float, float] | None, name: str = "planned") -> str:
    """A layout (TOML) with ``sources`` as its projectors.

    ``table_size`` adds the table (None: no table); a surface built from the
    builtin bust adds ``[mesh] builtin = "bust"``.
    """
    lines = [f"name = {_fmt(name)}", ""]
    if table_size is not None:
        lines += ["[table]", f"size = {_fmt(list(table_size))}", ""]
    if surface.mesh is not None:
        if surface.name != "bust":
            raise ValueError("only the builtin bust can be written into a layout; save other meshes and reference their path")
        lines += ["[mesh]", 'builtin = "bust"', ""]
    for s in sources:
        d = s.device
        target = surface.target
        lines += [
            "[[projector]]",
            f"slot = {_fmt(s.name)}",
            f"position = {_fmt(d.center)}",
            f"target = {_fmt(target)}",
            f"up = {_fmt(up_for(target - d.center))}",
            f"resolution = {_fmt(list(d.size))}",
            f"focal_px = {_fmt(d.K[0, 0])}",
            f"peak = {_fmt(s.peak)}",
            "",
        ]
    top = max(float(s.device.center[2]) for s in sources)
    lines += ["[[camera]]", "name = \"ceiling\"", f"position = {_fmt([0.0, -125.0, max(top, 1400.0)])}", f"target = {_fmt([0.0, 0.0, 0.0])}", ""]
    return "\n".join(lines)


def picture(path: str | Path, surface: Surface, sources: Sequence[Source], chosen: Sequence[int], curve: Sequence[float], *, proxy: str,
            walls: frozenset[int] = frozenset(), marks: dict[int, float] | None = None, scale: float = 0.35) -> None:
    """Write the plan's picture: a top view (left) and the proxy curve (right).

    Parameters
    ----------
    walls : set of int
        Candidates drawn hollow (wall mounts).
    marks : {projector count: proxy}, optional
        Reference values drawn on the curve as squares (e.g. the paper's layouts).
    scale : float
        Pixels per mm of the top view.
    """
    xy = np.array([s.center[:2] for s in sources])
    lo = np.minimum(xy.min(axis=0), surface.points[:, :2].min(axis=0)) - 80
    hi = np.maximum(xy.max(axis=0), surface.points[:, :2].max(axis=0)) + 80
    W, H = math.ceil(float(hi[0] - lo[0]) * scale), math.ceil(float(hi[1] - lo[1]) * scale)
    top = np.full((H, W, 3), 255, np.uint8)

    def px(p) -> tuple[int, int]:
        return round(float(p[0] - lo[0]) * scale), round(float(hi[1] - p[1]) * scale)  # +y up in the picture

    if surface.grid is not None:
        g = surface.grid
        a = px((g.x0 - g.pitch / 2, g.y0 - g.pitch / 2))
        b = px((g.x0 + (g.shape[1] - 0.5) * g.pitch, g.y0 + (g.shape[0] - 0.5) * g.pitch))
        cv2.rectangle(top, a, b, (200, 225, 200), -1)
        cv2.rectangle(top, a, b, (60, 120, 60), 1)
    else:
        hull = cv2.convexHull(np.array([px(p) for p in surface.points], np.int32))
        cv2.fillConvexPoly(top, hull, (200, 225, 200))
        cv2.polylines(top, [hull], True, (60, 120, 60), 1, cv2.LINE_AA)
    for i, s in enumerate(sources):
        cv2.circle(top, px(s.center), 4, (150, 150, 150), 1 if i in walls else -1, cv2.LINE_AA)
    for order, i in enumerate(chosen, 1):
        c = px(sources[i].center)
        cv2.circle(top, c, 7, (40, 40, 220), -1, cv2.LINE_AA)
        cv2.putText(top, str(order), (c[0] + 8, c[1] - 6), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (40, 40, 160), 1, cv2.LINE_AA)
    # The curve.
    cw, ch, m = 420, max(H, 300), 50
    plot = np.full((ch, cw, 3), 255, np.uint8)
    vals = list(curve) + (list(marks.values()) if marks else [])
    vmax = max(max(vals), 1e-9)
    n = len(curve)

    def cp(count: float, v: float) -> tuple[int, int]:
        return int(m + (count - 1) / max(n - 1, 1) * (cw - 2 * m)), int(ch - m - v / vmax * (ch - 2 * m))

    cv2.line(plot, (m, ch - m), (cw - m, ch - m), (0, 0, 0), 1)
    cv2.line(plot, (m, m), (m, ch - m), (0, 0, 0), 1)
    pts = np.array([cp(i + 1, v) for i, v in enumerate(curve)], np.int32)
    cv2.polylines(plot, [pts], False, (40, 40, 220), 2, cv2.LINE_AA)
    for p in pts:
        cv2.circle(plot, tuple(int(v) for v in p), 3, (40, 40, 220), -1, cv2.LINE_AA)
    for count, v in (marks or {}).items():
        if 1 <= count <= n:
            x, y = cp(count, v)
            cv2.rectangle(plot, (x - 4, y - 4), (x + 4, y + 4), (200, 120, 0), 1)
    cv2.putText(plot, f"{proxy} vs projectors", (m, m - 20), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(plot, f"{vmax:.3g}", (4, m + 4), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(plot, "0", (m - 12, ch - m + 4), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(plot, f"1 .. {n}", (cw // 2 - 20, ch - m + 20), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    if top.shape[0] < ch:
        top = np.vstack([top, np.full((ch - top.shape[0], top.shape[1], 3), 255, np.uint8)])
    if not cv2.imwrite(str(path), np.hstack([top, plot])):
        raise OSError(f"cannot write the picture {path}")
