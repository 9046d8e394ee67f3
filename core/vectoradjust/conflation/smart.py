"""Smart conflation: adjusted road databases matched feature by feature, the more
accurate feature of each match prevailing (the dissertation's future work, 6.2).

Every database enters as a :class:`FeatureSet`: the features' XY after the adjustment
(one ``(n, 2)`` array per feature, NaN rows between the parts of a multi-line), their
``CE90`` / ``LE90`` and mean adjusted displacement (``RMSE``), and optionally a
normalised name and a class per feature. :func:`match_features` matches two sets one
to one: candidate pairs from a KD-tree of points sampled along the lines, per pair the
mean distances both ways, the symmetric Hausdorff distance and the overlap ratio (the
smaller of the two lines' shares within the pair's maximum distance), a score from the
overlap and the mean distance with a bonus for equal names / classes (never required),
and the Hungarian assignment (:func:`scipy.optimize.linear_sum_assignment`) per
connected group of candidates. :func:`smart_conflate` chains the databases (the first
two matched, their product against the third, ...), picks each match's winner by
:func:`choose` (the smaller CE90; within :data:`TIE_TOLERANCE` the smaller RMSE) and
carries every unmatched feature through.

Only numpy and scipy: the geometry is in coordinate arrays.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from itertools import chain
from typing import Optional

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

__all__ = ["FeatureSet", "Matches", "SmartResult", "TIE_TOLERANCE", "DISTANCE_FACTOR",
           "DISTANCE_FLOOR", "NAME_BONUS", "CLASS_BONUS", "normalise_name", "sample_line",
           "line_distances", "pair_geometry", "default_max_distance", "match_features",
           "choose", "smart_conflate", "summarise"]

#: CE90s (or RMSEs) within this share of the larger one count as equal: the tie-break
#: decides (CE90s of the same identification error differ in the fifth digit)
TIE_TOLERANCE = 0.01
#: the default maximum distance of a pair: this times the larger of the two CE90s (the
#: perpendicular offset of two independent lines has a sigma of at most
#: sqrt(2) CE90 / 2.146 = 0.66 CE90 per axis: 2 CE90 is 3 of those sigmas; 3 CE90 matched
#: a junction's neighbouring stubs and parallel carriageways in validation/
#: smart_conflation.py) ...
DISTANCE_FACTOR = 2.0
#: ... but at least this (m)
DISTANCE_FLOOR = 5.0
#: added to the score of a pair whose normalised names are equal (both named)
NAME_BONUS = 0.1
#: added to the score of a pair whose classes (same attribute) are equal
CLASS_BONUS = 0.05
#: at most this many points sampled along a line
MAX_SAMPLES = 200

_ABBREVIATIONS = {
    "street": "st", "avenue": "ave", "av": "ave", "drive": "dr", "road": "rd",
    "boulevard": "blvd", "lane": "ln", "court": "ct", "place": "pl", "highway": "hwy",
    "parkway": "pkwy", "circle": "cir", "terrace": "ter", "square": "sq", "north": "n",
    "south": "s", "east": "e", "west": "w", "saint": "st",
}


def normalise_name(name) -> Optional[str]:
    """A road name for comparison: lower case, no punctuation, common suffixes and
    directions abbreviated (``"First Street"`` and ``"First St."`` give ``"first st"``).

    Parameters
    ----------
    name : str or None

    Returns
    -------
    str or None
        None for a missing or empty name.
    """
    if name is None or (isinstance(name, float) and not np.isfinite(name)):
        return None
    words = re.findall(r"\w+", str(name).lower())
    if not words:
        return None
    return " ".join(_ABBREVIATIONS.get(w, w) for w in words)


@dataclass
class FeatureSet:
    """The adjusted features of one road database.

    Attributes
    ----------
    name : str
        The database (``Source`` of its winners).
    xy : list of numpy.ndarray
        Per feature an ``(n, 2)`` array of its vertices (NaN rows between parts).
    ce90, le90, rmse : numpy.ndarray, shape (nf,)
        The feature's CE90, LE90 and mean adjusted displacement (m; NaN: unknown).
    names : numpy.ndarray of object, optional
        Normalised names (:func:`normalise_name`; None where unnamed).
    classes : numpy.ndarray of object, optional
        Classes as ``"field=value"`` (equal only within one attribute), None where absent.
    """

    name: str
    xy: list
    ce90: np.ndarray
    le90: np.ndarray
    rmse: np.ndarray
    names: Optional[np.ndarray] = None
    classes: Optional[np.ndarray] = None

    def __post_init__(self) -> None:
        n = len(self.xy)
        self.xy = [np.asarray(a, float).reshape(-1, 2) for a in self.xy]
        for key in ("ce90", "le90", "rmse"):
            v = np.asarray(getattr(self, key), float).reshape(-1)
            if len(v) != n:
                raise ValueError(f"{self.name}: {key} has {len(v)} values for {n} features")
            setattr(self, key, v)
        for key in ("names", "classes"):
            v = getattr(self, key)
            v = np.full(n, None, object) if v is None else np.asarray(v, object).reshape(-1)
            setattr(self, key, v)

    def __len__(self) -> int:
        return len(self.xy)


@dataclass
class Matches:
    """One-to-one matches between two feature sets.

    Attributes
    ----------
    a, b : numpy.ndarray of int
        Matched feature indices of the first and the second set.
    score : numpy.ndarray
        ``MatchScore``: overlap x (1 - mean distance of the overlapping parts / maximum
        distance) x the ends' factor (:func:`_end_factor`, 0.5-1) plus the name / class
        bonus, at most 1.
    mean_distance : numpy.ndarray
        Mean of the two lines' mean distances to each other (m).
    hausdorff : numpy.ndarray
        Symmetric Hausdorff distance (m).
    overlap : numpy.ndarray
        The smaller of the two lines' shares within the maximum distance of the other.
    max_distance : numpy.ndarray
        The pair's maximum distance (m).
    candidates : int
        Candidate pairs examined.
    """

    a: np.ndarray
    b: np.ndarray
    score: np.ndarray
    mean_distance: np.ndarray
    hausdorff: np.ndarray
    overlap: np.ndarray
    max_distance: np.ndarray
    candidates: int = 0


def _segments(xy: np.ndarray) -> np.ndarray:
    """The segments ``(m, 2, 2)`` of a polyline (none across a NaN row)."""
    if len(xy) < 2:
        return np.repeat(xy[:, None, :], 2, axis=1)[np.isfinite(xy).all(axis=1)]
    seg = np.stack([xy[:-1], xy[1:]], axis=1)
    ok = np.isfinite(seg).all(axis=(1, 2))
    if not ok.any():  # single points between NaN rows
        pts = xy[np.isfinite(xy).all(axis=1)]
        return np.repeat(pts[:, None, :], 2, axis=1)
    return seg[ok]


def sample_line(xy: np.ndarray, step: float, max_samples: int = MAX_SAMPLES) -> np.ndarray:
    """Points along a polyline: every vertex plus points at most ``step`` apart on each
    segment (fewer when the line would get more than ``max_samples``).

    Parameters
    ----------
    xy : numpy.ndarray, shape (n, 2)
        Vertices (NaN rows between parts).
    step : float
        Largest spacing of the samples (m).
    max_samples : int

    Returns
    -------
    numpy.ndarray, shape (k, 2)
    """
    seg = _segments(np.asarray(xy, float))
    if not len(seg):
        return np.empty((0, 2))
    length = np.hypot(*(seg[:, 1] - seg[:, 0]).T)
    total = float(length.sum())
    if total > 0 and total / step > max_samples:
        step = total / max_samples
    n = np.maximum(np.ceil(length / max(step, 1e-9)).astype(int), 1)
    t = np.concatenate([np.arange(k) / k for k in n])
    s = np.repeat(np.arange(len(seg)), n)
    pts = seg[s, 0] + t[:, None] * (seg[s, 1] - seg[s, 0])
    return np.vstack([pts, seg[-1:, 1]])


def line_distances(points: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Each point's distance to the polyline ``xy`` (its nearest segment).

    Parameters
    ----------
    points : numpy.ndarray, shape (p, 2)
    xy : numpy.ndarray, shape (n, 2)
        Vertices (NaN rows between parts).

    Returns
    -------
    numpy.ndarray, shape (p,)
        Infinite where the line has no vertex.
    """
    seg = _segments(np.asarray(xy, float))
    points = np.asarray(points, float).reshape(-1, 2)
    if not len(seg):
        return np.full(len(points), np.inf)
    a, d = seg[:, 0], seg[:, 1] - seg[:, 0]
    dd = np.einsum("ij,ij->i", d, d)
    rel = points[:, None, :] - a[None, :, :]
    t = np.clip(np.einsum("pmi,mi->pm", rel, d) / np.where(dd > 0, dd, 1.0), 0.0, 1.0)
    diff = rel - t[..., None] * d[None, :, :]
    return np.sqrt(np.einsum("pmi,pmi->pm", diff, diff).min(axis=1))


