"""Compiled union of each road feature's segment bands (issue 13), with numba.

The band of a feature is the union of the G-band rings of its segments
(:mod:`vectoradjust.files.derived_outputs`). GEOS unites them by buffering the
overlapping MultiPolygon by 0, about 1.2 microseconds per ring point: two thirds of the
band processes' time at 10^6 shape points. The rings are small (about 60 points) and
overlap mostly their neighbours, so this kernel builds the union from the arrangement of
the rings' boundaries:

1. every proper crossing of two rings' edges (bounding boxes of the rings and of the
   edges first), in coordinates relative to the feature's first point;
2. each ring's boundary cut at its crossings into arcs; an arc is on the union's
   boundary when a point inside it is outside every other ring (crossing number); a
   ring without crossings is kept whole or not at all by the same test;
3. the kept arcs linked at the crossings (where an arc ends, the boundary goes on along
   the other ring) into closed loops: counter-clockwise loops bound the union from
   outside, clockwise ones are its holes.

In exact arithmetic this is the union. In floating point it is wherever no decision is
close, and a feature is left to GEOS (``status`` 1) when one is: an edge's end within
``eps`` (``1e-10`` of the feature's extent) of another ring's edge line where the edges'
boxes meet (a touch, a crossing at a vertex, collinear edges), a test point within
``eps`` of another ring, two crossings of a ring at one place, a ring crossed once, a
ring not counter-clockwise, arcs that do not link up into loops, no outer loop, several
outer loops with holes (which hole is in which is not worked out here), or more than
``32 k + 64`` crossings among ``k`` rings. ``tests/test_union_kernel.py`` compares the
result with GEOS's union on random, degenerate and real road bands.

The loops are written as GEOS writes a buffer's: outer rings clockwise, holes
counter-clockwise, and in each feature the outer ring before its holes.

This module imports numba at the top and is itself imported lazily, only by
:func:`vectoradjust.accuracy.derived._union_kernel`.
"""

from __future__ import annotations

import numba
import numpy as np

_jit = numba.njit(cache=True, nogil=True, error_model="numpy")


@_jit
def _misses(xy, e, ox, oy, x0, y0, x1, y1):
    """True when edge ``e`` (from point ``e`` to ``e + 1``, local coordinates) misses the
    box ``x0 .. x1, y0 .. y1`` or has no length."""
    px, py = xy[e, 0] - ox, xy[e, 1] - oy
    p2x, p2y = xy[e + 1, 0] - ox, xy[e + 1, 1] - oy
    return min(px, p2x) > x1 or max(px, p2x) < x0 or min(py, p2y) > y1 or \
        max(py, p2y) < y0 or (px == p2x and py == p2y)


