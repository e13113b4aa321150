"""A mesh rig's light transport measured by several cameras at once, and how the solve combines them.

The paper measured its object with three cameras: one sees only part of a 3D object (from the
ceiling, the bust's crown and shoulders), and texels no camera sees cannot be compensated. Here
the cameras of a :class:`~coordinator.compensation.mesh_rig.MeshCameras` act as one camera whose
image is theirs stacked top to bottom:

* every camera captures every dot pattern (one schedule keeps each dot's window clear in every
  camera that sees it: :func:`~imaging.compensation.mesh_geometry.schedule_dots`), so the
  captures grow with the cameras, never with the projectors;
* a texel's column of ``L`` holds its window in each camera that sees it
  (:func:`stacked_windows`: the windows of :func:`~imaging.compensation.mesh_geometry.texel_windows`
  placed in the stacked image), so the rows of the cameras that do not see it are empty, and its
  column in camera ``k``'s rows is what camera ``k`` alone would measure;
* in the solve every camera pixel's residual weighs ``cos``, how squarely that camera sees the
  surface there (:func:`~imaging.compensation.mesh_geometry.row_weights`, one divisor for all
  cameras), times its texel's **share** of that camera (:func:`camera_shares`).

Why shares and not the best camera alone: every camera's rows are a real measurement of the same
light, and each adds samples (where the cameras agree, the noise of the combined residual falls);
keeping only the best camera per texel would throw measurements away and switch abruptly
between cameras where their quality crosses, a seam the solve would print on the object. The
shares (``q_k / sum_j q_j`` with ``q_k = cos_k`` times camera ``k``'s pixels per texel, both at
the texel) sum to 1 over the cameras that measured the texel, so a texel seen by three cameras
weighs about what it weighs seen by one (its residual is an average over the cameras, led by the
one that sees it squarest and largest, not a sum that would make well-covered texels dominate
the others); they change smoothly across the object, so no seam. With one camera every share is
1 and the weights are that camera's.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import scipy.sparse as sp

from imaging.compensation.errors import CompensationError
from imaging.compensation.mesh_geometry import (
    measured_texels,
    ring_energy,
    row_weights,
    texel_windows,
)
from coordinator.compensation.mesh_rig import MIN_COS, MeshCameras
from imaging.compensation.texture_space import texels_per_pixel

__all__ = ["stacked_windows", "camera_blocks", "camera_shares", "stacked_row_weights", "stacked_ring_energy",
           "camera_summary"]


def stacked_windows(positions: Sequence[np.ndarray], seen: Sequence[np.ndarray], part_shape: Sequence[int],
                    radius: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each texel's windows in the stacked image of ``K`` cameras of ``part_shape`` each.

    Parameters
    ----------
    positions : K arrays (n, 2) float
        Each camera's position of every texel (:class:`~imaging.compensation.texture_space.TexelMap`).
    seen : K arrays (n,) bool
        The texels measured in each camera.
    part_shape : (Hc, Wc)
        One camera's image.
    radius : int

    Returns
    -------
    base : (K, n, 2) int64
        Rounded position of each texel in each camera's own image (0 where it is not measured there).
    rows : (n, K * (2R+1)^2) int32
        Stacked-image pixel of each window entry, camera by camera (camera ``k``'s pixel ``p`` is
        ``k Hc Wc + p``).
    valid : (n, K * (2R+1)^2) bool
    """
    if len(positions) != len(seen) or not positions:
        raise ValueError(f"need one position map per seen mask, got {len(positions)} and {len(seen)}")
    hc, wc = int(part_shape[0]), int(part_shape[1])
    bases, rows, valid = [], [], []
    for k, (pos, ok) in enumerate(zip(positions, seen)):
        b, r, v = texel_windows(pos, ok, (hc, wc), radius)
        bases.append(b)
        rows.append(r + np.int32(k * hc * wc) if k else r)
        valid.append(v)
    if len(rows) == 1:
        return bases[0][None], rows[0], valid[0]
    if len(positions) * hc * wc >= np.iinfo(np.int32).max:
        raise CompensationError("the cameras' images together are too large for one light transport")
    return np.stack(bases), np.concatenate(rows, axis=1), np.concatenate(valid, axis=1)


def camera_blocks(L: sp.spmatrix, cameras: int) -> list[sp.csr_matrix]:
    """``L`` of the stacked image ``(K Hc Wc, n)`` cut into each camera's rows: K ``(Hc Wc, n)`` CSR."""
    csr = sp.csr_matrix(L)
    if csr.shape[0] % cameras:
        raise ValueError(f"L has {csr.shape[0]} rows, not a multiple of {cameras} cameras")
    step = csr.shape[0] // cameras
    return [csr[k * step:(k + 1) * step] for k in range(cameras)]