def pair_geometry(sa: np.ndarray, xa: np.ndarray, sb: np.ndarray, xb: np.ndarray,
                  max_distance: float) -> tuple:
    """Mean distance, Hausdorff distance and overlap of two lines.

    Parameters
    ----------
    sa, sb : numpy.ndarray, shape (k, 2)
        Points sampled along the lines (:func:`sample_line`).
    xa, xb : numpy.ndarray, shape (n, 2)
        The lines' vertices.
    max_distance : float
        A sample within this distance of the other line overlaps it (m).

    Returns
    -------
    tuple of float
        ``(mean distance, Hausdorff distance, overlap, mean distance of the overlapping
        samples)``; the mean distance is the mean of both directions' means, the overlap
        the smaller of the two lines' overlapping shares.
    """
    dab, dba = line_distances(sa, xb), line_distances(sb, xa)
    if not len(dab) or not len(dba):
        return np.inf, np.inf, 0.0, np.inf
    mean = 0.5 * (dab.mean() + dba.mean())
    haus = max(dab.max(), dba.max())
    ia, ib = dab <= max_distance, dba <= max_distance
    overlap = min(ia.mean(), ib.mean())
    both = np.concatenate([dab[ia], dba[ib]])
    return float(mean), float(haus), float(overlap), float(both.mean()) if len(both) else np.inf


