"""The kernel, first half: blocks of observations laid out ``(c, ..., g)``, their
linearisation and their share of the normal equations; closed-form 3x3 point blocks.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Optional

import numpy as np

from vectoradjust.adjust.bundle.problem import BundleProblem, _Groups
from vectoradjust.adjust.intersection import (  # noqa: F401 (inv3x3, ray_intersection: API)
    _block_sum,
    approximate_points,
    inv3x3,
    ray_intersection,
)
from vectoradjust.sensor.collinearity import (
    rotation_derivatives,
    rotation_matrix,
)
from vectoradjust.sensor.models import observe_rpc

__all__ = []


#: observations per block: few numpy calls per point, temporaries of a few MB (the calls'
#: overhead costs more than the cache misses: the 10^6 pair took 5.5-5.8 s with 2048,
#: 3.8-4.6 s with 16384)
_CHUNK_OBS = 16384


@dataclass
class _Block:
    """``g`` points seen by the same ``c`` images, observations laid out by image.

    Every array is ``(c, ..., g)``: the camera values of a column are scalars that
    broadcast over the points, sums over a point's images are sums over axis 0, sums
    over an image's points are matrix products.
    """

    images: np.ndarray  # (c,)
    idx6: np.ndarray  # (6c,) rows of these images' EO in the reduced system
    points: np.ndarray  # (g,)
    obs: np.ndarray  # (c, g) observation indices
    xy: np.ndarray  # (c, 2, g) observed photo coordinates
    sw: np.ndarray  # (c, 2, g) square roots of the weights
    repeated: bool  # an image occurs twice in the set (a point measured twice on it)
    pw: np.ndarray  # (3, 3, g) prior weights of the points
    prior: np.ndarray  # (3, g) prior coordinates (0 where there is no prior)
    has: np.ndarray  # (g,) whether the point has a prior
    rpc_cols: Optional[np.ndarray] = None  # positions of the RPC images among ``images``


@dataclass
class _Layout:
    """The observations in blocks, and the points without image observations."""

    blocks: list
    lonely: np.ndarray
    has_prior: np.ndarray


def _layout(prob: BundleProblem, groups: _Groups) -> _Layout:
    """Cut the image-set groups into cache-sized blocks (done once per adjustment)."""
    blocks = []
    six = np.arange(6)
    sw_all = 1.0 / prob.obs_sigma
    has = prob.has_prior
    is_rpc = prob.is_rpc
    for imgs, pts, obs in zip(groups.images, groups.points, groups.obs):
        c = len(imgs)
        step = max(1, _CHUNK_OBS // c)
        idx6 = (6 * np.asarray(imgs, np.int64)[:, None] + six).ravel()
        repeated = len(np.unique(imgs)) < c
        for lo in range(0, len(pts), step):
            o = np.ascontiguousarray(obs[lo:lo + step].T)  # (c, g)
            p = pts[lo:lo + step]
            blocks.append(_Block(
                images=np.asarray(imgs, np.int64), idx6=idx6, points=p, obs=o,
                xy=np.ascontiguousarray(prob.obs_xy[o].transpose(0, 2, 1)),
                sw=np.ascontiguousarray(sw_all[o].transpose(0, 2, 1)), repeated=repeated,
                pw=np.ascontiguousarray(prob.prior_weight[p].transpose(1, 2, 0)),
                prior=np.where(has[p], prob.prior_xyz[p].T, 0.0), has=has[p],
                rpc_cols=np.flatnonzero(is_rpc[imgs]) if is_rpc[imgs].any() else None))
    counts = np.bincount(prob.obs_point, minlength=prob.n_points)
    return _Layout(blocks, np.flatnonzero(counts == 0), has)


def _cameras(eo: np.ndarray):
    """Per image (once, not per observation): projection centre ``(n, 3)`` and
    ``[M; dM/domega; dM/dphi]`` stacked ``(n, 9, 3)``."""
    m = rotation_matrix(eo[:, 3], eo[:, 4], eo[:, 5])
    d = rotation_derivatives(eo[:, 3], eo[:, 4], eo[:, 5])
    return np.ascontiguousarray(eo[:, :3]), np.concatenate([m, d[:, 0], d[:, 1]], axis=1)


def _rays(blk: _Block, cams, xyz: np.ndarray, rows: int = 9) -> np.ndarray:
    """``r, s, q`` (and their omega, phi derivatives with ``rows = 9``), ``(c, rows, g)``,
    and the block's points ``(3, g)``."""
    centre, mats = cams
    xg = xyz[blk.points].T
    d = xg[None, :, :] - centre[blk.images][:, :, None]  # (c, 3, g)
    return mats[blk.images, :rows] @ d, xg


