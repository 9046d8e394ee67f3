"""The G-band of a line segment and polyline (Shi & Liu 2000) and the equal-error grid of a
stereo pair (sigma of a forward-intersected ground point).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull
from scipy.special import gammaincinv  # chi2.ppf(q, k) = 2 gammaincinv(k/2, q)

from vectoradjust.accuracy.propagate.general import _full_cov
from vectoradjust.sensor.collinearity import partials

__all__ = ["confidence_scale", "g_band", "g_band_polyline", "GridSigma", "point_sigma_grid"]


def confidence_scale(confidence: float, dof: int = 2) -> float:
    """``sqrt(chi2_dof(confidence))``: the error-ellipse scale for a confidence level.

    For ``dof = 2``, ``confidence = 0.9``: 2.1460.
    """
    if not 0.0 < confidence < 1.0:
        raise ValueError("confidence must be between 0 and 1")
    return float(np.sqrt(2.0 * gammaincinv(0.5 * dof, confidence)))


def _psd_sqrt(c: np.ndarray) -> np.ndarray:
    """``S`` with ``S S' = C`` for a stack of PSD 2x2 matrices (eigen-decomposition)."""
    w, v = np.linalg.eigh(0.5 * (c + np.swapaxes(c, -1, -2)))
    return v * np.sqrt(np.clip(w, 0.0, None))[..., None, :]


def _circumscribed(s: np.ndarray, n_theta: int) -> np.ndarray:
    """Vertices of polygons circumscribing the ellipses ``{S z : |z| = 1}``.

    The unit circle is touched at ``n_theta`` uniform angles and at the four points
    whose images are the ellipse's extreme points along the local axes (normal and
    parallel to the segment); consecutive tangent lines meet at the vertices. The
    affine image contains the ellipse, and its extent along both axes is exact.
    Returns ``(m, n_theta + 4, 2)`` offsets from the centres.
    """
    m = s.shape[0]
    psi = np.broadcast_to(np.linspace(0.0, 2 * np.pi, n_theta, endpoint=False), (m, n_theta))
    dirs = np.array([[0.0, 1.0], [0.0, -1.0], [1.0, 0.0], [-1.0, 0.0]])
    st_m = np.einsum("tji,dj->tdi", s, dirs)  # S' m: circle point of the support in m
    psi_sup = np.arctan2(st_m[..., 1], st_m[..., 0]) % (2 * np.pi)
    psi = np.sort(np.concatenate([psi, psi_sup], axis=1), axis=1)
    nxt = np.concatenate([psi[:, 1:], psi[:, :1] + 2 * np.pi], axis=1)
    half = 0.5 * (nxt - psi)
    mid = psi + half
    radius = 1.0 / np.cos(half)
    z = np.stack([radius * np.cos(mid), radius * np.sin(mid)], axis=-1)
    return np.einsum("tij,tpj->tpi", s, z)


def _hull_ring(pts: np.ndarray) -> np.ndarray:
    try:
        hull = ConvexHull(pts)
    except Exception:  # degenerate (flat) point set: joggle
        hull = ConvexHull(pts, qhull_options="QJ")
    return pts[hull.vertices]  # counter-clockwise


def _chords(ring: np.ndarray, u: np.ndarray):
    """Lowest and highest ``w`` of a convex polygon on the vertical lines ``u``."""
    p0 = ring
    p1 = np.roll(ring, -1, axis=0)
    u0, u1 = p0[:, 0][:, None], p1[:, 0][:, None]
    w0, w1 = p0[:, 1][:, None], p1[:, 1][:, None]
    du = u1 - u0
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(du != 0, (u[None, :] - u0) / du, np.nan)
    inside = (t >= 0) & (t <= 1)
    w = w0 + t * (w1 - w0)
    # vertical edges and vertices exactly on the line
    on_vert = (du == 0) & (u0 == u[None, :])
    hi = np.max(np.where(inside, w, -np.inf), axis=0)
    lo = np.min(np.where(inside, w, np.inf), axis=0)
    hi = np.maximum(hi, np.max(np.where(on_vert, np.maximum(w0, w1), -np.inf), axis=0))
    lo = np.minimum(lo, np.min(np.where(on_vert, np.minimum(w0, w1), np.inf), axis=0))
    return lo, hi