def default_max_distance(ce_a, ce_b, factor: float = DISTANCE_FACTOR,
                         floor: float = DISTANCE_FLOOR) -> np.ndarray:
    """The default maximum distance of a pair: ``factor`` times the larger CE90, at
    least ``floor`` (NaN CE90s count as 0).

    Parameters
    ----------
    ce_a, ce_b : array_like
        The two features' CE90 (m).
    factor, floor : float

    Returns
    -------
    numpy.ndarray
    """
    ce = np.fmax(np.nan_to_num(np.asarray(ce_a, float)), np.nan_to_num(np.asarray(ce_b, float)))
    return np.maximum(factor * ce, floor)


def _samples(fs: FeatureSet, step: float) -> list:
    return [sample_line(x, step) for x in fs.xy]


def _candidates(sa: list, sb: list, radius_a: np.ndarray, radius_b: np.ndarray) -> set:
    """Feature pairs with a sample of one within the radius of a sample of the other
    (KD-trees of both sets' samples, each side's query with its own radii)."""
    codes = []
    n_b = max(len(sb), 1)
    for s_q, r_q, s_t, flip in ((sa, radius_a, sb, False), (sb, radius_b, sa, True)):
        own = np.repeat(np.arange(len(s_q)), [len(s) for s in s_q])
        other = np.repeat(np.arange(len(s_t)), [len(s) for s in s_t])
        if not len(own) or not len(other):
            return set()
        tree = cKDTree(np.vstack(s_t))
        pts, rad = np.vstack(s_q), r_q[own]
        for r in np.unique(rad):
            k = np.flatnonzero(rad == r)
            hits = tree.query_ball_point(pts[k], r)
            lens = np.fromiter(map(len, hits), np.int64, len(hits))
            flat = np.fromiter(chain.from_iterable(hits), np.int64, int(lens.sum()))
            i, j = np.repeat(own[k], lens), other[flat]
            a_idx, b_idx = (j, i) if flip else (i, j)
            codes.append(np.unique(a_idx * n_b + b_idx))
    both = np.unique(np.concatenate(codes)) if codes else np.zeros(0, np.int64)
    return set(zip((both // n_b).tolist(), (both % n_b).tolist()))


def _bonus(a: FeatureSet, b: FeatureSet, i: int, j: int) -> float:
    bonus = 0.0
    if a.names[i] is not None and a.names[i] == b.names[j]:
        bonus += NAME_BONUS
    if a.classes[i] is not None and a.classes[i] == b.classes[j]:
        bonus += CLASS_BONUS
    return bonus


def _end_factor(xa: np.ndarray, xb: np.ndarray, dmax: float) -> float:
    """``1 - min(e / dmax, 1) / 2`` with ``e`` the mean distance of the lines' ends
    (first to first and last to last, or crosswise, the smaller): two lines of the
    same road piece end at the same places, a neighbour of a missing piece does not
    (a match of different segmentations keeps half its score)."""
    fa, fb = xa[np.isfinite(xa).all(axis=1)], xb[np.isfinite(xb).all(axis=1)]
    if not len(fa) or not len(fb):
        return 0.5
    a0, a1, b0, b1 = fa[0], fa[-1], fb[0], fb[-1]
    e = 0.5 * min(np.hypot(*(a0 - b0)) + np.hypot(*(a1 - b1)),
                  np.hypot(*(a0 - b1)) + np.hypot(*(a1 - b0)))
    return 1.0 - 0.5 * min(e / dmax, 1.0)


def _assign(pairs: list, scores: np.ndarray, na: int, nb: int) -> np.ndarray:
    """Indices into ``pairs`` of the one-to-one assignment with the largest total score:
    the Hungarian method per connected group of candidate pairs."""
    if not pairs:
        return np.empty(0, np.int64)
    ia = np.array([p[0] for p in pairs])
    ib = np.array([p[1] for p in pairs])
    graph = coo_matrix((np.ones(len(pairs)), (ia, na + ib)), shape=(na + nb, na + nb))
    _, label = connected_components(graph, directed=False)
    chosen = []
    group = label[ia]
    for g in np.unique(group):
        k = np.flatnonzero(group == g)
        ua, ra = np.unique(ia[k], return_inverse=True)
        ub, rb = np.unique(ib[k], return_inverse=True)
        cost = np.zeros((len(ua), len(ub)))
        index = np.full((len(ua), len(ub)), -1)
        cost[ra, rb], index[ra, rb] = -scores[k], k
        rows, cols = linear_sum_assignment(cost)
        chosen.extend(int(index[r, c]) for r, c in zip(rows, cols) if index[r, c] >= 0)
    return np.sort(np.array(chosen, np.int64))


def match_features(a: FeatureSet, b: FeatureSet, max_distance: Optional[float] = None,
                   min_overlap: float = 0.5) -> Matches:
    """Match the features of two sets one to one by their geometry (names and classes
    as a bonus).

    Parameters
    ----------
    a, b : FeatureSet
    max_distance : float, optional
        The largest distance at which two lines overlap (m); default per pair
        :func:`default_max_distance` of the two CE90s.
    min_overlap : float
        Pairs whose overlap (:func:`pair_geometry`) is smaller are not candidates.

    Returns
    -------
    Matches
    """
    if max_distance is not None:
        rad_a = np.full(len(a), float(max_distance))
        rad_b = np.full(len(b), float(max_distance))
    else:
        rad_a = default_max_distance(a.ce90, np.nanmax(np.append(b.ce90, 0.0)))
        rad_b = default_max_distance(b.ce90, np.nanmax(np.append(a.ce90, 0.0)))
    step = 0.5 * float(min(rad_a.min(initial=np.inf), rad_b.min(initial=np.inf), 1e9))
    sa, sb = _samples(a, step), _samples(b, step)
    pairs, rows = [], []
    for i, j in sorted(_candidates(sa, sb, rad_a + step, rad_b + step)):
        dmax = (float(max_distance) if max_distance is not None
                else float(default_max_distance(a.ce90[i], b.ce90[j])))
        mean, haus, overlap, near = pair_geometry(sa[i], a.xy[i], sb[j], b.xy[j], dmax)
        if overlap < min_overlap or overlap <= 0:
            continue
        ends = _end_factor(a.xy[i], b.xy[j], dmax)
        score = min(overlap * max(1.0 - near / dmax, 0.0) * ends + _bonus(a, b, i, j), 1.0)
        pairs.append((i, j))
        rows.append((score, mean, haus, overlap, dmax))
    v = np.array(rows, float).reshape(-1, 5)
    k = _assign(pairs, v[:, 0], len(a), len(b))
    p = np.array(pairs, np.int64).reshape(-1, 2)[k]
    return Matches(p[:, 0], p[:, 1], v[k, 0], v[k, 1], v[k, 2], v[k, 3], v[k, 4],
                   candidates=len(rows))


def choose(ce_a, rmse_a, ce_b, rmse_b, by: str = "ce90",
           tie: float = TIE_TOLERANCE) -> np.ndarray:
    """Whether the first feature of each pair prevails.

    The smaller uncertainty wins: ``by="ce90"`` compares the CE90s and, where they are
    equal within ``tie`` of the larger, the mean adjusted displacements (RMSE);
    ``by="rmse"`` the other way round. Where both are equal (or unknown) the first wins.

    Parameters
    ----------
    ce_a, rmse_a, ce_b, rmse_b : array_like
    by : {"ce90", "rmse"}
    tie : float
        Relative tolerance of equality.

    Returns
    -------
    numpy.ndarray of bool
    """
    if by not in ("ce90", "rmse"):
        raise ValueError(f"by={by!r}: 'ce90' or 'rmse'")
    keys = ((ce_a, ce_b), (rmse_a, rmse_b)) if by == "ce90" else ((rmse_a, rmse_b),
                                                                   (ce_a, ce_b))
    out = np.ones(np.broadcast(*keys[0]).shape, bool)
    decided = np.zeros(out.shape, bool)
    for x, y in keys:
        x, y = np.asarray(x, float), np.asarray(y, float)
        known_x, known_y = np.isfinite(x), np.isfinite(y)
        big = np.where(known_x & known_y, np.fmax(x, y), 0.0)
        gap = np.abs(np.where(known_x & known_y, x - y, 0.0))
        differ = np.where(known_x & known_y, gap > tie * big, known_x != known_y)
        xx, yy = np.where(known_x, x, np.inf), np.where(known_y, y, np.inf)
        now = differ & ~decided
        out[now] = (xx < yy)[now]
        decided |= now
    return out


@dataclass
class SmartResult:
    """The conflated product: one row per output feature.

    Attributes
    ----------
    sets : list of FeatureSet
        The inputs, in the order of the chain.
    source : numpy.ndarray of int
        Index into ``sets`` of each row's winner.
    feature : numpy.ndarray of int
        The winner's feature index in its set.
    losers : list of list of tuple
        Per row the ``(set, feature)`` of the features it prevailed over.
    score : numpy.ndarray
        ``MatchScore`` (the weakest match of the row's chain; NaN: unmatched).
    loser_offset : numpy.ndarray
        Mean distance of the losers' lines to the winner's (m; NaN: unmatched).
    """

    sets: list
    source: np.ndarray
    feature: np.ndarray
    losers: list
    score: np.ndarray
    loser_offset: np.ndarray = field(default_factory=lambda: np.empty(0))

    def column(self, key: str) -> np.ndarray:
        """The winners' ``ce90``, ``le90`` or ``rmse`` per row."""
        return np.array([getattr(self.sets[s], key)[f] for s, f in zip(self.source,
                                                                         self.feature)])

    def loser_values(self, key: str) -> np.ndarray:
        """The smallest ``ce90``, ``le90`` or ``rmse`` of each row's losers (NaN: none)."""
        out = np.full(len(self.source), np.nan)
        for row, ls in enumerate(self.losers):
            v = [getattr(self.sets[s], key)[f] for s, f in ls]
            if v and np.isfinite(v).any():
                out[row] = np.nanmin(v)
        return out

    def loser_names(self) -> list:
        """Per row the losers' database names, comma separated (``""``: none)."""
        return [",".join(self.sets[s].name for s, _ in ls) for ls in self.losers]


def _product_set(r: SmartResult) -> FeatureSet:
    """The product so far as a feature set (the winners' lines and values)."""
    xy = [r.sets[s].xy[f] for s, f in zip(r.source, r.feature)]
    names = [r.sets[s].names[f] for s, f in zip(r.source, r.feature)]
    classes = [r.sets[s].classes[f] for s, f in zip(r.source, r.feature)]
    return FeatureSet("product", xy, r.column("ce90"), r.column("le90"), r.column("rmse"),
                      np.array(names, object), np.array(classes, object))


def _merge(r: SmartResult, k: int, m: Matches, by: str, tie: float) -> SmartResult:
    """The product ``r`` merged with set ``k`` by the matches ``m`` (product = a)."""
    new = r.sets[k]
    p = _product_set(r)
    wins = choose(p.ce90[m.a], p.rmse[m.a], new.ce90[m.b], new.rmse[m.b], by, tie)
    source, feature = r.source.copy(), r.feature.copy()
    losers = [list(ls) for ls in r.losers]
    score = r.score.copy()
    for row, j, w, s in zip(m.a, m.b, wins, m.score):
        if w:
            losers[row].append((k, int(j)))
        else:
            losers[row].insert(0, (int(source[row]), int(feature[row])))
            source[row], feature[row] = k, j
        score[row] = np.fmin(score[row], s) if np.isfinite(score[row]) else s
    rest = np.setdiff1d(np.arange(len(new)), m.b)
    return SmartResult(r.sets, np.append(source, np.full(len(rest), k)),
                       np.append(feature, rest), losers + [[] for _ in rest],
                       np.append(score, np.full(len(rest), np.nan)))


def _loser_offsets(r: SmartResult, step: float) -> np.ndarray:
    out = np.full(len(r.source), np.nan)
    for row, ls in enumerate(r.losers):
        if not ls:
            continue
        win = r.sets[r.source[row]].xy[r.feature[row]]
        d = [line_distances(sample_line(r.sets[s].xy[f], step), win) for s, f in ls]
        out[row] = float(np.mean([x.mean() for x in d if len(x)])) if d else np.nan
    return out


def smart_conflate(sets: Sequence[FeatureSet], max_distance: Optional[float] = None,
                   min_overlap: float = 0.5, by: str = "ce90", tie: float = TIE_TOLERANCE,
                   progress=None) -> tuple:
    """Conflate two or more adjusted databases feature by feature.

    The first two sets are matched (:func:`match_features`), each match's winner chosen
    (:func:`choose`), unmatched features of both carried through; the product is then
    matched against the third set, and so on.

    Parameters
    ----------
    sets : sequence of FeatureSet
        At least two.
    max_distance, min_overlap :
        See :func:`match_features`.
    by, tie :
        See :func:`choose`.
    progress : callable, optional
        ``progress(done, total)`` after each set.

    Returns
    -------
    tuple
        ``(SmartResult, list of Matches)``: the product and the matches of each step.
    """
    sets = list(sets)
    if len(sets) < 2:
        raise ValueError("smart conflation needs at least two feature sets")
    n0 = len(sets[0])
    r = SmartResult(sets, np.zeros(n0, np.int64), np.arange(n0), [[] for _ in range(n0)],
                    np.full(n0, np.nan))
    steps = []
    for k in range(1, len(sets)):
        m = match_features(_product_set(r), sets[k], max_distance, min_overlap)
        steps.append(m)
        r = _merge(r, k, m, by, tie)
        if progress is not None:
            progress(k, len(sets) - 1)
    step = 0.5 * (max_distance if max_distance is not None else DISTANCE_FLOOR)
    r.loser_offset = _loser_offsets(r, step)
    return r, steps


def summarise(r: SmartResult) -> dict:
    """The summary of a conflation: per database its features, how many were matched
    and unmatched, its wins and the mean CE90 of its features in the product.

    Parameters
    ----------
    r : SmartResult

    Returns
    -------
    dict
        ``{"features": n, "matched": rows with a loser, "databases": {name: {...}}}``.
    """
    ce = r.column("ce90")
    matched_rows = np.array([bool(ls) for ls in r.losers])
    dbs: dict = {}
    for k, s in enumerate(r.sets):
        in_match = np.zeros(len(s), bool)
        for row, ls in enumerate(r.losers):
            if ls and r.source[row] == k:
                in_match[r.feature[row]] = True
            for sk, f in ls:
                if sk == k:
                    in_match[f] = True
        mine = r.source == k
        ce_k = ce[mine]
        dbs[s.name] = {
            "features": len(s), "matched": int(in_match.sum()),
            "unmatched": int(len(s) - in_match.sum()),
            "wins": int((mine & matched_rows).sum()), "rows": int(mine.sum()),
            "mean_ce90": float(np.nanmean(ce_k)) if np.isfinite(ce_k).any() else None,
            "mean_ce90_input": (float(np.nanmean(s.ce90)) if np.isfinite(s.ce90).any()
                                else None),
        }
    return {"features": int(len(r.source)), "matched": int(matched_rows.sum()),
            "unmatched": int((~matched_rows).sum()), "databases": dbs,
            "mean_ce90": float(np.nanmean(ce)) if np.isfinite(ce).any() else None}