def _linearise(blk: _Block, cams, xyz: np.ndarray, f: float, pp: np.ndarray):
    """Misclosures ``(c, 2, g)`` (observed minus computed), the design rows, the points.

    The rows ``(c, 2, 9, g)`` are the partials of ``x, y`` with respect to
    ``XL, YL, ZL, omega, phi, kappa, XA, YA, ZA`` (docs/method.md section 2; with
    ``a = f/q``: ``dx/dtheta = a (r/q dq/dtheta - dr/dtheta)``, ``dx/dXA = a (r/q m3 - m1)``).
    """
    rr, xg = _rays(blk, cams, xyz)
    r, s, q = rr[:, 0], rr[:, 1], rr[:, 2]
    a = f / q
    xr = r / q
    ys = s / q
    m = cams[1][blk.images]  # (c, 9, 3): rows m1, m2, m3 first
    c, g = r.shape
    b = np.empty((c, 2, 9, g))
    b[:, 0, 6:] = a[:, None] * (xr[:, None] * m[:, 2, :, None] - m[:, 0, :, None])
    b[:, 1, 6:] = a[:, None] * (ys[:, None] * m[:, 2, :, None] - m[:, 1, :, None])
    np.negative(b[:, :, 6:], out=b[:, :, :3])
    b[:, 0, 3] = a * (xr * rr[:, 5] - rr[:, 3])
    b[:, 0, 4] = a * (xr * rr[:, 8] - rr[:, 6])
    b[:, 0, 5] = -a * s
    b[:, 1, 3] = a * (ys * rr[:, 5] - rr[:, 4])
    b[:, 1, 4] = a * (ys * rr[:, 8] - rr[:, 7])
    b[:, 1, 5] = a * r
    ell = np.empty((c, 2, g))
    ell[:, 0] = blk.xy[:, 0] - (pp[0] - f * xr)
    ell[:, 1] = blk.xy[:, 1] - (pp[1] - f * ys)
    return ell, b, xg


def _linearise_block(blk: _Block, cams, xyz: np.ndarray, prob: BundleProblem, eo: np.ndarray):
    """:func:`_linearise` through each image's sensor model: the frame images of the block
    by the collinearity equations, its RPC images (``blk.rpc_cols``) by
    :func:`vectoradjust.sensor.models.observe_rpc` (pixels, bias parameters)."""
    f, pp = float(prob.focal_length), prob.principal_point
    if blk.rpc_cols is None:
        return _linearise(blk, cams, xyz, f, pp)
    c, g = len(blk.images), len(blk.points)
    xg = xyz[blk.points].T
    ell, b = np.empty((c, 2, g)), np.empty((c, 2, 9, g))
    frame_cols = np.setdiff1d(np.arange(c), blk.rpc_cols)
    if frame_cols.size:
        sub = replace(blk, images=blk.images[frame_cols], xy=blk.xy[frame_cols])
        ell[frame_cols], b[frame_cols], _ = _linearise(sub, cams, xyz, f, pp)
    llh, jac = prob.sensors.frame.to_geodetic(xg.T)
    for j in blk.rpc_cols.tolist():
        i = int(blk.images[j])
        colrow, d_par, d_xyz = observe_rpc(prob.sensors.rpc[i], eo[i], llh, jac)
        ell[j] = blk.xy[j] - colrow.T
        b[j, :, :6] = d_par.transpose(1, 2, 0)
        b[j, :, 6:] = d_xyz.transpose(1, 2, 0)
    return ell, b, xg


def _block_normals(blk: _Block, ell: np.ndarray, b: np.ndarray, nep: np.ndarray):
    """Normal-equation pieces of a block from its weighted design rows.

    Returns ``nee (c, 6, 6)``, ``te (c, 6)`` per image, ``npp (3, 3, g)``, ``tp (3, g)``
    per point (image observations only) and the block's ``v'Pv``; fills ``nep
    (c, 6, 3, g)`` per observation.
    """
    b *= blk.sw[:, :, None, :]
    ell *= blk.sw
    c, _, _, g = b.shape
    e = b[:, :, :6].transpose(0, 2, 1, 3).reshape(c, 6, 2 * g)
    lw = ell.reshape(c, 2 * g)
    nee = e @ e.transpose(0, 2, 1)
    te = (e @ lw[:, :, None])[:, :, 0]
    tp = (b[:, :, 6:] * ell[:, :, None, :]).sum(axis=(0, 1))
    np.multiply(b[:, 0, :6, None, :], b[:, 0, None, 6:, :], out=nep)
    nep += b[:, 1, :6, None, :] * b[:, 1, None, 6:, :]
    if blk.rpc_cols is None:
        npp = -nep[:, :3].sum(axis=0)  # the position rows are minus the point rows
    else:  # an RPC image's parameters are no position: the point rows' own products
        npp = np.einsum("caig,cajg->ijg", b[:, :, 6:], b[:, :, 6:])
    return nee, te, npp, tp, float((lw * lw).sum())