@_jit
def _crossings(xy, off, rings, k, ox, oy, bb, eps, cand, cx, cy, er, ep):
    """All proper crossings of the ``k`` rings ``rings[:k]`` (bounding boxes ``bb``,
    local coordinates: minus ``(ox, oy)``).

    Crossing ``c`` is at ``(cx[c], cy[c])``; its event ``2 c`` is on ring slot
    ``er[2 c]`` at ``ep[2 c]`` (edge index within the ring + parameter along the edge),
    event ``2 c + 1`` on the other ring. Returns the number of crossings, or -1: a
    degenerate configuration, or more crossings than ``cx`` holds."""
    cap = cx.shape[0]
    nc = 0
    for ii in range(k):
        a0, a1 = off[rings[ii]], off[rings[ii] + 1]
        for jj in range(ii + 1, k):
            if bb[ii, 0] > bb[jj, 2] + eps or bb[jj, 0] > bb[ii, 2] + eps or \
                    bb[ii, 1] > bb[jj, 3] + eps or bb[jj, 1] > bb[ii, 3] + eps:
                continue
            x0 = max(bb[ii, 0], bb[jj, 0]) - eps  # where the boxes overlap
            y0 = max(bb[ii, 1], bb[jj, 1]) - eps
            x1 = min(bb[ii, 2], bb[jj, 2]) + eps
            y1 = min(bb[ii, 3], bb[jj, 3]) + eps
            b0, b1 = off[rings[jj]], off[rings[jj] + 1]
            nb = 0  # the edges of ring jj there
            for f in range(b0, b1 - 1):
                if not _misses(xy, f, ox, oy, x0, y0, x1, y1):
                    cand[nb] = f
                    nb += 1
            if nb == 0:
                continue
            for e in range(a0, a1 - 1):
                if _misses(xy, e, ox, oy, x0, y0, x1, y1):
                    continue
                px, py = xy[e, 0] - ox, xy[e, 1] - oy
                p2x, p2y = xy[e + 1, 0] - ox, xy[e + 1, 1] - oy
                rx, ry = p2x - px, p2y - py
                ta = eps * np.sqrt(rx * rx + ry * ry)
                for c in range(nb):
                    f = cand[c]
                    qx, qy = xy[f, 0] - ox, xy[f, 1] - oy
                    q2x, q2y = xy[f + 1, 0] - ox, xy[f + 1, 1] - oy
                    if min(qx, q2x) > max(px, p2x) + eps or \
                            max(qx, q2x) < min(px, p2x) - eps or \
                            min(qy, q2y) > max(py, p2y) + eps or \
                            max(qy, q2y) < min(py, p2y) - eps:
                        continue
                    sx, sy = q2x - qx, q2y - qy
                    tb = eps * np.sqrt(sx * sx + sy * sy)
                    o1 = rx * (qy - py) - ry * (qx - px)  # q and q2 against p p2
                    o2 = rx * (q2y - py) - ry * (q2x - px)
                    o3 = sx * (py - qy) - sy * (px - qx)  # p and p2 against q q2
                    o4 = sx * (p2y - qy) - sy * (p2x - qx)
                    if (o1 > ta and o2 > ta) or (o1 < -ta and o2 < -ta) or \
                            (o3 > tb and o4 > tb) or (o3 < -tb and o4 < -tb):
                        continue  # clearly apart
                    if abs(o1) <= ta or abs(o2) <= ta or abs(o3) <= tb or abs(o4) <= tb:
                        return -1  # an end on (or close to) the other edge's line
                    if nc >= cap:
                        return -1
                    t = o3 / (o3 - o4)  # along p p2
                    u = o1 / (o1 - o2)  # along q q2
                    cx[nc] = px + t * rx
                    cy[nc] = py + t * ry
                    er[2 * nc] = ii
                    ep[2 * nc] = (e - a0) + t
                    er[2 * nc + 1] = jj
                    ep[2 * nc + 1] = (f - b0) + u
                    nc += 1
    return nc


@_jit
def _inside(xy, off, r, px, py, ox, oy, eps):
    """1 if the local point ``(px, py)`` is inside ring ``r``, 0 if outside, -1 if
    within ``eps`` of its boundary (crossing number)."""
    inside = False
    for e in range(off[r], off[r + 1] - 1):
        ax, ay = xy[e, 0] - ox, xy[e, 1] - oy
        bx, by = xy[e + 1, 0] - ox, xy[e + 1, 1] - oy
        if min(ax, bx) - eps <= px <= max(ax, bx) + eps and \
                min(ay, by) - eps <= py <= max(ay, by) + eps:
            dx, dy = bx - ax, by - ay
            ll = dx * dx + dy * dy
            s = 0.0 if ll == 0.0 else min(max(((px - ax) * dx + (py - ay) * dy) / ll, 0.0), 1.0)
            if (px - ax - s * dx) ** 2 + (py - ay - s * dy) ** 2 <= eps * eps:
                return -1
        if (ay > py) != (by > py):
            if px < ax + (py - ay) * (bx - ax) / (by - ay):
                inside = not inside
    return 1 if inside else 0


@_jit
def _outside_others(xy, off, rings, k, bb, own, px, py, ox, oy, eps):
    """1: the local point is outside every ring ``rings[:k]`` but slot ``own``; 0: inside
    one; -1: within ``eps`` of one's boundary."""
    for jj in range(k):
        if jj == own or px < bb[jj, 0] - eps or px > bb[jj, 2] + eps or \
                py < bb[jj, 1] - eps or py > bb[jj, 3] + eps:
            continue
        s = _inside(xy, off, rings[jj], px, py, ox, oy, eps)
        if s != 0:
            return -1 if s < 0 else 0
    return 1