def g_band(
    p1,
    p2,
    cov_joint,
    confidence: float = 0.9,
    n_samples: int = 33,
    *,
    n_theta: int = 64,
    pieces: bool = False,
):
    """G-band (Shi & Liu 2000): confidence region of a line segment.

    For ``t`` in ``[0, 1]`` the point ``P(t) = (1 - t) P1 + t P2`` has covariance
    ``C(t) = F(t) C_joint F(t)'`` with ``F(t) = [(1 - t) I, t I]``; the band is the
    union (envelope) of the error ellipses of ``P(t)`` scaled by
    ``k = sqrt(chi2_2(confidence))``.

    Construction: ``n_samples`` values of ``t``; each ellipse is replaced by a
    circumscribed polygon (``n_theta + 4`` tangent points, four of them the ellipse's
    extreme points normal and parallel to the segment, so the extents along those
    directions are exact). The convex hull of every consecutive pair of ellipses is formed
    (``scipy.spatial.ConvexHull``). Because the support function of ``C(t)`` is convex
    in ``t``, every ellipse between two samples lies inside the hull of the pair, so the
    union of the hulls contains the whole band and is exact where the envelope is
    straight (it overestimates the band only by ``O(dt^2)`` where it curves). The
    single ring returned is that union, taken as the region between the lowest and
    highest hull boundary on every line normal to the segment (evaluated at all hull
    vertices). This assumes each normal line cuts the band in one interval, true in the
    usual case of ellipses small compared with the segment; for a very short segment
    with large, differently shaped end ellipses the ring may slightly fill concave
    notches (use ``pieces=True`` and a polygon union for the exact union of hulls).
    A zero-length segment is treated as lying along X.

    Parameters
    ----------
    p1, p2 : array_like, shape (d,)
        End points (only X, Y are used).
    cov_joint : array_like, shape (2d, 2d)
        Joint covariance of ``[p1, p2]`` (``p1``'s coordinates first).
    confidence : float
        Probability of the ellipses (2 degrees of freedom).
    n_samples : int
        Number of ``t`` samples (>= 2).
    n_theta : int
        Tangent points per ellipse (besides the four extreme points).
    pieces : bool
        Return the list of per-pair hull rings instead (the caller can union them,
        e.g. with shapely).

    Returns
    -------
    numpy.ndarray, shape (k, 2)
        Closed ring (first point repeated at the end), counter-clockwise, in the
        coordinates of the input. With ``pieces=True``: a list of such rings.
    """
    a = np.asarray(p1, float)
    b = np.asarray(p2, float)
    dd = a.shape[0]
    cj = np.asarray(cov_joint, float)
    if cj.shape != (2 * dd, 2 * dd) or b.shape != (dd,) or dd < 2:
        raise ValueError(f"g_band: points of dimension {dd} need a ({2 * dd}, {2 * dd}) "
                         f"joint covariance; got {cj.shape}")
    if n_samples < 2:
        raise ValueError("g_band needs n_samples >= 2")
    sel = [0, 1, dd, dd + 1]
    delta = b[:2] - a[:2]
    length = float(np.hypot(*delta))
    e_u = delta / length if length > 0 else np.array([1.0, 0.0])
    rot = np.vstack([e_u, np.array([-e_u[1], e_u[0]])])  # world -> local
    hulls = _pair_hulls(cj[np.ix_(sel, sel)], rot, length, confidence_scale(confidence, 2),
                        n_samples, n_theta)

    def to_world(ring_local: np.ndarray) -> np.ndarray:
        w = a[:2] + ring_local @ rot
        return np.vstack([w, w[:1]])

    if pieces:
        return [to_world(h) for h in hulls]
    return to_world(_envelope(hulls))


