"""G-band geometry (Shi & Liu 2000) in numpy: the upper envelope of the error ellipses along a
segment, tangent normals, the chains and polygons of a band, one segment at a time in
vectorised form (:func:`_g_band_flat`).

Heart module: numpy and scipy only.
"""

from __future__ import annotations

import numpy as np

__all__ = []


# ------------------------------------------------------------------------------ G-band
def _upper_envelope(cu: np.ndarray, slope: np.ndarray, icpt: np.ndarray):
    """Upper envelope of P concave piecewise-linear chains per row, at every chain vertex.

    Chain ``c`` of a row has the vertices ``cu[c, 0] <= ... <= cu[c, K-1]`` and on piece
    ``j`` (between vertices ``j`` and ``j + 1``) the line ``w = icpt[c, j] + slope[c, j] u``
    (an upper edge of a convex polygon); outside ``[cu[c, 0], cu[c, K-1]]`` it is absent.
    The envelope is evaluated at every vertex of every chain (the stations, sorted): the
    piece of chain ``c`` holding station ``i`` is found by counting chain ``c``'s vertices
    among the sorted stations up to ``i`` (one cumulative sum, no search); at a tie the
    neighbouring piece gives the same value (the chain is continuous).

    ``cu``: (m, P, K); ``slope, icpt``: (m, P, K - 1). Returns ``(u, w)`` of shape
    (m, P K): the stations in ascending order and the envelope there.
    """
    m, p, kk = cu.shape
    flat = cu.reshape(m, p * kk)
    order = np.argsort(flat, axis=1, kind="stable")
    su = np.take_along_axis(flat, order, axis=1)
    owner = order // kk  # chain of each station
    # (m, P, P K): vertices of chain c up to station i, made the flat index of the piece
    count = np.cumsum(owner[:, None, :] == np.arange(p)[None, :, None], axis=2, dtype=np.intp)
    np.subtract(count, 1, out=count)
    np.clip(count, 0, kk - 2, out=count)
    count += (np.arange(m * p) * (kk - 1)).reshape(m, p, 1)
    sb = su[:, None, :]
    val = np.take(slope, count)
    val *= sb
    val += np.take(icpt, count)
    out = (sb < cu[:, :, :1]) | (sb > cu[:, :, -1:])
    np.putmask(val, out, -np.inf)
    return su, val.max(axis=1)


def _neighbours(keep: np.ndarray):
    """Index of the last kept entry at or before, and the first at or after, each entry."""
    m, n = keep.shape
    idx = np.arange(n)
    prev = np.maximum.accumulate(np.where(keep, idx, -1), axis=1)
    nxt = np.minimum.accumulate(np.where(keep, idx, n)[:, ::-1], axis=1)[:, ::-1]
    return prev, nxt


def _chord_gap(u: np.ndarray, w: np.ndarray, prev: np.ndarray, nxt: np.ndarray):
    """``w`` minus the chord through the entries ``prev`` and ``nxt`` (NaN without both)."""
    m, n = u.shape
    inner = (prev >= 0) & (nxt < n)
    base = np.arange(0, m * n, n)[:, None]
    pi = np.clip(prev, 0, n - 1) + base
    ni = np.clip(nxt, 0, n - 1) + base
    uf, wf = u.ravel(), w.ravel()
    u0, u1, w0, w1 = uf.take(pi), uf.take(ni), wf.take(pi), wf.take(ni)
    with np.errstate(invalid="ignore", divide="ignore"):
        gap = w - (w0 + (w1 - w0) * (u - u0) / (u1 - u0))
    return np.where(inner, gap, np.nan)


def _drop_collinear(u: np.ndarray, w: np.ndarray, valid: np.ndarray,
                    tol: np.ndarray) -> np.ndarray:
    """Vertices of the polyline ``(u, w)[valid]`` to keep, straight runs thinned out.

    One vectorised pass drops every vertex within ``tol`` (per row) of the chord through
    its two neighbours; then every dropped vertex is checked against the chord through
    the kept vertices around it, and those farther than ``tol`` are kept after all
    (repeated until none is; usually no repetition). So the thinned polyline is within
    ``tol`` of the full one at every dropped vertex and, both being linear between the
    vertices, everywhere: an outer polyline stays outer to within ``tol``.
    """
    prev, nxt = _neighbours(valid)
    n = u.shape[1]
    prev = np.concatenate([np.full((len(u), 1), -1), prev[:, :-1]], axis=1)
    nxt = np.concatenate([nxt[:, 1:], np.full((len(u), 1), n)], axis=1)
    gap = _chord_gap(u, w, prev, nxt)
    keep = valid & ~(np.abs(gap) <= tol)
    for _ in range(n):
        dropped = valid & ~keep
        if not dropped.any():
            break
        gap = _chord_gap(u, w, *_neighbours(keep))
        bad = dropped & ~(np.abs(gap) <= tol)
        if not bad.any():
            break
        keep |= bad
    return keep