@_jit
def _close_loop(out, start, at, ox, oy):
    """Close the loop ``out[start:at]`` (its first point repeated), reverse it (GEOS's
    orientation) and return ``(at, +1 outer / -1 hole)`` by its orientation as traced
    (counter-clockwise: outer)."""
    out[at, 0], out[at, 1] = out[start, 0], out[start, 1]
    at += 1
    s = 0.0
    for i in range(start, at - 1):
        s += (out[i, 0] - ox) * (out[i + 1, 1] - oy) - (out[i + 1, 0] - ox) * (out[i, 1] - oy)
    i, j = start, at - 1
    while i < j:
        x, y = out[i, 0], out[i, 1]
        out[i, 0], out[i, 1] = out[j, 0], out[j, 1]
        out[j, 0], out[j, 1] = x, y
        i += 1
        j -= 1
    return at, (1 if s > 0.0 else -1)


@_jit
def _boxes(xy, off, rings, k, ox, oy, bb):
    """The rings' bounding boxes (local) into ``bb``; their extent, or -1 when a ring is
    not counter-clockwise (or not finite)."""
    ext = 0.0
    for ii in range(k):
        r = rings[ii]
        x0, y0, x1, y1 = np.inf, np.inf, -np.inf, -np.inf
        s = 0.0
        for p in range(off[r], off[r + 1]):
            x, y = xy[p, 0] - ox, xy[p, 1] - oy
            x0, y0, x1, y1 = min(x0, x), min(y0, y), max(x1, x), max(y1, y)
            if p + 1 < off[r + 1]:
                s += x * (xy[p + 1, 1] - oy) - (xy[p + 1, 0] - ox) * y
        if not s > 0.0:
            return -1.0
        bb[ii, 0], bb[ii, 1], bb[ii, 2], bb[ii, 3] = x0, y0, x1, y1
        ext = max(ext, abs(x0), abs(y0), abs(x1), abs(y1))
    return ext if np.isfinite(ext) else -1.0


@_jit
def _along(k, ne, er, ep, first, fill, order, nxt):
    """Every ring's events in order along it (slot ``ii``'s are
    ``order[first[ii]:first[ii + 1]]``) and the next event along the same ring
    (``nxt``). False: a ring crossed once, or two crossings at one place."""
    for ii in range(k + 1):
        first[ii] = 0
    for e in range(ne):
        first[er[e] + 1] += 1
    for ii in range(k):
        first[ii + 1] += first[ii]
        fill[ii] = first[ii]
    for e in range(ne):
        order[fill[er[e]]] = e
        fill[er[e]] += 1
    for ii in range(k):
        a0, a1 = first[ii], first[ii + 1]
        if a1 - a0 == 1:
            return False
        for a in range(a0 + 1, a1):  # insertion sort (a few events per ring)
            e = order[a]
            b = a - 1
            while b >= a0 and ep[order[b]] > ep[e]:
                order[b + 1] = order[b]
                b -= 1
            order[b + 1] = e
        for a in range(a0, a1):
            nxt[order[a]] = order[a + 1] if a + 1 < a1 else order[a0]
            if a > a0 and ep[order[a]] - ep[order[a - 1]] <= 1e-12:
                return False
    return True