def _pair_hulls(cxy: np.ndarray, rot: np.ndarray, length: float, k: float, n_samples: int,
                n_theta: int) -> list[np.ndarray]:
    """The convex hulls of consecutive pairs of the ``k``-scaled error ellipses along a
    segment (:func:`g_band`), in the segment's frame (``rot``: world -> local; X along
    the segment from its start, of ``length``); ``cxy`` the joint XY covariance of
    the two ends (4, 4)."""
    t = np.linspace(0.0, 1.0, n_samples)
    fmat = np.zeros((n_samples, 2, 4))
    fmat[:, :, :2] = (1 - t)[:, None, None] * np.eye(2)
    fmat[:, :, 2:] = t[:, None, None] * np.eye(2)
    c_t = np.einsum("ij,tjk,lk->til", rot, np.einsum("tij,jk,tlk->til", fmat, cxy, fmat), rot)
    centres = np.column_stack([t * length, np.zeros(n_samples)])
    s = _psd_sqrt(c_t)
    ell = centres[:, None, :] + k * _circumscribed(s, n_theta)
    return [_hull_ring(np.vstack([ell[j], ell[j + 1]])) for j in range(n_samples - 1)]


def _envelope(hulls: list[np.ndarray]) -> np.ndarray:
    """The ring (local frame, not closed) between the lowest and the highest hull
    boundary on every line normal to the segment, at all hull vertices (:func:`g_band`),
    near-collinear vertices dropped."""
    stations = np.unique(np.concatenate([h[:, 0] for h in hulls]))
    lo = np.full(stations.size, np.inf)
    hi = np.full(stations.size, -np.inf)
    for h in hulls:
        l_h, h_h = _chords(h, stations)
        lo = np.minimum(lo, l_h)
        hi = np.maximum(hi, h_h)
    ok = np.isfinite(lo) & np.isfinite(hi)
    st, lo, hi = stations[ok], lo[ok], hi[ok]
    tol = 1e-7 * max(float(np.max(hi - lo)), 1e-300)
    k_lo = _simplify_chain(st, lo, tol)
    k_hi = _simplify_chain(st, hi, tol)
    ring = np.vstack([np.column_stack([st[k_lo], lo[k_lo]]),
                      np.column_stack([st[k_hi][::-1], hi[k_hi][::-1]])])
    # drop the repeated points at the two ends where lo == hi
    keep = np.ones(len(ring), bool)
    keep[1:] = np.any(np.abs(np.diff(ring, axis=0)) > 0, axis=1)
    return ring[keep]


def _simplify_chain(u: np.ndarray, w: np.ndarray, tol: float) -> np.ndarray:
    """Mask of the vertices of a chain ``w(u)`` to keep: drops near-collinear vertices.

    Vertices whose distance (along ``w``) from the chord of their neighbours is below
    ``tol`` are removed, never two neighbours in one pass; the passes repeat until
    nothing changes. The deviation of every removed vertex from the final chain stays
    within a few ``tol``.
    """
    keep = np.ones(u.size, bool)
    for sweep in range(200):
        idx = np.flatnonzero(keep)
        if idx.size < 3:
            break
        uu, ww = u[idx], w[idx]
        span = uu[2:] - uu[:-2]
        with np.errstate(invalid="ignore", divide="ignore"):
            pred = ww[:-2] + (ww[2:] - ww[:-2]) * (uu[1:-1] - uu[:-2]) / span
        cand = (span > 0) & (np.abs(ww[1:-1] - pred) < tol)
        parity = np.arange(1, idx.size - 1) % 2 == sweep % 2
        rem = cand & parity
        if not rem.any():
            if not (cand & ~parity).any():
                break
            continue
        keep[idx[1:-1][rem]] = False
    return keep


def g_band_polyline(xyz, cov_joint, confidence: float = 0.9, n_samples: int = 33, **kwargs):
    """G-bands of every segment of a polyline.

    Parameters
    ----------
    xyz : array_like, shape (n, d)
        Vertices (X, Y used).
    cov_joint : array_like, shape (n d, n d)
        Full covariance of the vertices (point-major).
    confidence, n_samples, **kwargs
        As :func:`g_band`.

    Returns
    -------
    list of numpy.ndarray
        One ring per segment (``n - 1``); their union is the band of the line.
    """
    p = np.asarray(xyz, float)
    n, d = p.shape
    c = _full_cov(cov_joint, n, d)
    out = []
    for i in range(n - 1):  # one band per segment
        idx = np.arange(i * d, (i + 2) * d)
        out.append(g_band(p[i], p[i + 1], c[np.ix_(idx, idx)], confidence, n_samples,
                          **kwargs))
    return out


