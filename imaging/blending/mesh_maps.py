"""A mesh rig's alpha maps, fitted jointly so that the light they give matches the target where the camera
sees the surface.

On a planar rig a map texel covers a small patch of one surface, so sampling the wanted gain ``r_i Q``
(:mod:`imaging.blending.solve`) at each texel's point is enough. On a mesh a texel of a projector's map
(``map_scale`` pixels a side) may light two surfaces far apart (a chin and the neck behind it), or a patch
over which the shading changes much faster than the map can: sampled, the maps miss the target there by
tens of percent. So the maps are fitted instead, per colour channel, by sparse least squares over every
camera grid point ``x`` the blend covers:

* **the light** (weight 1): ``sum_i T_i(x) alpha_i(u_i(x)) = target(x)``, relative to the target, where
  ``alpha_i(u)`` is the node's own bilinear sampling of the map (:func:`bilinear_matrix`, the convention of
  :func:`imaging.blending.predict.sample_map`); a point one projector's texel misses is made up by the
  others' where they reach it;
* **the share** (weight ``share``): each projector's part stays near its weighted share ``r_i Q`` (what the
  planar solve asks), so that the partition of the light between projectors, and the fades at their
  footprints' edges, are kept where the light alone does not decide;
* **smoothness** (weight ``smooth``): neighbouring texels stay close, which also carries values into
  texels that light nothing the camera sees.

The unknown is the change from the sampled maps (``initial``): the least-norm change leaves a texel no
equation reaches as it was. Alphas are clipped to 0..1 afterwards, as the node does.
"""
from __future__ import annotations

from typing import Mapping

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import lsqr, spsolve

__all__ = ["bilinear_matrix", "map_scale_for", "footprint_points", "snap_pixels", "footprint_matrix", "fit_alpha_maps", "SHARE", "SMOOTH", "FOOTPRINT_SAMPLES"]

#: weight of each projector's share against the light's equations (on the room's bust, with maps fine enough to
#: follow the grazed crown, 0.2 held the maps off the light by 0.4 % of p99 non-uniformity more than 0.02)
SHARE = 0.02
#: weight of the texel-to-texel smoothness (0.1: at 0.3 and at 0.05 the bust's p99 was 0.2 % higher)
SMOOTH = 0.1
#: the normal equations' ridge (keeps an unknown the equations do not pin where it was)
RIDGE = 1e-6
#: sub-samples per axis of a grid cell's footprint in the projector (:func:`footprint_matrix`; 0: a point)
FOOTPRINT_SAMPLES = 4
#: a neighbour further than this many projector pixels lies across a depth edge: not the same surface
FOOTPRINT_JUMP = 12.0
#: more unknowns than this (texels some grid point samples, all projectors) are solved iteratively
DIRECT_MAX = 150_000


def bilinear_matrix(u: np.ndarray, projector_size: tuple[int, int], map_size: tuple[int, int]) -> sp.csr_matrix:
    """``(n, mh * mw)`` CSR float64: row ``k`` holds the bilinear weights with which a node samples a map of
    ``map_size`` = (mw, mh) over a projector of ``projector_size`` = (W, H) at projector pixel ``u[k]``
    (``u``: (n, 2) finite): texel centres at ``(t + 0.5) W / mw - 0.5``, clamped at the edges."""
    W, H = projector_size
    mw, mh = map_size
    u = np.asarray(u, np.float64).reshape(-1, 2)
    tx = np.clip((u[:, 0] + 0.5) * (mw / W) - 0.5, 0.0, mw - 1.0)
    ty = np.clip((u[:, 1] + 0.5) * (mh / H) - 0.5, 0.0, mh - 1.0)
    x0 = np.floor(tx).astype(np.int64)
    y0 = np.floor(ty).astype(np.int64)
    fx, fy = tx - x0, ty - y0
    x1, y1 = np.minimum(x0 + 1, mw - 1), np.minimum(y0 + 1, mh - 1)
    n = len(u)
    rows = np.repeat(np.arange(n), 4)
    cols = np.stack([y0 * mw + x0, y0 * mw + x1, y1 * mw + x0, y1 * mw + x1], axis=1).reshape(-1)
    vals = np.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy], axis=1).reshape(-1)
    return sp.csr_matrix((vals, (rows, cols)), shape=(n, mw * mh))