def _tangent_normals(tl: np.ndarray, ql: np.ndarray, k: float, du: float):
    """Normal directions of the common tangents of consecutive ellipses (both sides).

    The support functions ``h_j(d) = tl_j d_u + k sqrt(d' Q_j d)`` of the ellipses ``j``
    and ``j + 1`` are equal at the normal ``d`` of their common tangent. It is searched
    within one uniform direction step ``du`` of the left normal ``(0, 1)`` and of the right
    normal ``(0, -1)``, as ``d = (-s, 1)`` and ``(s, -1)`` with ``|s| <= tan(du)`` (the
    support function is positively homogeneous, so the sign of ``h_j - h_j+1`` does not
    depend on the length of ``d``; no trigonometric function in the loop): 6 bisection
    steps, then 5 steps of regula falsi with the Illinois modification (the function is
    smooth: the supports then agree to ~1e-12 of the band's scale). Where there is no
    sign change (one ellipse reaches farther on the whole interval) or the root is within
    ``1e-6`` rad of a uniform direction, the direction half a step past the normal is taken.
    Any direction keeps the circumscribed polygon valid (an outer bound): the precision
    only makes it follow the band's side.

    ``tl``: (m, P+1) centres; ``ql``: (m, P+1, 2, 2) local covariances.
    Returns ``(cos, sin, phi)`` (m, P, 2) of the left and right tangent normals and their
    angle ``phi`` from ``(0, 1)`` resp. ``(0, -1)``, in ``(-du, du)``.
    """
    q00, q01, q11 = ql[..., 0, 0, None], ql[..., 0, 1, None], ql[..., 1, 1, None]
    dt = (tl[:, :-1] - tl[:, 1:])[..., None] * np.array([-1.0, 1.0])

    def g(s):
        ss, s2 = s * s, 2.0 * s
        v0 = ss * q00[:, :-1] - s2 * q01[:, :-1] + q11[:, :-1]  # d' Q_j d
        v1 = ss * q00[:, 1:] - s2 * q01[:, 1:] + q11[:, 1:]  # d' Q_j+1 d
        return dt * s + k * (np.sqrt(np.clip(v0, 0.0, None)) - np.sqrt(np.clip(v1, 0.0, None)))

    smax = np.tan(du)
    lo, hi = np.full(dt.shape, -smax), np.full(dt.shape, smax)
    glo, ghi = g(lo), g(hi)
    ok = np.sign(glo) * np.sign(ghi) < 0
    for _ in range(6):  # bisection: bracket 2 tan(du) / 64
        mid = 0.5 * (lo + hi)
        gm = g(mid)
        left = np.sign(gm) == np.sign(glo)
        lo, glo = np.where(left, mid, lo), np.where(left, gm, glo)
        hi, ghi = np.where(left, hi, mid), np.where(left, ghi, gm)
    s = 0.5 * (lo + hi)
    last = np.zeros(dt.shape, bool)  # the low end was replaced in the previous step
    for it in range(5):  # regula falsi within the bracket (Illinois: no stuck end)
        with np.errstate(invalid="ignore", divide="ignore"):
            s = lo - glo * (hi - lo) / (ghi - glo)
        # converged, the step may leave the bracket by rounding: stay at its end
        s = np.where(np.isfinite(s), np.clip(s, lo, hi), 0.5 * (lo + hi))
        gs = g(s)
        left = np.sign(gs) == np.sign(glo)
        lo, glo = np.where(left, s, lo), np.where(left, gs, glo)
        hi, ghi = np.where(left, hi, s), np.where(left, ghi, gs)
        if it:  # the same end replaced twice: halve the other end's value
            ghi = np.where(left & last, 0.5 * ghi, ghi)
            glo = np.where(~left & ~last, 0.5 * glo, glo)
        last = left
    phi = np.arctan(s)
    near = (np.abs(phi) < 1e-6) | (np.abs(phi) > du - 1e-6)
    use = ok & ~near
    phi = np.where(use, phi, 0.5 * du)
    s = np.where(use, s, np.tan(0.5 * du))
    r = 1.0 / np.sqrt(1.0 + s * s)
    side = np.array([1.0, -1.0])  # left: (-s, 1), right: (s, -1)
    return -side * s * r, side * r, phi