def _add_point_priors(blk: _Block, xg: np.ndarray, npp: np.ndarray, tp: np.ndarray) -> None:
    """Add the coordinate priors of the block's points to ``npp (3, 3, g)``, ``tp (3, g)``."""
    npp += blk.pw
    d = np.where(blk.has, blk.prior - xg, 0.0)
    tp += (blk.pw * d[None, :, :]).sum(axis=1)


def _inv_sym3(a: np.ndarray):
    """Inverse and determinant of symmetric 3x3 blocks laid out ``(3, 3, g)``."""
    a00, a01, a02, a11, a12, a22 = a[0, 0], a[0, 1], a[0, 2], a[1, 1], a[1, 2], a[2, 2]
    c00 = a11 * a22 - a12 * a12
    c01 = a02 * a12 - a01 * a22
    c02 = a01 * a12 - a02 * a11
    c11 = a00 * a22 - a02 * a02
    c12 = a02 * a01 - a00 * a12
    c22 = a00 * a11 - a01 * a01
    det = a00 * c00 + a01 * c01 + a02 * c02
    with np.errstate(divide="ignore", invalid="ignore"):
        r = 1.0 / det
    inv = np.empty_like(a)
    inv[0, 0] = c00 * r
    inv[1, 1] = c11 * r
    inv[2, 2] = c22 * r
    inv[0, 1] = inv[1, 0] = c01 * r
    inv[0, 2] = inv[2, 0] = c02 * r
    inv[1, 2] = inv[2, 1] = c12 * r
    return inv, det


def _undetermined(det: np.ndarray, trace: np.ndarray) -> np.ndarray:
    """Positions of numerically singular point blocks (same test as the dense check)."""
    scale = trace**3
    return np.flatnonzero(~(np.abs(det) > 1e-12 * np.maximum(scale, 1e-300)))


def _times_cholesky(nep: np.ndarray, inv: np.ndarray) -> np.ndarray:
    """``U = N_ep L`` per observation with ``N_pp^-1 = L L'`` (closed form), so that
    ``N_ep N_pp^-1 N_pe = U U'`` (one symmetric product per block)."""
    l00 = np.sqrt(inv[0, 0])
    l10 = inv[1, 0] / l00
    l20 = inv[2, 0] / l00
    l11 = np.sqrt(inv[1, 1] - l10 * l10)
    l21 = (inv[2, 1] - l20 * l10) / l11
    l22 = np.sqrt(inv[2, 2] - l20 * l20 - l21 * l21)
    n0, n1, n2 = nep[:, :, 0], nep[:, :, 1], nep[:, :, 2]
    u = np.empty_like(nep)
    u[:, :, 0] = n0 * l00 + n1 * l10 + n2 * l20
    u[:, :, 1] = n1 * l11 + n2 * l21
    u[:, :, 2] = n2 * l22
    return u


def _times_inverse(nep: np.ndarray, inv: np.ndarray) -> np.ndarray:
    """``Y = N_ep N_pp^-1`` per observation, ``(c, 6, 3, g)``, explicit products."""
    y = nep[:, :, 0:1] * inv[0]
    y += nep[:, :, 1:2] * inv[1]
    y += nep[:, :, 2:3] * inv[2]
    return y


def _add_block(s: np.ndarray, rhs: np.ndarray, blk: _Block, loc: np.ndarray,
               r6: np.ndarray) -> None:
    """Scatter a block's ``(6c, 6c)`` reduced-system share and right-hand side."""
    if blk.repeated:
        np.add.at(s, np.ix_(blk.idx6, blk.idx6), loc)
        np.add.at(rhs, blk.idx6, r6)
    else:
        s[np.ix_(blk.idx6, blk.idx6)] += loc
        rhs[blk.idx6] += r6