@_jit
def _kept(xy, off, rings, k, ox, oy, bb, eps, ne, er, ep, nxt, first, keep, seen, whole):
    """Which arcs (from an event to the next along its ring: ``keep``) and which rings
    without crossings (``whole``) are on the union's boundary. False: a close call."""
    for e in range(ne):
        r = rings[er[e]]
        n = off[r + 1] - off[r] - 1
        edge = min(int(ep[e]), n - 1)
        t = ep[e] - edge
        q = ep[nxt[e]]
        tm = 0.5 * (t + (q - edge)) if (int(q) == edge and q > ep[e]) else 0.5 * (t + 1.0)
        p0 = off[r] + edge
        ax, ay = xy[p0, 0] - ox, xy[p0, 1] - oy
        px = ax + tm * ((xy[p0 + 1, 0] - ox) - ax)
        py = ay + tm * ((xy[p0 + 1, 1] - oy) - ay)
        state = _outside_others(xy, off, rings, k, bb, er[e], px, py, ox, oy, eps)
        if state < 0:
            return False
        keep[e] = state == 1
        seen[e] = False
    for ii in range(k):
        whole[ii] = False
        if first[ii + 1] == first[ii]:
            p0 = off[rings[ii]]
            px = 0.5 * ((xy[p0, 0] - ox) + (xy[p0 + 1, 0] - ox))
            py = 0.5 * ((xy[p0, 1] - oy) + (xy[p0 + 1, 1] - oy))
            state = _outside_others(xy, off, rings, k, bb, ii, px, py, ox, oy, eps)
            if state < 0:
                return False
            whole[ii] = state == 1
    return True


