"""G-bands of many segments at once (:func:`g_band_rings`, :func:`g_band_batch`) and the
compiled band kernels: :mod:`vectoradjust.accuracy._bandkernel` and
:mod:`vectoradjust.accuracy._unionkernel` (numba) are imported lazily here, looked for
once per process, with the numpy code (or GEOS) as the fallback.

Heart module: numpy and scipy only (numba optional, imported lazily).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Callable, Optional

import numpy as np

from vectoradjust.accuracy import propagate as prop
from vectoradjust.accuracy.derived.band_geometry import _band_constants, _g_band_flat

__all__ = ["g_band_rings", "g_band_batch"]


_BAND_BUDGET = 500_000  # elements of the largest (chunk, P, P K) temporaries (~1000 rows)


def g_band_rings(p1, p2, cov_joint, confidence: float = 0.9, n_pairs: int = 6,
                 n_directions: int = 24, progress=None):
    """:func:`g_band_batch` with the rings as one array: ``(xy, offsets)``.

    Ring ``i`` is ``xy[offsets[i]:offsets[i + 1]]`` (closed, counter-clockwise); ready
    for ``shapely.linearrings(xy, indices=...)`` without a Python list of arrays. The
    parameters are those of :func:`g_band_batch`.

    With numba installed, ``_KERNEL_MIN`` segments or more are built by the compiled
    kernel of :mod:`vectoradjust.accuracy._bandkernel` (the same expressions one segment
    at a time, the same rings: ``tests/test_gband_kernel.py``), fewer, or all when
    ``VECTORADJUST_NUMBA=0``, by the numpy code.

    Returns
    -------
    xy : numpy.ndarray, shape (N, 2)
    offsets : numpy.ndarray of int, shape (m + 1,)
    """
    a = np.asarray(p1, float)
    b = np.asarray(p2, float)
    a = a.reshape(-1, a.shape[-1])[:, :2]
    b = b.reshape(-1, b.shape[-1])[:, :2]
    c4 = np.asarray(cov_joint, float).reshape(-1, 4, 4)
    m = a.shape[0]
    if b.shape[0] != m or c4.shape[0] != m:
        raise ValueError("g_band_batch: p1, p2 and cov_joint must describe the same segments")
    if n_pairs < 1 or n_directions < 8 or n_directions % 4:
        raise ValueError("g_band_batch needs n_pairs >= 1 and n_directions a multiple of 4, >= 8")
    k = prop.confidence_scale(confidence, 2)
    kernel = _ring_kernel() if m >= _KERNEL_MIN else None
    if kernel is not None:
        return _compiled_rings(kernel, a, b, c4, k, n_pairs, n_directions, progress)
    # bounded temporaries: (chunk, P, P (M / 2 + 1)) per chunk
    chunk = max(16, _BAND_BUDGET // (n_pairs * n_pairs * (n_directions // 2 + 1)))
    xys, offs, base = [], [np.zeros(1, np.int64)], 0
    for i in range(0, m, chunk):
        xy, off = _g_band_flat(a[i:i + chunk], b[i:i + chunk], c4[i:i + chunk], k,
                               n_pairs, n_directions)
        xys.append(xy)
        offs.append(off[1:] + base)
        base += len(xy)
        if progress is not None:
            progress(min(i + chunk, m) / m)
    xy = np.concatenate(xys) if xys else np.zeros((0, 2))
    return xy, np.concatenate(offs)


#: segments per call of the compiled ring kernel (progress and cancel in between)
_KERNEL_CHUNK = 8_192
#: fewer segments go to the numpy code (and their union to GEOS): loading the compiled
#: kernels from numba's cache costs about 0.5 s per process (about 20 s the first time,
#: when numba compiles them)
_KERNEL_MIN = 10_000
_KERNEL: list = []  # the compiled kernel once looked for (None: numpy only)
_UNION: list = []  # the compiled union of the rings once looked for (None: GEOS only)


def warm_ring_kernel(n_segments: int, progress: Optional[Callable[[str], None]] = None) -> bool:
    """Load (or compile, the first time) the compiled band kernels now - the rings
    (:func:`_ring_kernel`) and their union per feature (:func:`_union_kernel`) - if the
    bands of ``n_segments`` segments will use them; e.g. once in a parent before it
    forks the processes that build the bands. True if both are ready.

    ``progress(message)`` is called before they are looked for (once per process):
    loading takes about 0.5 s, compiling the first time after installation about 20 s.
    """
    if n_segments < _KERNEL_MIN:
        return False
    if not (_KERNEL and _UNION) and progress is not None and not _numba_off():
        progress("loading the compiled band kernels (compiled once after installing)")
    return _ring_kernel() is not None and _union_kernel() is not None


def _numba_off() -> bool:
    """``VECTORADJUST_NUMBA=0`` (or ``no``, ``false``): the numpy code only."""
    return os.environ.get("VECTORADJUST_NUMBA", "1").strip().lower() in ("0", "no", "false")


def _load_kernel(slot: list, load: Callable, trial: Callable, what: str, instead: str):
    """A compiled kernel, looked for once per process and remembered in ``slot``:
    ``load()`` imports its module (ImportError: no numba), ``trial(module)`` calls it
    once - compiled now or loaded from numba's cache - and returns it. None (the
    fallback ``instead`` runs) with ``VECTORADJUST_NUMBA=0``, without numba, or when
    numba cannot compile or cache it (a ``RuntimeWarning`` says why)."""
    if _numba_off():
        return None
    if not slot:
        try:
            module = load()
        except ImportError:  # no numba (e.g. QGIS's Python): the fallback
            slot.append(None)
            return None
        try:
            kernel = trial(module)
        except Exception as exc:  # noqa: BLE001 - any failure of numba: the fallback
            import warnings

            warnings.warn(f"{what} is not available ({exc!r}); {instead}", RuntimeWarning,
                          stacklevel=3)
            slot.append(None)
        else:
            slot.append(kernel)
    return slot[0]


def _ring_kernel():
    """The compiled ring kernel (:mod:`._bandkernel`, numba), loaded from numba's cache
    or compiled (about 8 s, once), or None: no numba, or numba cannot compile it here (a
    warning says why).

    Looked for once per process. ``VECTORADJUST_NUMBA=0`` in the environment keeps the
    numpy code (e.g. to compare the two).
    """
    def load():
        from vectoradjust.accuracy import _bandkernel

        return _bandkernel

    def trial(module):
        _compiled_rings(module.rings, np.zeros((1, 2)), np.ones((1, 2)), np.eye(4)[None],
                        1.0, 6, 24, None)
        return module.rings

    return _load_kernel(_KERNEL, load, trial, "the compiled G-band kernel",
                        "the bands are built by the numpy code (the same rings, slower)")


def _union_kernel():
    """The compiled union of the segment rings of each feature
    (:func:`._unionkernel.union_rings`, numba), loaded from numba's cache or compiled
    (about 11 s, once), or None: no numba, ``VECTORADJUST_NUMBA=0``, or numba cannot
    compile it here (a warning says why); the bands are then united by GEOS. Looked for
    once per process.
    """
    def load():
        from vectoradjust.accuracy import _unionkernel

        return _unionkernel

    def trial(module):  # two overlapping squares
        sq = np.array([[0.0, 0], [2, 0], [2, 1], [0, 1], [0, 0]])
        module.union_rings(np.concatenate([sq, sq + 1]), np.array([0, 5, 10]),
                           np.array([0, 2]), np.ones(2, np.int8), 1e-10)
        return module.union_rings

    return _load_kernel(_UNION, load, trial, "the compiled union of the bands",
                        "GEOS unites them (the same bands, slower)")


def _compiled_rings(kernel, a, b, c4, k, n_pairs, n_directions, progress):
    """:func:`g_band_rings` by the compiled kernel, ``_KERNEL_CHUNK`` segments a call;
    the few segments it leaves (an input or a point not finite) by the numpy code."""
    m = a.shape[0]
    t, t0, t1, t2, du, uc, us = _band_constants(n_pairs, n_directions)
    const = (k, t, t0, t1, t2, uc, us, float(np.tan(du)), float(np.tan(0.5 * du)), du)
    xys, counts = [], []
    for i in range(0, m, _KERNEL_CHUNK):
        j = min(i + _KERNEL_CHUNK, m)
        xy, cnt, ok = kernel(np.ascontiguousarray(a[i:j]), np.ascontiguousarray(b[i:j]),
                             np.ascontiguousarray(c4[i:j]), *const)
        if not ok.all():
            xy, cnt = _splice(xy, cnt, ok, *_g_band_flat(
                a[i:j][~ok], b[i:j][~ok], c4[i:j][~ok], k, n_pairs, n_directions))
        xys.append(xy)
        counts.append(cnt)
        if progress is not None:
            progress(j / m)
    xy = np.concatenate(xys) if xys else np.zeros((0, 2))
    return xy, np.concatenate([np.zeros(1, np.int64), np.cumsum(np.concatenate(counts or [
        np.zeros(0, np.int64)]))])


def _splice(xy, cnt, ok, xy_b, off_b):
    """Rings ``(xy, cnt)`` of the rows ``ok`` and ``(xy_b, off_b)`` of the others, put
    together in row order."""
    cnt = np.asarray(cnt, np.int64).copy()
    cnt[~ok] = np.diff(off_b)
    start = np.empty(len(cnt), np.int64)  # first point of each row in [xy; xy_b]
    start[ok] = np.cumsum(cnt[ok]) - cnt[ok]
    start[~ok] = off_b[:-1] + len(xy)
    src = np.concatenate([xy, xy_b])
    take = np.repeat(start - (np.cumsum(cnt) - cnt), cnt) + np.arange(int(cnt.sum()))
    return src[take], cnt


def g_band_batch(p1, p2, cov_joint, confidence: float = 0.9, n_pairs: int = 6,
                 n_directions: int = 24, progress=None) -> list:
    """G-bands (Shi & Liu 2000) of many line segments at once.

    The band of a segment is the union over ``t`` in ``[0, 1]`` of the error ellipses
    (scaled by ``k = sqrt(chi2_2(confidence))``) of ``P(t) = (1 - t) P1 + t P2``, whose
    covariance is ``F(t) C F(t)'`` with ``F(t) = [(1 - t) I, t I]``.

    Construction (outer approximation, vectorised over segments): the support function
    of the ellipse of ``P(t)`` is convex in ``t`` (a norm of an affine function of ``t``
    plus an affine term), so every ellipse between two samples ``t_j, t_{j+1}`` lies in
    the convex hull of the two sampled ellipses. Each of the ``n_pairs`` hulls is
    replaced by the polygon circumscribed at ``n_directions`` uniform directions plus the
    normals of the two common tangents along the band's sides (bisection, then regula
    falsi), so it contains the hull, follows its straight sides and exceeds its round
    caps by at most ``1 / cos(pi / n_directions) - 1`` of the ellipse size. The band's
    ring is the upper and lower envelope of these polygons along the segment, evaluated
    exactly at every polygon vertex (each polygon side is a maximum / minimum of its edge
    lines); between two such stations the envelope is a maximum of linear pieces, which
    the chord bounds from outside. Stations on straight runs are then dropped where the
    ring moves by at most ``1e-9`` of the band's scale. The ring therefore contains every
    ellipse of the band (to that tolerance), in particular those of the two end points.
    It exceeds the exact band where the band narrows between samples (the waist,
    ``O(1 / n_pairs^2)``): on road segments about 0.5 % of the area with the defaults,
    0.3 % with 8 pairs and 32 directions. Like :func:`vectoradjust.accuracy.propagate.g_band`
    it assumes that every line normal to the segment cuts the band in one interval (true
    unless the segment is shorter than its ellipses).

    Parameters
    ----------
    p1, p2 : array_like, shape (m, 2) or (m, d)
        End points (X, Y used).
    cov_joint : array_like, shape (m, 4, 4)
        Joint covariance of ``[X1, Y1, X2, Y2]`` per segment.
    confidence : float
        Probability of the ellipses (2 degrees of freedom); 0.9 gives ``k = 2.146``.
    n_pairs : int
        Number of ``t`` intervals (``n_pairs + 1`` sampled ellipses).
    n_directions : int
        Uniform directions of the circumscribed polygons (a multiple of 4, >= 8).
    progress : callable, optional
        ``progress(fraction)`` after every chunk of segments (about 1000 with the
        defaults; fewer with more pairs or directions, so that the temporaries stay
        bounded). It may raise to cancel, e.g. :class:`vectoradjust.errors.CancelledError`.

    Returns
    -------
    list of numpy.ndarray
        One closed ring ``(k, 2)`` per segment (first point repeated), counter-clockwise.
        :func:`g_band_rings` gives the same rings as one array with offsets.
    """
    xy, offsets = g_band_rings(p1, p2, cov_joint, confidence, n_pairs, n_directions,
                               progress)
    if len(offsets) < 2:
        return []
    return np.split(xy, offsets[1:-1])


class _Rings(Sequence):
    """The rings of :func:`g_band_rings` as a read-only list of arrays (views, made on use)."""

    def __init__(self, xy: np.ndarray, offsets: np.ndarray) -> None:
        self._xy, self._off = xy, offsets

    def __len__(self) -> int:
        return max(len(self._off) - 1, 0)

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[j] for j in range(*i.indices(len(self)))]
        if not -len(self) <= i < len(self):
            raise IndexError("ring index out of range")
        i = i % len(self)
        return self._xy[self._off[i]:self._off[i + 1]]
