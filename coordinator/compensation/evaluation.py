"""The ``compensate`` job's evaluation: capture the rig without compensation, with the per-projector
baseline and with ours, score each against the target and draw them
(:func:`imaging.compensation.quality_figure.compensation_figure`: full size, the detail where the
blur costs most enlarged, and each one's difference to the target on one colour scale, from the
float images the scores are computed from).

The order of the captures, the picture (``compensation/quality.png``) and the figures
(``compensation/quality.json``) are the same on every surface; how a capture is taken (one camera,
or several stacked, at what exposure), scored (PSNR/SSIM over a table's inscribed rectangle, or over
an object's visible surface) and predicted through the measured ``L`` is the surface's
:class:`Scoring`.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

import cv2
import numpy as np

from coordinator.compensation.store import SUBDIR, compensation_dir, write_result
from coordinator.jobs import JobError
from coordinator.jobs.results import Figures
from imaging.compensation.quality_figure import compensation_figure
from protos.store import atomic_write_bytes

if TYPE_CHECKING:
    from coordinator.compensation.options import CompensateOptions
    from coordinator.jobs import JobContext

__all__ = ["Scoring", "evaluate", "quality_picture"]


class Scoring(Protocol):
    """A surface's way of capturing and scoring one evaluation."""

    async def capture(self) -> np.ndarray:
        """One capture of what the rig shows: (Hc, Wc, 3) float32 (several cameras: stacked rows)."""

    def score(self, capture: np.ndarray, black: np.ndarray) -> tuple[Figures, np.ndarray]:
        """A capture's PSNR/SSIM figures against the target (black removed), and its tile for the picture."""

    async def baseline_frames(self, base_x: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Each baseline projector's own frame (its pixels) for its image ((H, W, C) float32, by slot)."""

    def predicted(self, x: np.ndarray) -> Figures:
        """The scores ``x`` would get through the measured ``L`` (what the solver believed)."""

    def tiles(self, tiles: dict[str, np.ndarray], order: list[str]) -> list[np.ndarray]:
        """The picture's tiles: the target, then ``tiles`` in ``order`` (each (h, w, C) float32, linear,
        1 = the target level; pixels outside the scored region 0 in every tile; a mesh's several cameras:
        each one's view cut to its scored pixels, packed by imaging.compensation.quality_figure.packed_views)."""

    def figures(self) -> Figures:
        """The scored region's (and the exposure's) figures for ``quality.json``."""


async def evaluate(ctx: JobContext, scoring: Scoring, none: np.ndarray, ours: np.ndarray,
                   base_x: dict[str, np.ndarray] | None, opts: CompensateOptions, name: str) -> Figures:
    """Capture none / baseline / ours; PSNR, SSIM and the side-by-side picture, stored as ``quality.json``.

    ``none``, ``ours``: (H, W, C) float32 content images; ``base_x``: the baseline's image per slot, or None.
    """
    rig = ctx.rig
    frames = opts.eval_frames
    steps = 3 if base_x else 2

    async def seen(image: np.ndarray) -> np.ndarray:
        await ctx.show_content(image, settle_s=opts.settle_s)
        return await scoring.capture()

    ctx.progress("evaluate", "", 0, steps, "without compensation")
    black = await seen(np.zeros(none.shape[:2], np.float32))
    scores: dict[str, dict] = {}
    tiles: dict[str, np.ndarray] = {}
    scores["none"], tiles["none"] = scoring.score(await seen(none), black)
    if base_x is not None:
        ctx.progress("evaluate", "", 1, steps, "baseline")
        frames_by_slot = await scoring.baseline_frames(base_x)
        await ctx.show(frames_by_slot, settle_s=opts.settle_s, require=list(frames_by_slot))
        scores["baseline"], tiles["baseline"] = scoring.score(await scoring.capture(), black)
    ctx.progress("evaluate", "", steps - 1, steps, "ours")
    scores["ours"], tiles["ours"] = scoring.score(await seen(ours), black)
    ctx.progress("evaluate", "", steps, steps, "scored")

    order = ["none"] + (["baseline"] if base_x is not None else []) + ["ours"]
    png, shown = await ctx.compute(quality_picture, scoring.tiles(tiles, order), order, scores, scoring.figures(), name)
    atomic_write_bytes(compensation_dir(rig) / "quality.png", png)
    out = {**scores, "predicted": {"none": await ctx.compute(scoring.predicted, none),
                                   "ours": await ctx.compute(scoring.predicted, ours)},
           **scoring.figures(), "captures_averaged": frames, "picture": f"{SUBDIR}/quality.png",
           "picture_shows": shown, "image": name}
    out["ordering"] = {
        "ours_minus_none_db": round(scores["ours"]["psnr"] - scores["none"]["psnr"], 3),
        **({"ours_minus_baseline_db": round(scores["ours"]["psnr"] - scores["baseline"]["psnr"], 3),
            "baseline_minus_none_db": round(scores["baseline"]["psnr"] - scores["none"]["psnr"], 3)}
           if base_x is not None else {}),
    }
    write_result(rig, "quality.json", out)
    return out


def quality_picture(tiles: list[np.ndarray], order: list[str], scores: dict[str, dict], region: Figures,
                    name: str) -> tuple[bytes, dict]:
    """``quality.png`` (PNG bytes) and what it shows (:func:`compensation_figure`'s second value).

    ``tiles``: :meth:`Scoring.tiles` (the target, then the captures in ``order``); ``region``:
    :meth:`Scoring.figures` (a table's scored rectangle in camera px, ``region.x`` / ``region.y``, or a
    mesh's visible surface: the cameras' views, each cut to the object, packed; unscored pixels 0 in every tile)."""
    target, captures = tiles[0], dict(zip(order, tiles[1:]))
    box = region.get("region") or {}
    if "x" in box and "y" in box:
        origin = (int(box["x"][0]), int(box["y"][0]))
        where = (f"seen by the camera over the scored region of the table (camera px x {box['x'][0]}..{box['x'][1]}, "
                 f"y {box['y'][0]}..{box['y'][1]})")
        mask = None
    else:
        # the mesh's tiles are 0 outside the visible surface in every tile; a scored pixel that is exactly 0
        # in all of them has no error either, so leaving it out moves no figure but the mean's count
        origin = None
        where = ("seen by the camera over the object's visible surface (several cameras: each one's view cut to "
                 "the object, next to the others)")
        mask = np.any([np.any(np.asarray(t) != 0, axis=2) for t in tiles], axis=0)
    title = [f"Blur compensation of {name!r}, {where}.",
             "PSNR and SSIM: against the target over the scored pixels (the figures of quality.json)."]
    picture, shown = compensation_figure(target, captures, scores, title=title, mask=mask, origin=origin)
    ok, png = cv2.imencode(".png", picture)
    if not ok:
        raise JobError("could not encode the compensation picture")
    return png.tobytes(), shown