def _derivative(U: np.ndarray, axis: int) -> np.ndarray:
    """``(h, w, 2)``: the change of ``U`` ((h, w, 2), NaN where undefined) per grid step along ``axis`` (0: rows,
    1: columns): the central difference where both neighbours lie on the same surface (finite and within
    :data:`FOOTPRINT_JUMP` pixels), else the one-sided one, else 0."""
    pad = [(0, 0)] * 3
    pad[axis] = (1, 1)
    P = np.pad(U, pad, constant_values=np.nan)
    sl = [slice(None)] * 3
    sl[axis] = slice(2, None)
    nxt = P[tuple(sl)]
    sl[axis] = slice(None, -2)
    prv = P[tuple(sl)]
    fwd, bwd = nxt - U, U - prv
    with np.errstate(invalid="ignore"):
        vf = np.isfinite(fwd).all(-1) & (np.linalg.norm(np.nan_to_num(fwd, nan=np.inf), axis=-1) <= FOOTPRINT_JUMP)
        vb = np.isfinite(bwd).all(-1) & (np.linalg.norm(np.nan_to_num(bwd, nan=np.inf), axis=-1) <= FOOTPRINT_JUMP)
    out = np.where((vf & vb)[..., None], 0.5 * (np.nan_to_num(fwd) + np.nan_to_num(bwd)),
                   np.where(vf[..., None], np.nan_to_num(fwd), np.where(vb[..., None], np.nan_to_num(bwd), 0.0)))
    return out


def footprint_points(coords: np.ndarray, rows: np.ndarray, *, samples: int = FOOTPRINT_SAMPLES) -> np.ndarray:
    """``(n, samples**2, 2) float64``: the projector pixels of ``samples`` x ``samples`` points spread evenly over
    the camera-grid cell of each grid point ``rows`` ((n,) flat indices into ``coords`` (h, w, 2), finite there),
    through the local Jacobian of the coordinates (:func:`_derivative`: from the neighbouring grid points on the
    same surface; a point with none keeps its centre)."""
    U = np.asarray(coords, np.float64)
    if U.ndim != 3 or U.shape[2] != 2:
        raise ValueError(f"coords must be (h, w, 2), got {U.shape}")
    rows = np.asarray(rows, np.int64)
    u = U.reshape(-1, 2)[rows]
    if not np.isfinite(u).all():
        raise ValueError("every row's projector coordinates must be finite")
    if samples < 1:
        raise ValueError(f"samples must be at least 1, got {samples}")
    dx = _derivative(U, 1).reshape(-1, 2)[rows]
    dy = _derivative(U, 0).reshape(-1, 2)[rows]
    o = (np.arange(samples) + 0.5) / samples - 0.5
    ox, oy = (a.ravel() for a in np.meshgrid(o, o))
    return u[:, None, :] + ox[None, :, None] * dx[:, None, :] + oy[None, :, None] * dy[:, None, :]


def map_scale_for(coords: Mapping[str, np.ndarray], *, coarsest: int = 4) -> int:
    """The blend maps' downscale for a mesh rig: as fine as the camera grid resolves the projectors' pixels on the
    surface. Each grid cell spans ``sqrt|det J|`` projector pixels (``J`` the Jacobian of its projector
    coordinates, :func:`_derivative`); the median over every slot's reached cells, rounded, clamped to
    ``1..coarsest``. A coarser map cannot follow the shading of a surface the projectors graze (on the room's
    bust a cell spans half a projector pixel and the maps are fitted pixel by pixel); a finer one than the grid
    sees is not measured.

    ``coords``: slot -> (h, w, 2) float, each grid point's projector pixel (NaN where not reached)."""
    spans = []
    for U in coords.values():
        U = np.asarray(U, np.float64)
        dx, dy = _derivative(U, 1), _derivative(U, 0)
        det = np.abs(dx[..., 0] * dy[..., 1] - dx[..., 1] * dy[..., 0])
        ok = np.isfinite(U).all(axis=-1) & (det > 0)
        spans.append(np.sqrt(det[ok]))
    every = np.concatenate(spans) if spans else np.zeros(0)
    if not len(every):
        return int(coarsest)
    return int(np.clip(round(float(np.median(every))), 1, coarsest))