# ---------------------------------------------------------------------- equal-error grid
@dataclass
class GridSigma:
    """Standard deviations of forward-intersected ground points (:func:`point_sigma_grid`).

    Attributes
    ----------
    sigma_x, sigma_y, sigma_z : numpy.ndarray
        Shape of the grid.
    cov : numpy.ndarray
        Grid shape + ``(3, 3)``.
    cov_images_only : numpy.ndarray
        The part due to the image coordinates alone (EO taken as error-free).
    """

    sigma_x: np.ndarray
    sigma_y: np.ndarray
    sigma_z: np.ndarray
    cov: np.ndarray
    cov_images_only: np.ndarray


def point_sigma_grid(eo_pair, cov_eo, f: float, sigma_image_mm, X, Y, Z) -> GridSigma:
    """Equal-error grid: sigma X, Y, Z of ground points intersected from a stereo pair.

    For every grid node the ground point is projected into both images and
    intersected back by least squares from its four photo coordinates. With
    ``N_pp = A_p' W A_p`` and ``N_pe = A_p' W A_e`` (``A_p``, ``A_e`` the collinearity
    partials with respect to the point and to the 12 exterior orientation parameters,
    ``W`` the image weights) the covariance of the intersected point is
    ``C = N_pp^-1 + N_pp^-1 N_pe C_ee N_ep N_pp^-1``.

    Parameters
    ----------
    eo_pair : array_like, shape (2, 6)
        ``XL, YL, ZL, omega, phi, kappa`` (m, rad) of the two images.
    cov_eo : array_like, shape (12, 12) or None
        Covariance of the 12 EO parameters (both images, same order; may contain the
        correlation between the images, e.g. from a bundle adjustment).
    f : float
        Focal length (mm).
    sigma_image_mm : float or array_like, shape (4,)
        Photo coordinate sigma(s) (xL, yL, xR, yR).
    X, Y, Z : array_like
        Grid node coordinates, broadcast to a common shape.

    Returns
    -------
    GridSigma
    """
    eo = np.asarray(eo_pair, float).reshape(2, 6)
    cee = np.zeros((12, 12)) if cov_eo is None else np.asarray(cov_eo, float).reshape(12, 12)
    X, Y, Z = np.broadcast_arrays(np.asarray(X, float), np.asarray(Y, float),
                                  np.asarray(Z, float))
    shape = X.shape
    pts = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])
    k = pts.shape[0]
    sig = np.broadcast_to(np.asarray(sigma_image_mm, float), (4,))
    w = 1.0 / sig**2
    ae0, ap0 = partials(np.broadcast_to(eo[0], (k, 6)), pts, f)
    ae1, ap1 = partials(np.broadcast_to(eo[1], (k, 6)), pts, f)
    ap = np.concatenate([ap0, ap1], axis=1)  # (k, 4, 3)
    ae = np.zeros((k, 4, 12))
    ae[:, :2, :6] = ae0
    ae[:, 2:, 6:] = ae1
    wap = w[None, :, None] * ap
    npp_inv = np.linalg.inv(np.einsum("kij,kil->kjl", ap, wap))
    npe = np.einsum("kij,kil->kjl", wap, ae)  # (k, 3, 12)
    g = npp_inv @ npe
    cov = npp_inv + np.einsum("kij,jl,kml->kim", g, cee, g)
    sd = np.sqrt(np.clip(np.diagonal(cov, axis1=-2, axis2=-1), 0, None))
    return GridSigma(
        sigma_x=sd[:, 0].reshape(shape),
        sigma_y=sd[:, 1].reshape(shape),
        sigma_z=sd[:, 2].reshape(shape),
        cov=cov.reshape(shape + (3, 3)),
        cov_images_only=npp_inv.reshape(shape + (3, 3)),
    )

