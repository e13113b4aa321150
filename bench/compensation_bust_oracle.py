"""The bust's oracle: ours and the per-projector baseline solved with measured and with true transports.

``bench compensation_bust`` scores both methods from camera captures, where the measured ``L`` (and
each projector's ``L_i``) and the evaluation's camera noise both count. This module solves the same
weighted problems as the ``compensate`` job (:func:`coordinator.compensation.mesh_compensate.weighted_solve`:
the same rows, weights, texels, target, ridge weight and iteration budget) four times, with the
measured and with the room's true transports (``truth_of``: :func:`bench.compensation_bust.truth_mesh_transport`),
and scores every result through the true transport, without a camera. Ours against the baseline
with the true transports is what each method can reach in this room; with the measured ones, what
the measurement leaves of it. One camera (the ceiling one).
"""
from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import scipy.sparse as sp

from bench.compensation_room import demo_image
from imaging.compensation.geometry import row_white
from coordinator.compensation.image_param import prepare_image
from coordinator.compensation.mesh_cameras import stacked_row_weights
from coordinator.compensation.mesh_compensate import (
    SCORE_PERCENTILE,
    WeightedProblem,
    solve_baseline,
    weighted_solve,
)
from imaging.compensation.mesh_geometry import masked_quality, measured_texels
from coordinator.compensation.mesh_rig import mesh_cameras
from imaging.compensation.texture_space import content_at_view
from imaging.compensation.transport import load_transport
from coordinator.rig import Rig

__all__ = ["bust_oracle"]


def bust_oracle(truth_of: Callable[[list[str]], sp.spmatrix], rig: Rig, slots: list[str], job: dict, *,
                max_iter: int) -> dict:
    """Ours and the baseline solved with the measured and the true transports, scored through the true one.

    ``truth_of(slots)``: the room's true transport of those slots together (texel -> camera px, as ``L`` is
    measured); ``job``: the ``compensate`` job's result on the bench's demo image (its ``target_level``, ridge
    weight and method are reused); the rig holds the measured ``L`` and each slot's ``L_i``
    (``compensation/baseline``). Returns PSNR / SSIM over the
    solve's rows for ``none``, ``ours`` and ``baseline`` under ``true_transport`` and ``measured_transport``,
    and the differences ours - baseline of each.
    """
    comp = Path(rig.path) / "compensation"
    L, meta = load_transport(comp / "transport.npz")
    exposure = np.float32(meta.get("exposure", 1.0))       # L is in the units of the exposure it was measured at
    cw, ch = rig.config.content_width, rig.config.content_height
    cams = mesh_cameras(rig, slots, [int(meta.get("camera", 0))])
    w = stacked_row_weights(cams, L, radius=int(meta.get("core", meta["radius"])))
    region = w > 0
    wp = WeightedProblem(w, measured_texels(L))
    opts = SimpleNamespace(regularization=float(job["solve"]["regularization"]), max_iter=max_iter, tol=1e-5,
                           est_tol=0.0, method=job["solve"]["method"])  # the job's defaults
    content = prepare_image(demo_image((cw, ch)), (cw, ch))
    T = content_at_view(content, cams.view)
    truth = sp.csr_matrix(truth_of(slots) * exposure)
    truths = {s: sp.csr_matrix(truth_of([s]) * exposure) for s in slots}
    white_true = row_white(truth, cams.part_shape)
    goal = np.float32(job["target_level"]) * white_true[:, :, None] * T        # the target with perfect measurement
    ref = float(np.percentile(goal[region], SCORE_PERCENTILE))

    def score(light: np.ndarray) -> dict:
        c = np.asarray(light, np.float32).reshape(*cams.part_shape, -1) / np.float32(ref)
        return masked_quality(goal / np.float32(ref), c, region)

    def through_truth(x: np.ndarray) -> np.ndarray:
        return truth @ x.reshape(-1, x.shape[2])

    out: dict = {}
    for name, big, each in (("true_transport", truth, truths),
                            ("measured_transport", L, {s: load_transport(comp / "baseline" / f"{s}.npz")[0]
                                                       for s in slots})):
        white = row_white(big, cams.part_shape)
        target = np.float32(job["target_level"]) * white[:, :, None] * T
        _, ours, none, _ = weighted_solve(wp, big, target, content, opts)
        base, _ = solve_baseline(each, wp, white, target, content, opts)
        light = sum(truths[k] @ x.reshape(-1, x.shape[2]) for k, x in base.items())
        scores = {"none": score(through_truth(none)), "ours": score(through_truth(ours)), "baseline": score(light)}
        scores["ours_minus_baseline_db"] = round(scores["ours"]["psnr"] - scores["baseline"]["psnr"], 3)
        out[name] = scores
    out["note"] = ("both methods solved as the job does (rows, weights, target, ridge, iterations) with the room's true "
                   "and with the measured transports, every result scored through the true transport (no camera)")
    return out