def snap_pixels(points: np.ndarray, projector_size: tuple[int, int]) -> np.ndarray:
    """``points`` (..., 2) float: the centre of the projector pixel each falls in (pixel ``k`` spans
    ``[k - 0.5, k + 0.5)``), clamped to the frame; float64."""
    W, H = projector_size
    pix = np.floor(np.asarray(points, np.float64) + 0.5)
    pix[..., 0] = np.clip(pix[..., 0], 0, W - 1)
    pix[..., 1] = np.clip(pix[..., 1], 0, H - 1)
    return pix


def footprint_matrix(coords: np.ndarray, rows: np.ndarray, projector_size: tuple[int, int], map_size: tuple[int, int],
                     *, samples: int = FOOTPRINT_SAMPLES) -> sp.csr_matrix:
    """``(len(rows), mh * mw)`` CSR float64: how much of each map texel the light of grid points ``rows`` carries.

    A grid point stands for a cell of the camera grid, and the camera sees the mean light over it. On a surface
    the projector grazes, that cell's footprint in the projector is stretched along the surface over several
    projector pixels, and a node shows each pixel as a square of one value (its map sampled bilinearly at the
    pixel's centre, :func:`imaging.blending.predict.sample_map`'s convention). So the cell is sampled at
    ``samples`` x ``samples`` points spread over it (:func:`footprint_points`); each is snapped to the centre of
    the projector pixel it falls in (:func:`snap_pixels`) and weighs the texels around that centre bilinearly;
    a row is the mean over its samples. ``samples`` 0 gives the point model (:func:`bilinear_matrix` at the
    cell's centre).

    Parameters
    ----------
    coords : (h, w, 2) float, every grid point's projector pixel (NaN where the projector does not reach it)
    rows : (n,) int, flat grid indices whose coordinates are finite
    projector_size : (W, H); map_size : (mw, mh)
    """
    if samples <= 0:
        u = np.asarray(coords, np.float64).reshape(-1, 2)[np.asarray(rows, np.int64)]
        return bilinear_matrix(u, projector_size, map_size)
    pts = footprint_points(coords, rows, samples=samples)
    n, k = pts.shape[:2]
    M = bilinear_matrix(snap_pixels(pts, projector_size).reshape(-1, 2), projector_size, map_size)
    mean = sp.csr_matrix((np.full(n * k, 1.0 / k), (np.repeat(np.arange(n), k), np.arange(n * k))), shape=(n, n * k))
    return (mean @ M).tocsr()


def _differences(mw: int, mh: int) -> sp.csr_matrix:
    """``(edges, mh * mw)``: the difference across every horizontal and vertical pair of neighbouring texels."""
    idx = np.arange(mw * mh).reshape(mh, mw)
    a = np.concatenate([idx[:, :-1].ravel(), idx[:-1, :].ravel()])
    b = np.concatenate([idx[:, 1:].ravel(), idx[1:, :].ravel()])
    m = len(a)
    rows = np.concatenate([np.arange(m), np.arange(m)])
    return sp.csr_matrix((np.concatenate([np.ones(m), -np.ones(m)]), (rows, np.concatenate([a, b]))),
                         shape=(m, mw * mh))