@_jit
def _trace(xy, off, rings, e0, ox, oy, cx, cy, er, ep, nxt, keep, seen, out, at):
    """The loop of kept arcs from event ``e0`` into ``out`` from ``at`` (not closed);
    returns its end, or -1 when the arcs do not link up."""
    e = e0
    while True:
        if seen[e] or not keep[e]:
            return -1
        seen[e] = True
        r = rings[er[e]]
        n = off[r + 1] - off[r] - 1
        out[at, 0], out[at, 1] = cx[e // 2] + ox, cy[e // 2] + oy
        at += 1
        f = nxt[e]
        ea, eb = min(int(ep[e]), n - 1), min(int(ep[f]), n - 1)
        if eb == ea and ep[f] > ep[e]:
            steps = 0
        else:
            steps = (eb - ea) % n
            if steps == 0:
                steps = n
        for s in range(1, steps + 1):  # the ring's points between the two events
            v = off[r] + (ea + s) % n
            out[at, 0], out[at, 1] = xy[v, 0], xy[v, 1]
            at += 1
        e = f ^ 1  # the same crossing on the other ring: the boundary goes on there
        if e == e0:
            return at


@_jit
def _feature(xy, off, rings, k, eps_rel, out, at, loops, nl, bb, cand, cx, cy, er, ep,
             first, fill, order, nxt, keep, seen, whole):
    """The union of the rings ``rings[:k]`` (one feature): its loops appended to ``out``
    from point ``at`` and to ``loops`` (rows: first point, end, +1 outer / -1 hole) from
    row ``nl``. Returns ``(at, nl, ok)``; not ok: left to GEOS (nothing kept)."""
    ox, oy = xy[off[rings[0]], 0], xy[off[rings[0]], 1]
    ext = _boxes(xy, off, rings, k, ox, oy, bb)
    if ext < 0.0:
        return at, nl, False
    eps = eps_rel * ext
    nc = _crossings(xy, off, rings, k, ox, oy, bb, eps, cand, cx, cy, er, ep)
    if nc < 0 or not _along(k, 2 * nc, er, ep, first, fill, order, nxt) or \
            not _kept(xy, off, rings, k, ox, oy, bb, eps, 2 * nc, er, ep, nxt, first, keep,
                      seen, whole):
        return at, nl, False
    at0, nl0 = at, nl
    shells, holes = 0, 0
    for e0 in range(2 * nc + k):  # the kept arcs linked into loops, then whole rings
        start = at
        if e0 < 2 * nc:
            if not keep[e0] or seen[e0]:
                continue
            at = _trace(xy, off, rings, e0, ox, oy, cx, cy, er, ep, nxt, keep, seen, out, at)
            if at < 0:
                return at0, nl0, False
        elif whole[e0 - 2 * nc]:
            r = rings[e0 - 2 * nc]
            for p in range(off[r], off[r + 1] - 1):
                out[at, 0], out[at, 1] = xy[p, 0], xy[p, 1]
                at += 1
        else:
            continue
        at, sign = _close_loop(out, start, at, ox, oy)
        loops[nl, 0], loops[nl, 1], loops[nl, 2] = start, at, sign
        nl += 1
        shells += sign > 0
        holes += sign < 0
    for e in range(2 * nc):
        if keep[e] and not seen[e]:
            return at0, nl0, False
    if shells == 0 or (holes > 0 and shells > 1):
        return at0, nl0, False
    if holes > 0:  # the one outer loop first, its holes after it
        for i in range(nl0 + 1, nl):
            if loops[i, 2] > 0:
                for c in range(3):
                    loops[i, c], loops[nl0, c] = loops[nl0, c], loops[i, c]
                break
    return at, nl, True


@_jit
def union_rings(xy, off, fs, usable, eps_rel):
    """The union of every feature's rings.

    Parameters
    ----------
    xy : (N, 2) float64
        The rings' points; ring ``r`` is ``xy[off[r]:off[r + 1]]``, closed and
        counter-clockwise.
    off : (m + 1,) int64
    fs : (nf + 1,) int64
        Feature ``f`` has the rings ``fs[f] .. fs[f + 1] - 1``.
    usable : (m,) int8
        1: a valid ring; 0: no ring (no area, left out); -1: not valid (its feature is
        left to GEOS).
    eps_rel : float
        Closeness, relative to a feature's extent, below which a decision is left to
        GEOS.

    Returns
    -------
    out : (K, 2) float64
        The loops' points.
    loops : (L, 3) int64
        Per loop: first point, end, +1 outer / -1 hole; in each feature its outer loop
        before the holes.
    lstart : (nf + 1,) int64
        Feature ``f``'s loops are ``loops[lstart[f]:lstart[f + 1]]`` (none: empty, or
        left to GEOS).
    status : (nf,) int8
        0: done here, 1: left to GEOS.
    """
    m = off.shape[0] - 1
    nf = fs.shape[0] - 1
    kmax, rmax = 1, 4
    for f in range(nf):
        kmax = max(kmax, fs[f + 1] - fs[f])
    for r in range(m):
        rmax = max(rmax, off[r + 1] - off[r])
    cap = 32 * kmax + 64
    rings = np.empty(kmax, np.int64)
    bb = np.empty((kmax, 4))
    cand = np.empty(rmax, np.int64)
    cx, cy = np.empty(cap), np.empty(cap)
    er, ep = np.empty(2 * cap, np.int64), np.empty(2 * cap)
    first, fill = np.empty(kmax + 1, np.int64), np.empty(kmax, np.int64)
    order, nxt = np.empty(2 * cap, np.int64), np.empty(2 * cap, np.int64)
    keep, seen = np.empty(2 * cap, np.bool_), np.empty(2 * cap, np.bool_)
    whole = np.empty(kmax, np.bool_)
    out = np.empty((xy.shape[0] + 4 * cap + 64, 2))
    loops = np.empty((m + 2 * cap + 64, 3), np.int64)
    lstart = np.zeros(nf + 1, np.int64)
    status = np.zeros(nf, np.int8)
    at, nl = 0, 0
    for f in range(nf):
        k, verts, bad = 0, 0, False
        for r in range(fs[f], fs[f + 1]):
            if usable[r] < 0:
                bad = True
            elif usable[r] > 0:
                rings[k] = r
                k += 1
                verts += off[r + 1] - off[r]
        if bad:
            status[f] = 1
        elif k > 0:
            need = verts + 6 * cap + 2 * kmax  # points of the loops, at most
            if at + need > out.shape[0]:
                grown = np.empty((max(2 * out.shape[0], at + need), 2))
                grown[:at] = out[:at]
                out = grown
            if nl + 2 * cap + kmax > loops.shape[0]:
                more = np.empty((max(2 * loops.shape[0], nl + 2 * cap + kmax), 3), np.int64)
                more[:nl] = loops[:nl]
                loops = more
            at, nl, ok = _feature(xy, off, rings, k, eps_rel, out, at, loops, nl, bb, cand,
                                  cx, cy, er, ep, first, fill, order, nxt, keep, seen, whole)
            if not ok:
                status[f] = 1
        lstart[f + 1] = nl
    return out[:at], loops[:nl], lstart, status
