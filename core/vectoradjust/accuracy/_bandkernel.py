"""Compiled G-band rings: :func:`vectoradjust.accuracy.derived.g_band_rings` one segment
at a time, with numba (issue 13).

The same construction as the vectorised numpy code in :mod:`.derived` (circumscribed
polygons of the pair hulls, the common tangents by bisection and regula falsi, the
upper envelope of each side's chains at every chain vertex, straight runs thinned to
``1e-9`` of the band's scale, the ring), written as loops over one segment so that no
``(chunk, P, P K)`` temporaries are made. Every floating-point expression is that of the
numpy code, in the same order and without ``fastmath``. Only the library functions
``hypot`` (the segment's length) and ``arctan`` (which decides nothing but the sign and
the 1e-6 rad guard of a tangent's angle) may come from another maths library than
numpy's and differ by an ulp. ``tests/test_gband_kernel.py`` checks that the rings are
the numpy code's, point for point.

This module imports numba at the top and is itself imported lazily, only by
:func:`vectoradjust.accuracy.derived._ring_kernel`, which falls back to the numpy code
when numba is missing (e.g. in QGIS's Python).
"""

from __future__ import annotations

import math

import numba
import numpy as np

_jit = numba.njit(cache=True, nogil=True, error_model="numpy")


@_jit
def _sign(x):
    if x > 0.0:
        return 1.0
    if x < 0.0:
        return -1.0
    if x == 0.0:
        return 0.0
    return x  # NaN, as numpy.sign


@_jit
def _clip0(v):
    return v if not v < 0.0 else 0.0  # numpy.clip(v, 0, None), NaN kept


@_jit
def _g(s, dts, k, ql, j):
    """Difference of the support functions of ellipses ``j`` and ``j + 1`` at (-s, 1)."""
    ss, s2 = s * s, 2.0 * s
    v0 = ss * ql[j, 0] - s2 * ql[j, 1] + ql[j, 2]
    v1 = ss * ql[j + 1, 0] - s2 * ql[j + 1, 1] + ql[j + 1, 2]
    return dts * s + k * (math.sqrt(_clip0(v0)) - math.sqrt(_clip0(v1)))