def fit_alpha_maps(white: dict, coords: dict, projector_size: dict, initial: dict, share: dict, target: np.ndarray,
                   covered: np.ndarray, *, share_weight: float = SHARE, smooth: float = SMOOTH,
                   footprint: int = FOOTPRINT_SAMPLES) -> dict:
    """The alpha maps, fitted (see the module docstring).

    Parameters
    ----------
    white : slot -> (h, w, 3) float32, each projector's light above black at full white on the grid
    coords : slot -> (h, w, 2) float64, its projector pixel of every grid point (NaN where it does not reach)
    projector_size : slot -> (W, H)
    initial : slot -> (mh, mw, 3) float32, the sampled alpha maps (their size is the maps')
    share : slot -> (h, w, 3) float32, the gain ``r_i Q`` each projector is asked for on the grid
    target : (h, w, 3) the light wanted above black; covered : (h, w) bool, where it is asked for
    footprint : sub-samples per axis of each grid cell's footprint (:func:`footprint_matrix`; 0: a point)

    Returns
    -------
    slot -> (mh, mw, 3) float32 alpha maps in 0..1
    """
    slots = list(initial)
    cov = np.asarray(covered, bool) & np.all(np.asarray(target) > 0, axis=-1)
    idx = np.flatnonzero(cov)
    n = len(idx)
    if n == 0 or not slots:
        return {s: np.asarray(initial[s], np.float32) for s in slots}
    tgt = np.asarray(target, np.float64).reshape(-1, 3)[idx]
    sizes, offsets, B, reach = {}, {}, {}, {}
    total = 0
    for s in slots:
        mh, mw = initial[s].shape[:2]
        sizes[s] = (mw, mh)
        offsets[s] = total
        total += mw * mh
        u = np.asarray(coords[s], np.float64).reshape(-1, 2)[idx]
        ok = np.isfinite(u).all(axis=1) & np.any(np.asarray(white[s]).reshape(-1, 3)[idx] > 0, axis=1)
        reach[s] = np.flatnonzero(ok)
        B[s] = footprint_matrix(coords[s], idx[reach[s]], projector_size[s], (mw, mh), samples=footprint)
    D = {s: _differences(*sizes[s]) for s in slots}
    # only texels some grid point samples are unknowns; the others keep their sampled values (the smoothness
    # still ties the unknowns to them)
    touched = np.flatnonzero(np.concatenate([np.asarray(abs(B[s]).sum(axis=0)).ravel() > 0 for s in slots]))
    out = {s: np.empty((sizes[s][1], sizes[s][0], 3), np.float32) for s in slots}
    for ch in range(3):
        t = tgt[:, ch]
        light_blocks, share_blocks, share_rhs, smooth_blocks = [], [], [], []
        for s in slots:
            k = reach[s]
            T = np.asarray(white[s], np.float64).reshape(-1, 3)[idx][k, ch] / t[k]   # relative light per unit alpha
            rows = (sp.diags(T) @ B[s]).tocsr()
            light_blocks.append(rows)
            share_blocks.append(share_weight * rows)
            share_rhs.append(share_weight * T * np.asarray(share[s], np.float64).reshape(-1, 3)[idx][k, ch])
            smooth_blocks.append(smooth * D[s])
        # the light: rows are grid points; each slot's block lands on its reached points' rows
        light = sp.hstack([_scatter(light_blocks[j], reach[s], n) for j, s in enumerate(slots)])
        A = sp.vstack([light, sp.block_diag(share_blocks), sp.block_diag(smooth_blocks)]).tocsr()
        b = np.concatenate([np.ones(n), *share_rhs, np.zeros(sum(d.shape[0] for d in D.values()))])
        x0 = np.concatenate([np.asarray(initial[s], np.float64)[..., ch].ravel() for s in slots])
        At = A[:, touched].tocsc()
        rhs = b - A @ x0
        x = x0.copy()
        if len(touched) <= DIRECT_MAX:
            # the normal equations, with a faint pull of every unknown toward its sampled value, solved directly
            N = (At.T @ At).tocsc() + sp.identity(len(touched), format="csc") * RIDGE
            x[touched] += spsolve(N, At.T @ rhs)
        else:       # too many for a direct solve: iterate from the sampled maps
            x[touched] += lsqr(At, rhs, atol=1e-5, btol=1e-5, iter_lim=300)[0]
        x = np.clip(x, 0.0, 1.0)
        for s in slots:
            mw, mh = sizes[s]
            out[s][..., ch] = x[offsets[s]:offsets[s] + mw * mh].reshape(mh, mw)
    return out


def _scatter(block: sp.csr_matrix, rows: np.ndarray, n: int) -> sp.csr_matrix:
    """``block``'s rows placed at ``rows`` of an ``n``-row matrix (the others empty)."""
    coo = block.tocoo()
    return sp.csr_matrix((coo.data, (rows[coo.row], coo.col)), shape=(n, block.shape[1]))