def _pixels_per_texel(cams: MeshCameras, k: int) -> np.ndarray:
    """Camera ``k``'s pixels per texel at each texel's camera position: ``(n,) float64`` (NaN where unknown)."""
    g = cams.parts[k]
    area = texels_per_pixel(g.view).astype(np.float64)
    ok = g.view.on_mesh & np.isfinite(area) & (area > 0)
    if not ok.any():
        return np.full(len(g.texels.visible), np.nan)
    med = float(np.median(area[ok]))
    area = np.where(ok, np.clip(area, med / 4, 4 * med), med)      # seams and silhouettes jump
    hc, wc = g.camera_shape
    pos = np.rint(np.nan_to_num(g.texels.position, nan=-1.0))
    inside = (pos[:, 0] >= 0) & (pos[:, 0] < wc) & (pos[:, 1] >= 0) & (pos[:, 1] < hc)
    ix = np.where(inside, pos[:, 0], 0).astype(np.int64)
    iy = np.where(inside, pos[:, 1], 0).astype(np.int64)
    return np.where(inside, 1.0 / area[iy, ix], np.nan)


def camera_shares(cams: MeshCameras, measured: Sequence[np.ndarray]) -> np.ndarray:
    """Each camera's share of each texel in the solve: ``(K, n) float32``, summing to 1 over the cameras that
    measured the texel (0 in the others; all 0 where none did). See the module docstring.

    ``measured``: K ``(n,) bool`` texels with a window in each camera's rows of ``L``.
    """
    k = len(cams.parts)
    if len(measured) != k:
        raise ValueError(f"need one measured mask per camera, got {len(measured)} for {k}")
    q = np.zeros((k, len(cams.on_mesh)), np.float64)
    for i, (g, m) in enumerate(zip(cams.parts, measured)):
        px = _pixels_per_texel(cams, i)
        good = np.asarray(m, bool) & np.isfinite(px)
        q[i, good] = g.texels.cos[good] * px[good]
    total = q.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        share = np.where(total > 0, q / total, 0.0)
    return share.astype(np.float32)


def stacked_row_weights(cams: MeshCameras, L: sp.spmatrix, *, radius: int, min_cos: float = MIN_COS) -> np.ndarray:
    """The solve's weight of every pixel of the stacked image: ``(K Hc, Wc) float32``, 0 off the surface it uses.

    Per camera :func:`~imaging.compensation.mesh_geometry.row_weights` with that camera's
    measured texels (its rows of ``L``), times the share of the texel each pixel sees
    (:func:`camera_shares`); one divisor for all: the median of ``cos`` over the pixels used.
    One camera: exactly its :func:`row_weights`.
    """
    blocks = camera_blocks(L, len(cams.parts))
    measured = [measured_texels(b) for b in blocks]
    raws = []
    for g, m in zip(cams.parts, measured):
        missing = g.texels.visible & ~m
        try:
            raws.append(row_weights(g.view, m, g.content_size, radius=radius, min_cos=min_cos,
                                    unmeasured_at=g.texels.position[missing], normalise=False))
        except CompensationError:
            if len(cams.parts) == 1:
                raise
            raws.append(np.zeros(g.camera_shape, np.float32))       # another camera may see the surface well
    used = np.concatenate([r[r > 0] for r in raws])
    if not used.size:
        raise CompensationError("no camera pixel sees the measured surface well: check the cameras' poses and the "
                                "light-transport measurement")
    divisor = np.float32(np.median(used))
    if len(cams.parts) == 1:
        return raws[0] / divisor
    share = camera_shares(cams, measured)
    cw, ch = cams.content_size
    out = []
    for k, (g, r) in enumerate(zip(cams.parts, raws)):
        x = np.clip(np.rint(np.nan_to_num(g.view.x, nan=-1.0)), 0, cw - 1).astype(np.int64)
        y = np.clip(np.rint(np.nan_to_num(g.view.y, nan=-1.0)), 0, ch - 1).astype(np.int64)
        out.append(np.where(r > 0, r * share[k][y * cw + x], 0).astype(np.float32) / divisor)
    return np.vstack(out)


def stacked_ring_energy(L: sp.spmatrix, base: np.ndarray, part_shape: Sequence[int], radius: int) -> float:
    """:func:`~imaging.compensation.mesh_geometry.ring_energy` of a stacked ``L`` (``base`` (K, n, 2), each
    camera's window centres): the share of all squared entries on the outer ring of their windows."""
    blocks = camera_blocks(L, len(base))
    ring = total = 0.0
    for b, block in zip(base, blocks):
        t = float(np.square(block.data, dtype=np.float64).sum())
        ring += ring_energy(block, b, int(part_shape[1]), radius) * t
        total += t
    return ring / total if total > 0 else 0.0


def camera_summary(cams: MeshCameras, L: sp.spmatrix) -> dict:
    """Per camera, the texels it sees and measures; and how many texels are seen by 1, 2, ... cameras."""
    blocks = camera_blocks(L, len(cams.parts))
    seen_by = np.sum([g.texels.visible for g in cams.parts], axis=0)
    on = cams.on_mesh
    return {"cameras": list(cams.cameras),
            "per_camera": [{"camera": c, "seen": int(g.texels.visible.sum()), "measured": int(measured_texels(b).sum())}
                           for c, g, b in zip(cams.cameras, cams.parts, blocks)],
            "seen_by": {str(n): int(np.count_nonzero(on & (seen_by == n))) for n in range(len(cams.parts) + 1)}}