@_jit
def _tangents(tl, ql, k, smax, shalf, du, tw):
    """``(s, phi)`` of the common tangent normals of all pairs, both sides
    (derived._tangent_normals): lane ``2 j`` the left, ``2 j + 1`` the right side of pair
    ``j``. The lanes are iterated together (independent: their latencies overlap)."""
    lo, hi, glo, ghi, dts, s, last, ok = tw[0], tw[1], tw[2], tw[3], tw[4], tw[5], tw[6], tw[7]
    nl = tw.shape[1]
    for lane in range(nl):
        j = lane // 2
        dts[lane] = (tl[j] - tl[j + 1]) * (-1.0 if lane % 2 == 0 else 1.0)
        lo[lane], hi[lane] = -smax, smax
        glo[lane] = _g(lo[lane], dts[lane], k, ql, j)
        ghi[lane] = _g(hi[lane], dts[lane], k, ql, j)
        ok[lane] = 1.0 if _sign(glo[lane]) * _sign(ghi[lane]) < 0.0 else 0.0
    for _ in range(6):
        for lane in range(nl):
            mid = 0.5 * (lo[lane] + hi[lane])
            gm = _g(mid, dts[lane], k, ql, lane // 2)
            if _sign(gm) == _sign(glo[lane]):
                lo[lane], glo[lane] = mid, gm
            else:
                hi[lane], ghi[lane] = mid, gm
    for it in range(5):
        for lane in range(nl):
            x = lo[lane] - glo[lane] * (hi[lane] - lo[lane]) / (ghi[lane] - glo[lane])
            if math.isfinite(x):
                x = min(max(x, lo[lane]), hi[lane])
            else:
                x = 0.5 * (lo[lane] + hi[lane])
            s[lane] = x
            gs = _g(x, dts[lane], k, ql, lane // 2)
            left = _sign(gs) == _sign(glo[lane])
            if left:
                lo[lane], glo[lane] = x, gs
            else:
                hi[lane], ghi[lane] = x, gs
            if it:
                if left and last[lane] > 0.0:
                    ghi[lane] = 0.5 * ghi[lane]
                if not left and not last[lane] > 0.0:
                    glo[lane] = 0.5 * glo[lane]
            last[lane] = 1.0 if left else 0.0
    for lane in range(nl):  # phi (in lo), s
        phi = math.atan(s[lane])
        near = (abs(phi) < 1e-6) or (abs(phi) > du - 1e-6)
        if ok[lane] > 0.0 and not near:
            lo[lane] = phi
        else:
            lo[lane], s[lane] = 0.5 * du, shalf


@_jit
def _support(c, s, tl, ql, j, k):
    v = c * c * ql[j, 0] + 2.0 * c * s * ql[j, 1] + s * s * ql[j, 2]
    return tl[j] * c + k * math.sqrt(_clip0(v))


@_jit
def _frame(a, b, c4, t, t0, t1, t2, ql, tl):
    """Unit vector along the segment; local covariances ``ql`` (P+1, 3) and centres."""
    dx, dy = b[0] - a[0], b[1] - a[1]
    length = math.hypot(dx, dy)
    if length > 0.0:
        ex, ey = dx / length, dy / length
    else:
        ex, ey = 1.0, 0.0

    def sym(i, j):
        return 0.5 * (c4[i, j] + c4[j, i])

    for p in range(len(t)):
        qxx = (t0[p] * sym(0, 0) + 0.5 * t1[p] * (sym(0, 2) + sym(0, 2))
               + t2[p] * sym(2, 2))
        qxy = (t0[p] * sym(0, 1) + 0.5 * t1[p] * (sym(0, 3) + sym(1, 2))
               + t2[p] * sym(2, 3))
        qyy = (t0[p] * sym(1, 1) + 0.5 * t1[p] * (sym(1, 3) + sym(1, 3))
               + t2[p] * sym(3, 3))
        ql[p, 0] = ex * ex * qxx + 2 * ex * ey * qxy + ey * ey * qyy
        ql[p, 2] = ey * ey * qxx - 2 * ex * ey * qxy + ex * ex * qyy
        ql[p, 1] = ex * ey * (qyy - qxx) + (ex * ex - ey * ey) * qxy
        tl[p] = t[p] * length
    return ex, ey


@_jit
def _polygons(tl, ql, k, uc, us, smax, shalf, du, he, tw, cs, sn, hp, vu):
    """Directions, supports and vertices ``u`` of every pair's polygon (M + 2 edges)."""
    nd, npairs = len(uc), len(tl) - 1
    a, b = nd // 4, 3 * nd // 4
    for j in range(npairs + 1):  # each sampled ellipse at the uniform directions
        for d in range(nd):
            he[j, d] = _support(uc[d], us[d], tl, ql, j, k)
    _tangents(tl, ql, k, smax, shalf, du, tw)
    for j in range(npairs):
        pos = 0
        for d in range(nd):
            hu = max(he[j, d], he[j + 1, d])
            if d == a or d == b:
                side = 1.0 if d == a else -1.0
                lane = 2 * j + (0 if d == a else 1)
                sl, phi = tw[5, lane], tw[0, lane]
                r = 1.0 / math.sqrt(1.0 + sl * sl)
                xc, xs = -side * sl * r, side * r
                hx = max(_support(xc, xs, tl, ql, j, k), _support(xc, xs, tl, ql, j + 1, k))
                first = phi < 0.0
                cs[j, pos], sn[j, pos], hp[j, pos] = (xc, xs, hx) if first else (uc[d], us[d], hu)
                cs[j, pos + 1], sn[j, pos + 1], hp[j, pos + 1] = (
                    (uc[d], us[d], hu) if first else (xc, xs, hx))
                pos += 2
            else:
                cs[j, pos], sn[j, pos], hp[j, pos] = uc[d], us[d], hu
                pos += 1
        n = nd + 2
        for i in range(n):
            i1 = (i + 1) % n
            det = cs[j, i] * sn[j, i1] - sn[j, i] * cs[j, i1]
            vu[j, i] = (hp[j, i] * sn[j, i1] - hp[j, i1] * sn[j, i]) / det


@_jit
def _chain(vu, cs, sn, hp, sign, cu, slope, icpt):
    """One side's chains (derived._g_band_flat / _band_chain): ``cu`` (P, K) vertices,
    ``slope``, ``icpt`` (P, K - 1) of its pieces."""
    npairs, kk = cu.shape
    half = kk
    for p in range(npairs):
        for i in range(kk):
            cu[p, i] = vu[p, half - 1 - i] if sign > 0 else vu[p, half + i]
        for i in range(kk - 1):
            e = half - 1 - i if sign > 0 else half + 1 + i
            slope[p, i] = -sign * cs[p, e] / sn[p, e]
            icpt[p, i] = sign * hp[p, e] / sn[p, e]


@_jit
def _stable_order(x, order):
    """``numpy.argsort(x, kind="stable")`` into ``order`` (insertion sort: the chains are
    sorted runs, so few moves; NaN last as numpy)."""
    for i in range(len(x)):
        v = x[i]
        j = i
        while j > 0 and (x[order[j - 1]] > v or (math.isnan(x[order[j - 1]])
                                                 and not math.isnan(v))):
            order[j] = order[j - 1]
            j -= 1
        order[j] = i
    return order


@_jit
def _envelope(cu, slope, icpt, su, w, count, order):
    """Upper envelope at every chain vertex (derived._upper_envelope)."""
    npairs, kk = cu.shape
    flat = cu.ravel()
    order = _stable_order(flat, order)
    count[:] = 0
    for n in range(len(order)):
        f = order[n]
        x = flat[f]
        su[n] = x
        count[f // kk] += 1
        best = -np.inf
        for c in range(npairs):
            if x < cu[c, 0] or x > cu[c, kk - 1]:
                continue  # outside chain c: -inf
            piece = min(max(count[c] - 1, 0), kk - 2)
            v = slope[c, piece] * x + icpt[c, piece]
            if v > best or math.isnan(v):
                best = v
        w[n] = best


@_jit
def _gap(u, w, i, p, q):
    if p < 0 or q >= len(u):
        return np.nan
    u0, u1, w0, w1 = u[p], u[q], w[p], w[q]
    return w[i] - (w0 + (w1 - w0) * (u[i] - u0) / (u1 - u0))


@_jit
def _thin(u, w, valid, keep):
    """Straight runs thinned to ``1e-9`` of the band's scale (derived._drop_collinear)."""
    n = len(u)
    scale = 0.0
    for i in range(n):
        if i and not u[i] > u[i - 1]:
            valid[i] = False
        else:
            valid[i] = math.isfinite(w[i])
        if not valid[i]:
            w[i] = 0.0
        scale = max(scale, abs(w[i]))
    scale = max(scale, u[n - 1] - u[0])
    tol = 1e-9 * max(scale, 1e-300)
    prev = -1
    for i in range(n):
        nxt = i + 1
        while nxt < n and not valid[nxt]:
            nxt += 1
        keep[i] = valid[i] and not abs(_gap(u, w, i, prev, nxt)) <= tol
        if valid[i]:
            prev = i
    for _ in range(n):
        more = False
        p = -1
        for i in range(n):
            if keep[i]:
                p = i
            elif valid[i]:
                q = i + 1
                while q < n and not keep[q]:
                    q += 1
                if not abs(_gap(u, w, i, p, q)) <= tol:
                    more = True
                    keep[i] = True  # numpy: all bad ones at once, from the kept before
        if not more:
            break


@_jit
def _ring(a, b, c4, k, t, t0, t1, t2, uc, us, smax, shalf, du, ws, out):
    """The closed ring of one segment into ``out``; returns its number of points."""
    (ql, tl, cs, sn, hp, vu, cu, slope, icpt, su, w, count, valid, keep, ru, rw, rv,
     order, he, tw) = ws
    ex, ey = _frame(a, b, c4, t, t0, t1, t2, ql, tl)
    _polygons(tl, ql, k, uc, us, smax, shalf, du, he, tw, cs, sn, hp, vu)
    nn = su.shape[0]
    for side in range(2):
        sign = -1.0 if side == 0 else 1.0  # the right side first, u ascending
        _chain(vu, cs, sn, hp, sign, cu, slope, icpt)
        _envelope(cu, slope, icpt, su, w, count, order)
        _thin(su, w, valid, keep)
        for i in range(nn):
            r = i if side == 0 else 2 * nn - 1 - i
            ru[r], rw[r], rv[r] = su[i], sign * w[i], keep[i]
    m = 0
    for i in range(2 * nn):
        if not rv[i]:
            continue
        x = a[0] + ru[i] * ex - rw[i] * ey
        y = a[1] + ru[i] * ey + rw[i] * ex
        if m and x == out[m - 1, 0] and y == out[m - 1, 1]:
            continue
        out[m, 0], out[m, 1] = x, y
        m += 1
    if m:
        out[m, 0], out[m, 1] = out[0, 0], out[0, 1]
        m += 1
    return m


@_jit
def rings(a, b, c4, k, t, t0, t1, t2, uc, us, smax, shalf, du):
    """Rings of many segments: ``(xy, counts, ok)``.

    ``a, b`` (m, 2), ``c4`` (m, 4, 4) C-contiguous; ``t, t0, t1, t2`` (P + 1,) the sample
    parameters and their weights, ``uc, us`` (M,) the uniform directions, ``smax =
    tan(du)``, ``shalf = tan(du / 2)``, ``du = 2 pi / M``. Segment ``i``'s ring is the
    ``counts[i]`` points after those of the segments before it. ``ok[i]`` is False where
    an input or a point is not finite: no ring is written there (the numpy code decides).
    """
    m, npairs, nd = a.shape[0], len(t) - 1, len(uc)
    kk = nd // 2 + 1
    nn = npairs * kk
    ws = (np.empty((npairs + 1, 3)), np.empty(npairs + 1), np.empty((npairs, nd + 2)),
          np.empty((npairs, nd + 2)), np.empty((npairs, nd + 2)), np.empty((npairs, nd + 2)),
          np.empty((npairs, kk)), np.empty((npairs, kk - 1)), np.empty((npairs, kk - 1)),
          np.empty(nn), np.empty(nn), np.zeros(npairs, np.int64), np.empty(nn, np.bool_),
          np.empty(nn, np.bool_), np.empty(2 * nn), np.empty(2 * nn), np.empty(2 * nn, np.bool_),
          np.empty(nn, np.int64), np.empty((npairs + 1, nd)), np.empty((8, 2 * npairs)))
    xy = np.empty((m * (2 * nn + 1), 2))
    counts = np.zeros(m, np.int64)
    ok = np.zeros(m, np.bool_)
    at = 0
    for i in range(m):
        if not (np.all(np.isfinite(a[i])) and np.all(np.isfinite(b[i]))
                and np.all(np.isfinite(c4[i]))):
            continue
        n = _ring(a[i], b[i], c4[i], k, t, t0, t1, t2, uc, us, smax, shalf, du, ws, xy[at:])
        if n == 0 or not np.all(np.isfinite(xy[at:at + n])):
            continue
        counts[i], ok[i] = n, True
        at += n
    return xy[:at], counts, ok
