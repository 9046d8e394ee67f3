"""Uncertainty bands of a run's segments: the segments' joint covariances
(:func:`segment_covariances`), the conflated vertices' covariance
(:func:`vertex_covariance`), the bands' scales (:func:`band_scale`, at free ends
:func:`end_scale`) and the bands of every feature (:func:`segment_bands`,
:func:`uncertainty_bands`).

Heart module: numpy and scipy only.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Optional

import numpy as np
from scipy.special import ndtri

from vectoradjust.accuracy import stats
from vectoradjust.accuracy.derived.band_kernels import _Rings, g_band_rings
from vectoradjust.accuracy.derived.covariance import (
    _adjusted_coords,
    _check_result,
    _identification_variance,
    _segments,
    cross_covariance,
)

if TYPE_CHECKING:  # pragma: no cover
    from vectoradjust.results import AdjustmentRun, DatabaseResult

__all__ = ["SegmentBands", "SegmentCovariances", "vertex_covariance", "segment_covariances",
           "segment_bands", "band_scale", "end_scale", "band_segment_counts", "uncertainty_bands"]


@dataclass
class SegmentBands:
    """G-bands of the segments of a road database (:func:`segment_bands`).

    Attributes
    ----------
    feature : numpy.ndarray of int, shape (s,)
        Feature index of each segment.
    start_vertex : numpy.ndarray of int, shape (s,)
        First vertex of each segment (the segment runs to ``start_vertex + 1``).
    rings : sequence of numpy.ndarray
        Closed ring ``(k, 2)`` of each segment's band (a read-only list).
    cov_joint : numpy.ndarray, shape (s, 6, 6)
        Joint a-posteriori covariance of the segment's end points (X1, Y1, Z1, X2, ...).
    confidence : float
    xy, offsets : numpy.ndarray, optional
        The same rings as one array: ring ``i`` is ``xy[offsets[i]:offsets[i + 1]]``
        (:func:`g_band_rings`).
    """

    feature: np.ndarray
    start_vertex: np.ndarray
    rings: list
    cov_joint: np.ndarray
    confidence: float
    xy: Optional[np.ndarray] = None
    offsets: Optional[np.ndarray] = None


@dataclass
class SegmentCovariances:
    """Covariance blocks of the measured segments of a road database
    (:func:`segment_covariances`): everything :func:`segment_bands` takes from the
    factorisation, computed once so that the bands can be built after it is let go.

    ``start`` (s,) are the segments' first vertices (ascending), ``cross`` (s, 3, 3) the
    covariances ``Cov(x_a, x_b)`` of their end points, ``own_a`` / ``own_b`` (s, 3, 3)
    their own blocks when the result keeps no ``point_cov`` (None otherwise).
    """

    start: np.ndarray
    cross: np.ndarray
    own_a: Optional[np.ndarray] = None
    own_b: Optional[np.ndarray] = None


def _measured_segments(db: DatabaseResult, part: tuple = (0, 1)) -> np.ndarray:
    """First vertices of the segments with both end points measured (distinct points),
    of the features ``i`` modulo ``n`` (``part = (i, n)``)."""
    vp = np.asarray(db.vertex_point, np.int64)
    a = _part_segments(db, part)
    if a.size:
        a = a[(vp[a] >= 0) & (vp[a + 1] >= 0) & (vp[a] != vp[a + 1])]
    return a


def _part_segments(db: DatabaseResult, part: tuple = (0, 1)) -> np.ndarray:
    """:func:`_segments` of the features ``i`` modulo ``n`` (``part = (i, n)``)."""
    a = _segments(db)
    if part[1] > 1 and a.size:
        a = a[np.asarray(db.shape.layer.vertex_feature)[a] % part[1] == part[0]]
    return a


def vertex_covariance(db: DatabaseResult) -> Optional[np.ndarray]:
    """The covariance (nv, 3, 3) of every vertex that its ``CE90`` / ``LE90`` state.

    Built from ``d.vertices``: the sigmas ``SigmaX/Y/Z`` on the diagonal (a measured
    vertex: the adjustment's covariance, the database offsets' share included, plus the
    identification error; a conflated one: the collocation's prediction error with the
    database noise and the trend's error, :mod:`vectoradjust.conflation`), the
    horizontal block scaled so that its CE90 is the vertex's ``CE90`` (for a conflated
    vertex the CE90 of the predictive distribution, a little wider than the plug-in
    normal's). NaN where the vertex has no value (unmeasured and not conflated).

    Returns
    -------
    numpy.ndarray or None
        None before the vertices are tabulated (``d.vertices`` empty).
    """
    v = db.vertices
    if not v or "SigmaX" not in v or "CE90" not in v:
        return None
    sig = np.column_stack([np.asarray(v[f"Sigma{a}"], float) for a in "XYZ"])
    cov = np.zeros((len(sig), 3, 3))
    cov[:, [0, 1, 2], [0, 1, 2]] = sig ** 2
    with np.errstate(invalid="ignore", divide="ignore"):
        ce_diag = stats.ce90(cov[:, :2, :2])
        f = np.asarray(v["CE90"], float) / ce_diag
    f = np.where(np.isfinite(f) & (f > 0), f, 1.0)
    cov[:, :2, :2] *= (f * f)[:, None, None]
    cov[~np.isfinite(sig[:, :2]).all(axis=1)] = np.nan
    return cov


def _identification_blocks(cov: np.ndarray, idv: np.ndarray) -> np.ndarray:
    """``cov`` (s, 6, 6) of segments' two measured end points plus the identification
    error of each (independent per object point: the two ends are distinct points)."""
    out = cov.copy()
    d = np.concatenate([idv, idv])
    out[:, np.arange(6), np.arange(6)] += d
    return out


def _other_segments(run: AdjustmentRun, db: DatabaseResult, part: tuple):
    """The segments with an end point that was not measured but has a covariance (the
    conflation predicted it): first vertices (s,), end points and joint covariances
    (s, 6, 6); None before the conflation.

    A conflated vertex's error is a smooth field plus the database's white noise; the
    two ends of a segment (tens of metres apart, the field's range hundreds) are taken
    as fully correlated, ``C_ab = C_a^1/2 C_b^1/2``: the band between them is then the
    linear interpolation of their ellipses (the widest the two ends allow), never the
    narrower band of independent ends.
    """
    vc = vertex_covariance(db)
    if vc is None:
        return None
    vp = np.asarray(db.vertex_point, np.int64)
    vo = np.asarray(db.shape.vertex_object)
    a = _part_segments(db, part)
    if a.size:
        both = (vp[a] >= 0) & (vp[a + 1] >= 0)
        ok = np.isfinite(vc[a, 0, 0]) & np.isfinite(vc[a + 1, 0, 0])
        a = a[~both & ok & (vo[a] != vo[a + 1])]
    adj = _adjusted_coords(run, db)
    ca, cb = vc[a], vc[a + 1]
    sa = np.sqrt(np.einsum("sii->si", ca))
    sb = np.sqrt(np.einsum("sii->si", cb))
    cov = np.zeros((a.size, 6, 6))
    cov[:, :3, :3], cov[:, 3:, 3:] = ca, cb
    cross = np.zeros((a.size, 3, 3))
    cross[:, [0, 1, 2], [0, 1, 2]] = sa * sb
    cov[:, :3, 3:], cov[:, 3:, :3] = cross, cross
    return a, adj[a], adj[a + 1], cov


def segment_covariances(run: AdjustmentRun, db: DatabaseResult,
                        part: tuple = (0, 1)) -> SegmentCovariances:
    """The covariance blocks :func:`segment_bands` needs, for every measured segment.

    Parameters
    ----------
    run : AdjustmentRun
    db : DatabaseResult
    part : (int, int)
        Only the segments of :func:`segment_bands` with the same ``part``.

    Returns
    -------
    SegmentCovariances
    """
    res = run.result
    _check_result(res)
    vp = np.asarray(db.vertex_point, np.int64)
    a = _measured_segments(db, part)
    pa, pb = vp[a], vp[a + 1]
    own = res.point_cov is None
    return SegmentCovariances(a, cross_covariance(res, pa, pb),
                              cross_covariance(res, pa, pa) if own else None,
                              cross_covariance(res, pb, pb) if own else None)


def segment_bands(run: AdjustmentRun, db: DatabaseResult, confidence: float = 0.9,
                  part: tuple = (0, 1), covariances: Optional[dict] = None,
                  segments: str = "all", **kwargs) -> SegmentBands:
    """G-band of every segment of a road database, from the covariance of its vertices'
    CE90/LE90.

    A segment whose two end points were measured: the joint 6x6 covariance of the
    adjusted points from :func:`cross_covariance` (their own blocks and the cross
    block, the database offsets' share included), plus the identification error
    (``identification_sigma``, independent per object point) on each end - the band of
    the real road, as the vertices' CE90 is. A segment with an end that the conflation
    predicted: the conflated vertices' covariance (:func:`vertex_covariance`, fully
    correlated ends, :func:`_other_segments`); these exist only once the run is
    conflated (before, e.g. in the command line's band processes started right after
    the adjustment, only the measured segments get bands). A segment with an end
    without any covariance (not measured, not conflated) or whose two vertices are one
    object point gets none.

    The ellipses are drawn at :func:`band_scale` (``confidence`` of the error across
    the line: 1.645 sigma at 90 %), those at a free end of the band (a line's first or
    last vertex, or next to a segment without a band) at :func:`end_scale` (2.011 sigma
    at 90 %: the band holds the true end vertex itself at ``confidence``,
    :func:`_free_end_caps`). ``cov_joint`` is the covariance, not scaled.

    Parameters
    ----------
    run : AdjustmentRun
    db : DatabaseResult
    confidence : float
        Probability that the band holds the true road at a point of it (0.9 = 90 %).
    part : (int, int)
        ``(i, n)``: only the segments of the features whose index is ``i`` modulo ``n``
        (``n`` processes share the work; default all).
    covariances : dict, optional
        :class:`SegmentCovariances` by database name (:func:`segment_covariances`):
        taken from there instead of the factorisation, which may then be let go.
    segments : {"all", "measured", "other"}
        Which segments: both (default), those with two measured ends, or the others.
    **kwargs
        ``n_pairs``, ``n_directions``, ``progress`` of :func:`g_band_batch`.

    Returns
    -------
    SegmentBands
        Segments in the order of the layer (ascending first vertex).
    """
    if segments not in ("all", "measured", "other"):
        raise ValueError("segment_bands: segments must be 'all', 'measured' or 'other'")
    starts, p1s, p2s, covs, free = [], [], [], [], []
    if segments != "other":
        a, p1, p2, cov = _measured_joint(run, db, part, covariances)
        starts.append(a), p1s.append(p1), p2s.append(p2), covs.append(cov)
        free.append(_free_ends(a, _bandable_segments(db, part)))
    other = _other_segments(run, db, part) if segments != "measured" else None
    if other is not None:
        starts.append(other[0]), p1s.append(other[1]), p2s.append(other[2])
        covs.append(other[3])
        free.append(_free_ends(other[0], np.union1d(_measured_segments(db, part), other[0])))
    if not starts:
        starts, p1s, p2s, covs, free = ([np.zeros(0, np.int64)], [np.zeros((0, 3))],
                                        [np.zeros((0, 3))], [np.zeros((0, 6, 6))],
                                        [np.zeros((0, 2), bool)])
    a = np.concatenate(starts)
    order = np.argsort(a, kind="stable")
    a, cov = a[order], np.concatenate(covs)[order]
    p1, p2 = np.concatenate(p1s)[order], np.concatenate(p2s)[order]
    sel = [0, 1, 3, 4]
    drawn = _free_end_caps(cov[:, sel][:, :, sel], np.concatenate(free)[order], confidence)
    xy, offsets = g_band_rings(p1, p2, drawn, _ellipse_confidence(confidence), **kwargs)
    return SegmentBands(db.shape.layer.vertex_feature[a], a, _Rings(xy, offsets), cov,
                        confidence, xy, offsets)


def _bandable_segments(db: DatabaseResult, part: tuple) -> np.ndarray:
    """First vertices of the segments that have or may get a band: two distinct object
    points (measured, or predicted by a conflation that may come later)."""
    vo = np.asarray(db.shape.vertex_object)
    a = _part_segments(db, part)
    return a[vo[a] != vo[a + 1]] if a.size else a


def _free_ends(a: np.ndarray, banded: np.ndarray) -> np.ndarray:
    """(s, 2) bool: whether the first / second end of each segment ``a`` is a free end
    of the band (no segment of ``banded`` continues the line there)."""
    return np.column_stack([~np.isin(a - 1, banded), ~np.isin(a + 1, banded)])


def _free_end_caps(cov4: np.ndarray, free: np.ndarray, confidence: float) -> np.ndarray:
    """The joint covariances (s, 4, 4) the rings are drawn from: at a free end of the
    band (``free`` (s, 2), :func:`_free_ends`) the end's block is scaled so that its
    ellipse is drawn at :func:`end_scale` (2.011 sigma at 90 %) instead of
    :func:`band_scale` (1.645): the band then holds the true end vertex at
    ``confidence`` too.

    Between two banded segments an error along the line moves the true vertex into the
    next segment's band, so 1.645 sigma across suffices; at a free end nothing continues,
    and the 1-D scale's cap held the true end vertex at only about 82 % (a circular error:
    half the 90 % strip plus the 74 % of the cap's 1.645-sigma disc), which with most
    conflated vertices at line ends (short features between junctions) pulled the
    bands' coverage of conflated vertices to 0.84. ``D C D``, ``D = diag(f, f, g, g)``
    keeps the joint covariance positive semi-definite; the bands' stated ``cov_joint``
    is unchanged.

    Free ends of a measured segment are decided without the conflation (a neighbouring
    segment with an unmeasured end counts as continuing: its conflated band will), so
    that the measured bands are the same whether built before the conflation (the
    command line's band processes) or after; those of a conflated segment against the
    bands that exist (measured and conflated).
    """
    out = np.array(cov4, float, copy=True)
    if not len(out):
        return out
    f = end_scale(confidence) / band_scale(confidence)
    d = np.ones((len(out), 4))
    d[free[:, 0], :2] = f
    d[free[:, 1], 2:] = f
    return out * d[:, :, None] * d[:, None, :]


def end_scale(confidence: float) -> float:
    """The factor of the sigmas of the ellipse that closes a band at a free end of a line
    (:func:`_free_end_caps`): 2.011 at 90 %.

    At a free end the true end vertex is inside the band if its error points back along
    the line and its error across it is within ``a = band_scale(confidence)`` (the
    half-strip), or if it lies inside the end's ellipse of scale ``k``. For a circular
    normal error that probability is ``c / 2 + (1 - exp(-k^2 / 2)) / 2 + 2 int_a^k
    phi(x) (Phi(sqrt(k^2 - x^2)) - 1/2) dx``; ``k`` solves it equal to the band's
    ``confidence`` ``c`` (between ``a``, which gives 0.82 at 90 %, and the 2-D scale
    ``sqrt(-2 ln(1 - c))``, 2.146, which gives 0.92).
    """
    from scipy import integrate, optimize
    from scipy.special import ndtr

    a = band_scale(confidence)

    def held(k: float) -> float:
        side = integrate.quad(lambda x: np.exp(-0.5 * x * x) / np.sqrt(2.0 * np.pi)
                              * (ndtr(np.sqrt(max(k * k - x * x, 0.0))) - 0.5), a, k)[0]
        return 0.5 * confidence + 0.5 * -np.expm1(-0.5 * k * k) + 2.0 * side - confidence

    return float(optimize.brentq(held, a, float(np.sqrt(-2.0 * np.log1p(-confidence))),
                                 xtol=1e-12))


def band_scale(confidence: float) -> float:
    """The factor of the sigmas that a road's G-band of ``confidence`` draws:
    ``Phi^-1((1 + c) / 2)``, 1.645 at 90 %.

    The band is a statement about the line: where the true road runs, i.e. its error
    across the line, one dimension (an error along the line moves a point along it, still
    on the line). The two-dimensional scale of a point's 90 % ellipse (2.146) made the
    band hold the true road at 95-97 % of its vertices on real road geometry
    (validation/bands_lengths.py), this one at 86-89 % - less at the lines' ends, where
    an error along the line leaves the band: there :func:`end_scale`.
    """
    if not 0.0 < confidence < 1.0:
        raise ValueError("the band's confidence must lie between 0 and 1")
    return float(ndtri(0.5 + 0.5 * confidence))


def _ellipse_confidence(confidence: float) -> float:
    """The probability of the 2-D ellipses :func:`g_band_rings` draws at
    :func:`band_scale` (``1 - exp(-k^2 / 2)``)."""
    k = band_scale(confidence)
    return float(1.0 - np.exp(-0.5 * k * k))


def band_segment_counts(run: AdjustmentRun, db: DatabaseResult) -> tuple[int, int]:
    """How many segments of a database :func:`segment_bands` gives a band: with two
    measured ends, and with a conflated end (0 before the conflation)."""
    other = _other_segments(run, db, (0, 1))
    return int(_measured_segments(db).size), 0 if other is None else int(other[0].size)


def _measured_joint(run: AdjustmentRun, db: DatabaseResult, part: tuple,
                    covariances: Optional[dict]):
    """First vertices, end points and joint covariances (s, 6, 6) of the segments with
    two measured ends, the identification error included (:func:`segment_bands`)."""
    res = run.result
    kept = None if covariances is None else covariances.get(db.name)
    if kept is None:  # from the factorisation now
        kept = segment_covariances(run, db, part)
    vp = np.asarray(db.vertex_point, np.int64)
    a = _measured_segments(db, part)
    pa, pb = vp[a], vp[a + 1]
    row = np.searchsorted(kept.start, a)
    if np.any(row >= len(kept.start)) or np.any(
            kept.start[np.minimum(row, max(len(kept.start) - 1, 0))] != a):
        raise ValueError(f"segment_bands: the covariances given are not those of "
                         f"database {db.name!r}")
    cov = np.zeros((a.size, 6, 6))
    if a.size:
        own = kept.own_a is None  # the points' own blocks from point_cov
        cov[:, :3, :3] = res.point_cov[pa] if own else kept.own_a[row]
        cov[:, 3:, 3:] = res.point_cov[pb] if own else kept.own_b[row]
        cab = kept.cross[row]
        cov[:, :3, 3:] = cab
        cov[:, 3:, :3] = np.swapaxes(cab, 1, 2)
    cov = _identification_blocks(cov, _identification_variance(db))
    return a, res.xyz[pa], res.xyz[pb], cov


def uncertainty_bands(run: AdjustmentRun, db: DatabaseResult,
                      confidence: float = 0.9, **kwargs) -> list:
    """G-band rings of the measured segments of every feature (Shi & Liu 2000).

    Parameters
    ----------
    run : AdjustmentRun
    db : DatabaseResult
    confidence : float
        Probability of the error ellipses (default 90 %).
    **kwargs
        ``n_pairs``, ``n_directions`` of :func:`g_band_batch`.

    Returns
    -------
    list of (int, numpy.ndarray)
        ``(feature index, closed ring (k, 2))`` per segment; the union of a feature's
        rings is its uncertainty band (:mod:`vectoradjust.files.derived_outputs` forms it).
    """
    sb = segment_bands(run, db, confidence, **kwargs)
    return [(int(f), r) for f, r in zip(sb.feature, sb.rings)]
