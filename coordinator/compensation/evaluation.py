"""The ``compensate`` job's evaluation: capture the rig without compensation, with the per-projector
baseline and with ours, score each against the target and put them side by side.

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
from imaging.compensation.quality import side_by_side
from protos.store import atomic_write_bytes

if TYPE_CHECKING:
    from coordinator.compensation.options import CompensateOptions
    from coordinator.jobs import JobContext

__all__ = ["Scoring", "evaluate"]


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
        """The picture's tiles: the target, then ``tiles`` in ``order``."""

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
    labels = ["target"] + [f"{k} {scores[k]['psnr']:.2f} dB / {scores[k]['ssim']:.3f}" for k in order]
    pic = side_by_side(scoring.tiles(tiles, order), labels)
    ok, png = cv2.imencode(".png", cv2.cvtColor(pic, cv2.COLOR_RGB2BGR))
    if not ok:
        raise JobError("could not encode the side-by-side picture")
    atomic_write_bytes(compensation_dir(rig) / "quality.png", png.tobytes())
    out = {**scores, "predicted": {"none": await ctx.compute(scoring.predicted, none),
                                   "ours": await ctx.compute(scoring.predicted, ours)},
           **scoring.figures(), "captures_averaged": frames, "picture": f"{SUBDIR}/quality.png", "image": name}
    out["ordering"] = {
        "ours_minus_none_db": round(scores["ours"]["psnr"] - scores["none"]["psnr"], 3),
        **({"ours_minus_baseline_db": round(scores["ours"]["psnr"] - scores["baseline"]["psnr"], 3),
            "baseline_minus_none_db": round(scores["baseline"]["psnr"] - scores["none"]["psnr"], 3)}
           if base_x is not None else {}),
    }
    write_result(rig, "quality.json", out)
    return out
