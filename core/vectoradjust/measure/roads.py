"""Road-aware measurement: the centreline crossing at a junction or a corner vertex.

A database vertex where roads meet (a junction: three or more distinct directions) or
where a road turns sharply (a corner: two directions at most ``180 - min_turn`` degrees
apart) is a point of the real road that images show: the crossing of the centrelines of
its arms. :func:`vertex_arms` finds the arms of every object point from the database
lines; :func:`centreline_crossing` locates each arm's centreline near the prediction by
profiles across the database direction (a matched filter of the road width at stations
along the arm, a straight line through the profile peaks) and intersects the arms' lines
by least squares.

What cannot be measured this way (and is left to the analyst): vertices along a straight
or gently curving road (only the across-road position is defined there), dead ends,
arms hidden by trees, shadows or vehicles, roads whose surface does not contrast with
their surroundings, and junctions of arms closer in direction than ``min_angle``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vectoradjust.measure.geometry import inv2
from vectoradjust.measure.matching import sample

__all__ = ["vertex_arms", "measurable", "RoadSettings", "RoadResult", "centreline_crossing",
           "ROAD_FLAGS"]

#: Failure flags of a road measurement (bits of ``RoadResult.flags``).
ROAD_FLAGS = {
    "few_arms": 1,           # fewer than two arms with a centreline found
    "parallel_arms": 2,      # the arms found are too close in direction
    "low_contrast": 4,       # the road does not stand out of its surroundings
    "poor_fit": 8,           # profile peaks scatter about the arm's line
    "outside_window": 16,    # the crossing lies outside the search window
    "edge": 32,              # profiles leave the chip
}
MAX_ARMS = 4


def vertex_arms(coords: np.ndarray, vertex_feature: np.ndarray, vertex_part: np.ndarray,
                vertex_object: np.ndarray, n_objects: int,
                same_direction_deg: float = 10.0) -> tuple[np.ndarray, np.ndarray]:
    """Directions of the road arms leaving every object point.

    Parameters
    ----------
    coords : numpy.ndarray, shape (nv, 3)
        Vertex coordinates of a line layer, in feature and vertex order.
    vertex_feature, vertex_part : numpy.ndarray of int, shape (nv,)
    vertex_object : numpy.ndarray of int, shape (nv,)
        Object point of each vertex (:class:`adjust.shapepoints.ShapePoints`).
    n_objects : int
    same_direction_deg : float
        Arms closer than this in direction are one arm (a road passing through).

    Returns
    -------
    arms : numpy.ndarray, shape (n_objects, MAX_ARMS, 3)
        Coordinates of the neighbouring vertex along each distinct arm (NaN padding).
    degree : numpy.ndarray of int, shape (n_objects,)
        Number of distinct arms (capped at MAX_ARMS).
    """
    c = np.asarray(coords, float)
    nv = len(c)
    same = np.zeros(max(nv - 1, 0), bool)
    if nv > 1:
        same = (vertex_feature[1:] == vertex_feature[:-1]) & (vertex_part[1:] == vertex_part[:-1])
    k = np.flatnonzero(same)
    obj = np.concatenate([vertex_object[k], vertex_object[k + 1]])
    nb = np.concatenate([c[k + 1], c[k]])
    d = nb[:, :2] - c[np.concatenate([k, k + 1]), :2]
    ang = np.arctan2(d[:, 1], d[:, 0])
    keep = np.hypot(d[:, 0], d[:, 1]) > 0
    obj, nb, ang = obj[keep], nb[keep], ang[keep]
    order = np.lexsort((ang, obj))
    obj, nb, ang = obj[order], nb[order], ang[order]
    first = np.searchsorted(obj, obj, side="left")
    rank = np.arange(len(obj)) - first
    wide = 8
    ok = rank < wide
    pad_ang = np.full((n_objects, wide), np.nan)
    pad_nb = np.full((n_objects, wide, 3), np.nan)
    pad_ang[obj[ok], rank[ok]] = ang[ok]
    pad_nb[obj[ok], rank[ok]] = nb[ok]
    diff = np.abs(np.angle(np.exp(1j * (pad_ang[:, :, None] - pad_ang[:, None, :]))))
    close = diff < np.radians(same_direction_deg)
    earlier = np.tril(np.ones((wide, wide), bool), -1)[None]
    dup = np.any(close & earlier, axis=2)
    valid = np.isfinite(pad_ang) & ~dup
    rk = np.cumsum(valid, axis=1) - 1
    take = valid & (rk < MAX_ARMS)
    arms = np.full((n_objects, MAX_ARMS, 3), np.nan)
    oi, ai = np.nonzero(take)
    arms[oi, rk[oi, ai]] = pad_nb[oi, ai]
    return arms, np.minimum(valid.sum(axis=1), MAX_ARMS)


def measurable(xyz: np.ndarray, arms: np.ndarray, degree: np.ndarray,
               min_turn: float = 30.0) -> np.ndarray:
    """Which object points the road-aware measurement can attempt.

    Junctions (``degree >= 3``) and corners (two arms turning by at least ``min_turn``
    degrees) are measurable; dead ends and vertices along a road are not.
    """
    d = arms[:, :2, :2] - np.asarray(xyz, float)[:, None, :2]
    a = np.arctan2(d[..., 1], d[..., 0])
    between = np.degrees(np.abs(np.angle(np.exp(1j * (a[:, 0] - a[:, 1])))))
    corner = (degree == 2) & np.isfinite(between) & (between <= 180.0 - min_turn)
    return (degree >= 3) | corner


@dataclass
class RoadSettings:
    """Settings of :func:`centreline_crossing` (lengths in pixels unless stated).

    Attributes
    ----------
    stations : int
        Profiles per arm.
    arm_length : float
        Length of the arm examined, in road widths, beyond ``start`` widths from the
        prediction.
    start : float
        First station, in road widths from the prediction (clear of the junction).
    search : float
        Half length of each profile (pixels; the across-road search range).
    min_angle : float
        Smallest angle (degrees) between two arms used for the crossing.
    min_contrast : float
        Smallest matched-filter response relative to the chip's grey-value spread.
    max_rms : float
        Largest RMS (pixels) of the profile peaks about an arm's line.
    """

    stations: int = 9
    arm_length: float = 3.0
    start: float = 1.0
    search: float = 20.0
    min_angle: float = 25.0
    min_contrast: float = 0.3
    max_rms: float = 1.0


@dataclass
class RoadResult:
    """Centreline crossings.

    Attributes
    ----------
    px : numpy.ndarray, shape (n, 2)
        Image (column, row) of the crossing (NaN where not found).
    arms_used : numpy.ndarray of int, shape (n,)
    rms : numpy.ndarray, shape (n,)
        RMS of the profile peaks about their arms' lines (pixels).
    flags : numpy.ndarray of int, shape (n,)
        Bits of :data:`ROAD_FLAGS`; 0 = accepted.
    """

    px: np.ndarray
    arms_used: np.ndarray
    rms: np.ndarray
    flags: np.ndarray


def centreline_crossing(chips: np.ndarray, origin: np.ndarray, pred: np.ndarray,
                        arm_dirs: np.ndarray, width_px: np.ndarray,
                        settings: RoadSettings | None = None) -> RoadResult:
    """Locate the crossing of the arms' centrelines near each prediction.

    Parameters
    ----------
    chips : numpy.ndarray, shape (n, H, W)
        Image chips around the predictions (NaN outside the image).
    origin : numpy.ndarray, shape (n, 2)
        Image (column, row) of each chip's pixel (0, 0).
    pred : numpy.ndarray, shape (n, 2)
        Predicted image (column, row) of the vertex.
    arm_dirs : numpy.ndarray, shape (n, K, 2)
        Image directions of the arms (from the database lines projected into the
        image); NaN for absent arms.
    width_px : numpy.ndarray, shape (n,)
        Road width in pixels.
    settings : RoadSettings, optional

    Returns
    -------
    RoadResult
    """
    st = settings or RoadSettings()
    n, k = arm_dirs.shape[:2]
    w = np.maximum(np.asarray(width_px, float), 2.0)
    dirs = arm_dirs / np.linalg.norm(arm_dirs, axis=2, keepdims=True)
    nrm = np.stack([-dirs[..., 1], dirs[..., 0]], axis=-1)
    frac = np.linspace(0.0, 1.0, st.stations)
    s = w[:, None] * (st.start + st.arm_length * frac)[None, :]            # (n, ns)
    step = 0.5
    half = st.search + 2.0 * w.max()
    o = np.arange(-half, half + step / 2, step)
    loc = np.asarray(pred, float) - np.asarray(origin, float)
    base = loc[:, None, None, :] + s[:, None, :, None] * dirs[:, :, None, :]  # (n,K,ns,2)
    pts = base[:, :, :, None, :] + o[None, None, None, :, None] * nrm[:, :, None, None, :]
    prof = sample(chips, pts[..., 0], pts[..., 1])                           # (n,K,ns,no)
    resp, centre_ok = _matched_filter(prof, o, w, step, st.search)
    spread = np.nanstd(chips.reshape(n, -1), axis=1)
    peak, height = _profile_peaks(resp, centre_ok, o, step)
    contrast = np.nanmedian(np.where(np.isfinite(height), height, np.nan), axis=2) / spread[:, None]
    a, b, rms, used = _arm_lines(peak, s, st.max_rms)
    armok = (np.isfinite(a) & (used >= 4) & (np.nan_to_num(contrast) >= st.min_contrast)
             & (rms <= st.max_rms))
    px, lam_min, narms = _intersect(loc, dirs, nrm, a, b, armok)
    flags = np.zeros(n, np.int64)
    flags[narms < 2] |= ROAD_FLAGS["few_arms"]
    flags[(narms >= 2) & ~(lam_min >= 1.0 - np.cos(np.radians(st.min_angle)))] |= \
        ROAD_FLAGS["parallel_arms"]
    valid_arm = np.isfinite(dirs[..., 0])
    low = valid_arm & ~(np.nan_to_num(contrast) >= st.min_contrast)
    flags[np.any(low, axis=1) & (narms < 2)] |= ROAD_FLAGS["low_contrast"]
    badfit = valid_arm & np.isfinite(rms) & (rms > st.max_rms)
    flags[np.any(badfit, axis=1) & (narms < 2)] |= ROAD_FLAGS["poor_fit"]
    nan_prof = np.any(~np.isfinite(prof) & valid_arm[:, :, None, None], axis=(1, 2, 3))
    flags[nan_prof] |= ROAD_FLAGS["edge"]
    far = np.hypot(*(px - loc).T) > st.search
    flags[np.nan_to_num(far, nan=True)] |= ROAD_FLAGS["outside_window"]
    use = armok & np.isfinite(rms) if n else np.zeros((0, 1), bool)  # no usable arm: NaN
    mean_rms = np.where(use, np.nan_to_num(rms), 0.0).sum(axis=1) / np.where(
        use.any(axis=1), use.sum(axis=1), np.nan) if n else np.zeros(0)
    out = np.where((flags == 0)[:, None], px + np.asarray(origin, float), np.nan)
    return RoadResult(out, narms, mean_rms, flags)


def _matched_filter(prof, o, w, step, search):
    """Road-minus-verges response at every profile sample (zero-mean box of the width)."""
    n = prof.shape[0]
    hw = np.maximum(np.round(w / 2.0 / step).astype(int), 1)          # half width, samples
    filled = np.where(np.isfinite(prof), prof, 0.0)
    cs = np.concatenate([np.zeros(prof.shape[:-1] + (1,)), np.cumsum(filled, axis=-1)], -1)
    cn = np.concatenate([np.zeros(prof.shape[:-1] + (1,)),
                         np.cumsum(np.isfinite(prof), axis=-1)], -1)
    no = prof.shape[-1]
    i = np.arange(no)[None, :]
    h = hw[:, None]
    shape = (n, 1, 1, no)

    def box(lo, hi):
        lo = np.clip(lo, 0, no).reshape(shape)
        hi = np.clip(hi, 0, no).reshape(shape)
        lo_b = np.broadcast_to(lo, prof.shape[:-1] + (no,))
        hi_b = np.broadcast_to(hi, prof.shape[:-1] + (no,))
        return (np.take_along_axis(cs, hi_b, -1) - np.take_along_axis(cs, lo_b, -1),
                np.take_along_axis(cn, hi_b, -1) - np.take_along_axis(cn, lo_b, -1))

    s_in, n_in = box(i - h, i + h + 1)
    s_all, n_all = box(i - 2 * h, i + 2 * h + 1)
    full = (2 * h + 1).reshape(n, 1, 1, 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        resp = s_in / n_in - (s_all - s_in) / (n_all - n_in)
    ok = (n_in == full) & (n_all == (4 * h + 1).reshape(n, 1, 1, 1))
    ok &= (np.abs(o) <= search)[None, None, None, :]
    return np.where(ok, resp, np.nan), ok


def _profile_peaks(resp, ok, o, step):
    """Offset of the strongest response (sign chosen per arm) per station, sub-sample."""
    cnt = ok.sum(axis=2)
    mean = np.where(cnt > 0, np.where(ok, resp, 0.0).sum(axis=2) / np.maximum(cnt, 1), np.nan)
    with np.errstate(invalid="ignore"):
        hi = np.nanmax(np.nan_to_num(mean, nan=-np.inf), axis=-1)
        lo = np.nanmin(np.nan_to_num(mean, nan=np.inf), axis=-1)
    sign = np.where(np.abs(hi) >= np.abs(lo), 1.0, -1.0)
    r = np.where(ok, resp * sign[..., None, None], -np.inf)
    j = np.argmax(r, axis=-1)
    f0 = np.take_along_axis(r, j[..., None], -1)[..., 0]
    no = r.shape[-1]
    fm = np.take_along_axis(r, np.clip(j - 1, 0, no - 1)[..., None], -1)[..., 0]
    fp = np.take_along_axis(r, np.clip(j + 1, 0, no - 1)[..., None], -1)[..., 0]
    with np.errstate(invalid="ignore", divide="ignore"):  # -inf outside the image
        den = fm - 2 * f0 + fp
        good = np.isfinite(den) & (den < 0)
        d = np.where(good, 0.5 * (fm - fp) / np.where(good, den, 1.0), 0.0)
    peak = o[j] + np.clip(d, -0.5, 0.5) * step
    valid = np.isfinite(f0)
    return np.where(valid, peak, np.nan), np.where(valid, f0, np.nan)


def _arm_lines(peak, s, max_rms):
    """``offset = a + b s`` per arm through the profile peaks, one outlier pass."""
    ss = np.broadcast_to(s[:, None, :], peak.shape)
    use = np.isfinite(peak)
    for _ in range(2):
        a, b = _line_fit(ss, peak, use)
        res = peak - (a[..., None] + b[..., None] * ss)
        cnt = np.maximum(use.sum(-1), 1)
        rms = np.sqrt(np.nansum(np.where(use, res * res, 0.0), -1) / cnt)
        use = use & (np.abs(np.nan_to_num(res, nan=np.inf)) <= np.maximum(2.5 * rms, max_rms)
                     [..., None])
    a, b = _line_fit(ss, peak, use)
    res = peak - (a[..., None] + b[..., None] * ss)
    cnt = use.sum(-1)
    rms = np.sqrt(np.nansum(np.where(use, res * res, 0.0), -1) / np.maximum(cnt - 2, 1))
    return a, b, rms, cnt


def _line_fit(x, y, use):
    w = use.astype(float)
    x = np.where(use, x, 0.0)
    y = np.where(use, y, 0.0)
    sw, sx, sy = w.sum(-1), (w * x).sum(-1), (w * y).sum(-1)
    sxx, sxy = (w * x * x).sum(-1), (w * x * y).sum(-1)
    det = sw * sxx - sx * sx
    with np.errstate(invalid="ignore", divide="ignore"):
        b = np.where(det > 0, (sw * sxy - sx * sy) / det, np.nan)
        a = np.where(det > 0, (sy - b * sx) / np.where(sw > 0, sw, 1), np.nan)
    return a, b


def _intersect(loc, dirs, nrm, a, b, armok):
    """Least-squares crossing of the arms' lines (chip coordinates)."""
    dirs = np.nan_to_num(dirs)
    nrm = np.nan_to_num(nrm)
    a = np.nan_to_num(a)
    b = np.nan_to_num(b)
    nvec = nrm - b[..., None] * dirs
    nvec /= np.maximum(np.linalg.norm(nvec, axis=-1, keepdims=True), 1e-12)
    p = loc[:, None, :] + a[..., None] * nrm
    wgt = armok.astype(float)[..., None, None]
    m = np.sum(wgt * nvec[..., :, None] * nvec[..., None, :], axis=1)
    rhs = np.sum(wgt[..., 0] * nvec * np.sum(nvec * p, -1)[..., None], axis=1)
    half = 0.5 * (m[:, 0, 0] + m[:, 1, 1])
    lam = half - np.sqrt(0.25 * (m[:, 0, 0] - m[:, 1, 1]) ** 2 + m[:, 0, 1] ** 2)
    narms = armok.sum(axis=1)
    ok = (narms >= 2) & (lam > 1e-6)
    px = np.full(loc.shape, np.nan)
    if ok.any():
        px[ok] = np.einsum("nij,nj->ni", inv2(m[ok]), rhs[ok])
    # normalise the smallest eigenvalue per arm pair: two unit normals give 1 - |cos|
    lam_pair = np.where(narms >= 2, lam * 2.0 / np.maximum(narms, 2), 0.0)
    return px, lam_pair, narms