def _directions(n_directions: int, extra, phi):
    """Arrange the uniform directions and the tangent normals in ascending angle.

    ``extra``: (cos, sin) of the left and right tangent normals, (m, P, 2) each, at
    ``pi/2 + phi`` and ``3 pi/2 + phi``; each goes just before or after the uniform
    direction ``pi/2`` (``3 pi/2``) by the sign of ``phi``. Returns a function that lays
    out any per-direction quantity ``(uniform (..., M), extra (m, P, 2))`` as
    (m, P, M + 2) in that order (no sort, no trigonometric function per segment).
    """
    a, b = n_directions // 4, 3 * n_directions // 4
    before = phi < 0  # (m, P, 2)

    def lay(uni, ext):
        shape = ext.shape[:2] + (n_directions,)
        u = np.broadcast_to(uni, shape)
        cols = []
        for j, c in ((0, a), (1, b)):
            e, bf = ext[..., j:j + 1], before[..., j:j + 1]
            cols.append((np.where(bf, e, u[..., c:c + 1]), np.where(bf, u[..., c:c + 1], e)))
        return np.concatenate([u[..., :a], *cols[0], u[..., a + 1:b], *cols[1], u[..., b + 1:]],
                              axis=2)

    return lay


def _band_constants(n_pairs: int, n_directions: int):
    """What every segment's band shares (the numpy code and the compiled kernel alike):
    the sample parameters ``t`` (P + 1,) and their weights ``(1 - t)^2``, ``2 (1 - t) t``,
    ``t^2``; the direction step ``du`` and the uniform directions' cos, sin (M,), exact
    zeros where they vanish."""
    t = np.linspace(0.0, 1.0, n_pairs + 1)
    du = 2.0 * np.pi / n_directions
    ang = du * np.arange(n_directions)
    uc, us = np.cos(ang), np.sin(ang)
    uc[np.abs(uc) < 1e-15], us[np.abs(us) < 1e-15] = 0.0, 0.0
    return t, (1 - t) ** 2, 2 * (1 - t) * t, t * t, du, uc, us


def _pair_polygons(a, b, c4, k: float, n_pairs: int, n_directions: int):
    """Circumscribed polygons of the pair hulls of many segments, in the segment frame.

    Local frame: ``u`` along the segment from ``a``, ``w`` to its left. Returns
    ``(e_u, cs, sn, hp, vu)``: the unit vector along each segment (m, 2); the polygon's
    edge normals ``(cs, sn)`` in ascending angle from 0 (the uniform directions and the
    two tangent normals), the support ``hp`` of the pair hull at each of them and the
    ``u`` of the vertex between edges ``i`` and ``i + 1`` (all (m, P, M + 2)).
    """
    delta = b - a
    length = np.hypot(delta[:, 0], delta[:, 1])
    with np.errstate(invalid="ignore", divide="ignore"):
        e_u = np.where(length[:, None] > 0, delta / length[:, None], [1.0, 0.0])
    c4 = 0.5 * (c4 + np.swapaxes(c4, 1, 2))
    t, t0, t1, t2, du, uc, us = _band_constants(n_pairs, n_directions)
    t, t0, t1, t2 = t[None, :], t0[None, :], t1[None, :], t2[None, :]

    def q(i, j):  # (m, P+1) element (i, j) of F(t) C F(t)'
        return (t0 * c4[:, i, j, None] + 0.5 * t1 * (c4[:, i, 2 + j, None]
                + c4[:, j, 2 + i, None]) + t2 * c4[:, 2 + i, 2 + j, None])

    qxx, qxy, qyy = q(0, 0), q(0, 1), q(1, 1)
    ex, ey = e_u[:, 0, None], e_u[:, 1, None]  # rotate to (u, w): R = [[ex, ey], [-ey, ex]]
    ql = np.empty(qxx.shape + (2, 2))
    ql[..., 0, 0] = ex * ex * qxx + 2 * ex * ey * qxy + ey * ey * qyy
    ql[..., 1, 1] = ey * ey * qxx - 2 * ex * ey * qxy + ex * ex * qyy
    ql[..., 0, 1] = ql[..., 1, 0] = ex * ey * (qyy - qxx) + (ex * ex - ey * ey) * qxy
    tl = t * length[:, None]  # (m, P+1) centres along the segment
    xc, xs, phi = _tangent_normals(tl, ql, k, du)  # (m, P, 2)

    def support(c, s, tl, ql):  # support of ellipses (m, n) in directions (..., d)
        v = c * c * ql[..., 0, 0, None] + 2.0 * c * s * ql[..., 0, 1, None] \
            + s * s * ql[..., 1, 1, None]
        return tl[..., None] * c + k * np.sqrt(np.clip(v, 0.0, None))

    hu = support(uc, us, tl, ql)  # every sampled ellipse at the uniform directions
    hu = np.maximum(hu[:, :-1], hu[:, 1:])
    hx = np.maximum(support(xc, xs, tl[:, :-1], ql[:, :-1]),
                    support(xc, xs, tl[:, 1:], ql[:, 1:]))
    lay = _directions(n_directions, (xc, xs), phi)
    cs, sn, hp = lay(uc, xc), lay(us, xs), lay(hu, hx)
    c1, s1, hn = (np.roll(x, -1, axis=2) for x in (cs, sn, hp))
    det = cs * s1 - sn * c1  # sin of the angle between consecutive directions
    vu = (hp * s1 - hn * sn) / det  # vertex between directions i and i + 1
    return e_u, cs, sn, hp, vu


def _band_chain(cu, cs, sn, hp, sign: float):
    """Envelope of one side's chains: ``sign`` 1 the left (upper), -1 the right side.

    The edge of normal ``(cs, sn)`` (``sn != 0``) is the line
    ``w = (h - u cs) / sn``; the right side is taken as the upper envelope of ``-w``.
    Returns ``(u, w, valid)`` (m, P K): the envelope's vertices where ``valid``, straight
    runs thinned to within ``1e-9`` of the band's scale.
    """
    slope = -sign * cs / sn
    icpt = sign * hp / sn
    u, w = _upper_envelope(cu, slope, icpt)
    valid = np.isfinite(w)
    valid[:, 1:] &= u[:, 1:] > u[:, :-1]  # repeated abscissae: the envelope is equal there
    w = np.where(valid, w, 0.0)
    scale = np.maximum(np.abs(w).max(axis=1), np.ptp(u, axis=1))
    tol = (1e-9 * np.maximum(scale, 1e-300))[:, None]
    return u, sign * w, _drop_collinear(u, w, valid, tol)


def _g_band_flat(a, b, c4, k: float, n_pairs: int, n_directions: int):
    """The rings of :func:`g_band_batch` as one coordinate array and ring offsets.

    Returns ``(xy, offsets)``: ring ``i`` is ``xy[offsets[i]:offsets[i + 1]]`` (closed).
    """
    m = len(a)
    e_u, cs, sn, hp, vu = _pair_polygons(a, b, c4, k, n_pairs, n_directions)
    half = n_directions // 2 + 1  # directions in [0, pi) incl. the left tangent
    # left chain: vertices 0 .. half - 1 (u descending) on the edges 1 .. half - 1;
    # right chain: vertices half .. M + 1 (u ascending) on the edges half + 1 .. M + 1
    rev = slice(half - 1, 0, -1)
    up_u, up_w, up_v = _band_chain(vu[..., half - 1::-1], cs[..., rev], sn[..., rev],
                                   hp[..., rev], 1.0)
    lo_u, lo_w, lo_v = _band_chain(vu[..., half:], cs[..., half + 1:], sn[..., half + 1:],
                                   hp[..., half + 1:], -1.0)
    # ring: right side from u min to u max, then the left side back
    ru = np.concatenate([lo_u, up_u[:, ::-1]], axis=1)
    rw = np.concatenate([lo_w, up_w[:, ::-1]], axis=1)
    rv = np.concatenate([lo_v, up_v[:, ::-1]], axis=1)
    rows, cols = np.nonzero(rv)
    uu, ww = ru[rows, cols], rw[rows, cols]
    ex, ey = e_u[rows, 0], e_u[rows, 1]
    pts = np.column_stack([a[rows, 0] + uu * ex - ww * ey, a[rows, 1] + uu * ey + ww * ex])
    # drop repeated points, then close every ring with its first point
    keep = np.ones(len(pts), bool)
    keep[1:] = (rows[1:] != rows[:-1]) | np.any(pts[1:] != pts[:-1], axis=1)
    pts, rows = pts[keep], rows[keep]
    counts = np.bincount(rows, minlength=m)
    ends = np.cumsum(counts)
    has = counts > 0  # none where the covariance is not finite: an empty ring
    pts = np.insert(pts, ends[has], pts[(ends - counts)[has]], axis=0)
    offsets = np.concatenate([[0], np.cumsum(counts + has)])
    return pts, offsets
