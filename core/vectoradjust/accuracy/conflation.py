"""Conflation: correct every vertex of a road database by least-squares collocation.

DESIGN section 10: a database vertex is ``X_db = X_true + T_db + s(x) + e_db``. The
adjustment measures some vertices; their displacement ``d = X_hat - X_db`` is the
negative of the database error, seen through the measurement noise (the adjusted point's
covariance and the identification error). This module predicts the displacement at
every other vertex

    d(x) = t(x) + c_xm (C_mm + N)^-1 (d_m - t_m)

with the trend ``t`` the database's estimated systematic offset (``-G(x) T``,
:mod:`vectoradjust.adjust.offsets`; a constant mean for axes the offset model does not
cover, applied only where it is significant), ``C(r)`` a covariance function
(exponential or Gaussian) and ``N = diag(n_db + D_i)`` the white noise: the database's
own random error ``n_db`` plus the measured point's variance ``D_i`` (the images' share
of its covariance plus the identification variance). ``C0``, ``L`` and ``n_db`` are the
parameters whose leave-one-out predictions of the measured points score best (the
negative log predictive density, a proper scoring rule, :func:`fit_covariance`); the
semivariogram's least-squares fit gives the start; ``n_db`` is then taken as its mean
given the data (flat prior, :func:`_nugget_posterior`). The measured
displacement is taken as the images see it (:func:`image_only`): the adjusted shape
point is pulled towards the database by its prior, which would shrink the field.
The variance of the real vertex's position error is
``C(0) - c_xm (C_mm + N)^-1 c_mx + n_db + Var(t(x))`` (the unmeasured vertex carries
its own database noise ``n_db``; the trend's variance from the joint covariance of the
adjusted points, :func:`_mean_variance`). The horizontal CE90 is that of the predictive
distribution, the normal mixed over the distributions of the estimated ``n_db`` and
``C0`` (:func:`ce90_factor`; the sill with the database's stated variance as its prior,
:func:`_sill_prior`, which carries the vertices far from measured patches); the sigmas
are the plug-in ones.

Only the ``k`` nearest measured points enter each prediction (a KD-tree; the ``k x k``
systems are solved batch-wise with :func:`numpy.linalg.solve`), so the cost is linear
in the number of vertices. Horizontal (X and Y share one covariance function) and
vertical are separate fields. Numpy and scipy only.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Callable, Optional

import numpy as np

from vectoradjust.errors import CancelledError, ProjectError

__all__ = ["ConflationSettings", "CovarianceModel", "settings_from_table", "fit_covariance",
           "empirical_semivariogram", "krige", "cross_validate", "image_only", "FieldModel",
           "field_grid", "ce90_factor",
           "conflate_database", "conflate_run", "SOURCES", "CONFLATION_KEYS",
           "CE90_CIRCULAR", "LE90", "band_coverage", "DISTANCE_BANDS", "SILL_PRIOR_DOF"]

#: the ``Source`` values of a vertex
SOURCES = ("measured", "interpolated", "extrapolated", "unchanged")
#: keys of the project's ``[conflation]`` table
CONFLATION_KEYS = ("enabled", "k", "max_distance", "model", "min_points")
#: CE90 / sigma of a circular normal error, sqrt(-2 ln 0.1)
CE90_CIRCULAR = float(np.sqrt(-2.0 * np.log(0.1)))
#: LE90 / sigma of a normal error, Phi^-1(0.95)
LE90 = 1.6448536269514722
_MODELS = ("auto", "exponential", "gaussian")
#: degrees of freedom of the database's stated variance as the sill's prior
#: (:func:`_sill_prior`): known to about +-50 % (``sqrt(2 / 8)``)
SILL_PRIOR_DOF = 8.0


@dataclass
class ConflationSettings:
    """The project's ``[conflation]`` table.

    Attributes
    ----------
    enabled : bool
        Correct the unmeasured vertices (default true).
    k : int
        Measured points per prediction (nearest neighbours).
    max_distance : float
        A vertex farther than this (m) from every measured point, or outside their
        convex hull, is ``extrapolated``, else ``interpolated``; 0 (default): the fitted
        covariance's practical range.
    model : str
        ``"exponential"`` (``C0 exp(-r/L)``), ``"gaussian"`` (``C0 exp(-(r/L)^2)``) or
        ``"auto"`` (default: both fitted, the better leave-one-out score kept).
    min_points : int
        Fewest measured points a database needs for its field (fewer: ``unchanged``).
    """

    enabled: bool = True
    k: int = 12
    max_distance: float = 0.0
    model: str = "auto"
    min_points: int = 5


def settings_from_table(table: Optional[dict], source: str = "<project>") -> ConflationSettings:
    """Validate a ``[conflation]`` table (None: the defaults).

    Raises
    ------
    ProjectError
        Naming the key and the allowed values.
    """
    s = ConflationSettings()
    if not table:
        return s
    unknown = [k for k in table if k not in CONFLATION_KEYS]
    if unknown:
        raise ProjectError(f"{source}: [conflation] has no key {unknown[0]!r}",
                           f"Use only: {', '.join(CONFLATION_KEYS)}", path=source)

    def bad(key, what):
        return ProjectError(f"{source}: [conflation] {key} = {table[key]!r} is not {what}",
                            f"Write {key} as {what} (README: [conflation])", path=source)

    if "enabled" in table:
        if not isinstance(table["enabled"], bool):
            raise bad("enabled", "true or false")
        s.enabled = table["enabled"]
    for key, low in (("k", 1), ("min_points", 2)):
        if key in table:
            v = table[key]
            if isinstance(v, bool) or not isinstance(v, int) or v < low:
                raise bad(key, f"an integer >= {low}")
            setattr(s, key, int(v))
    if "max_distance" in table:
        v = table["max_distance"]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not v >= 0:
            raise bad("max_distance", "a distance >= 0 in metres")
        s.max_distance = float(v)
    if "model" in table:
        if table["model"] not in _MODELS:
            raise bad("model", " or ".join(repr(m) for m in _MODELS))
        s.model = table["model"]
    return s


@dataclass
class CovarianceModel:
    """An isotropic covariance function plus white noise, per component.

    Attributes
    ----------
    kind : str
        ``"exponential"`` or ``"gaussian"``.
    sill : float
        ``C0`` (m^2), the correlated signal's variance.
    length : float
        ``L`` (m).
    nugget : float
        White database noise ``n_db`` (m^2) in the kriging system and in every
        predicted vertex's variance (:func:`fit_covariance`).
    known_noise : float
        Mean variance of the measured points (adjustment + identification), m^2.
    fit : dict
        The empirical semivariogram and the fit's status.
    nugget_posterior : tuple of numpy.ndarray, optional
        ``(x, w)``: the distribution of ``n_db / nugget`` given the data (values and
        weights summing to 1, mean 1; :func:`_nugget_posterior`); None: ``nugget`` is
        taken as known.
    sill_dof : float
        Degrees of freedom of the sill's estimate (:func:`_sill_dof`; inf: known).
        With ``nugget_posterior`` they make the CE90 that of the predictive
        distribution (:func:`ce90_factor`).
    sill_prior : tuple, optional
        ``(S0, nu0)``: the database's stated variance of its field (m^2) and its degrees
        of freedom, the sill's prior in the CE90 (:func:`_sill_prior`,
        :func:`_ce90_table`); None: the estimate alone.
    """

    kind: str
    sill: float
    length: float
    nugget: float
    known_noise: float = 0.0
    fit: dict = field(default_factory=dict)
    nugget_posterior: Optional[tuple] = None
    sill_dof: float = float("inf")
    sill_prior: Optional[tuple] = None
    _table: Optional[np.ndarray] = field(default=None, init=False, repr=False, compare=False)

    def __call__(self, r: np.ndarray) -> np.ndarray:
        """``C(r)`` of the signal (no nugget)."""
        if self.sill <= 0 or self.length <= 0:
            return np.zeros_like(np.asarray(r, float))
        u = np.asarray(r, float) / self.length
        return self.sill * (np.exp(-u) if self.kind == "exponential" else np.exp(-u * u))

    @property
    def practical_range(self) -> float:
        """Distance at which the correlation falls to 5 %."""
        return float(self.length * (3.0 if self.kind == "exponential" else np.sqrt(3.0)))

    def as_dict(self) -> dict:
        """JSON-ready description."""
        return {"model": self.kind, "sill": float(self.sill), "length": float(self.length),
                "practical_range": self.practical_range, "nugget": float(self.nugget),
                "known_noise": float(self.known_noise), **self.fit,
                "nugget_sd": (float(self.nugget * np.sqrt(np.sum(self.nugget_posterior[1] * (
                    self.nugget_posterior[0] - 1.0) ** 2))) if self.nugget_posterior else 0.0),
                "sill_dof": float(self.sill_dof) if np.isfinite(self.sill_dof) else None,
                "sill_prior": (None if self.sill_prior is None else
                               {"variance": float(self.sill_prior[0]),
                                "dof": float(self.sill_prior[1])})}


def empirical_semivariogram(xy: np.ndarray, resid: np.ndarray, n_bins: int = 15,
                            max_points: int = 2000, seed: int = 0):
    """Binned semivariogram ``gamma(h) = mean (r_i - r_j)^2 / 2`` of the residuals.

    Parameters
    ----------
    xy : numpy.ndarray, shape (n, 2)
    resid : numpy.ndarray, shape (n, c)
        Residuals; the components share one semivariogram (averaged).
    n_bins : int
        Bins up to half the largest distance: one below the 1st percentile of the
        distances, the others geometrically spaced above it.
    max_points : int
        A random subset of this many points is used when there are more.
    seed : int

    Returns
    -------
    lag, gamma, count : numpy.ndarray
        Mean distance, semivariance and number of pairs per bin.
    """
    from scipy.spatial.distance import pdist

    n = len(xy)
    if n > max_points:
        pick = np.random.default_rng(seed).choice(n, max_points, replace=False)
        xy, resid = xy[pick], resid[pick]
    h = pdist(xy)
    g = np.mean([pdist(resid[:, [c]], "sqeuclidean") for c in range(resid.shape[1])],
                axis=0) / 2.0
    keep = (h > 0) & (h <= 0.5 * h.max(initial=0.0))
    h, g = h[keep], g[keep]
    if h.size < n_bins:
        return h, g, np.ones(h.size)
    # geometric bins from the 1st percentile of the distances: the short lags, which
    # carry the nugget and the field's behaviour near zero, get bins of their own
    h0 = max(float(np.quantile(h, 0.01)), 1e-6)
    edges = np.r_[0.0, np.geomspace(h0, h.max() * (1 + 1e-9), n_bins)]
    b = np.clip(np.searchsorted(edges, h, side="right") - 1, 0, n_bins - 1)
    count = np.bincount(b, minlength=n_bins).astype(float)
    ok = count > 0
    lag = np.bincount(b, weights=h, minlength=n_bins)[ok] / count[ok]
    gam = np.bincount(b, weights=g, minlength=n_bins)[ok] / count[ok]
    return lag, gam, count[ok]


def fit_covariance(xy: np.ndarray, resid: np.ndarray, known_noise: np.ndarray,
                   kind: str = "auto", k: int = 12, max_targets: int = 1000,
                   corr: Optional[np.ndarray] = None) -> CovarianceModel:
    """Fit the covariance function and the database's white noise to the residuals.

    Two steps. (1) Weighted least squares on the empirical semivariogram,
    ``gamma(h) = nugget + C0 (1 - rho(h / L))`` with the nugget at least the mean known
    noise (start values, and the figures reported). (2) The parameters ``(n_db, C0, L)``
    that minimise the leave-one-out negative log predictive density of the measured
    points (:func:`_loo_score`; each held out point predicted from its ``k`` nearest
    others, exactly as a vertex is predicted, its known noise ``known_noise`` entering its
    own variance): a proper scoring rule, so the predicted variances are calibrated on
    the data rather than on a curve fit that cannot tell the database's white noise from
    a steep rise of the semivariogram at the shortest lags. With ``kind = "auto"`` both
    functions are fitted and the one with the better score is kept. The score's
    gradient is in closed form (:func:`_loo_score_grad`), so a quasi-Newton search
    (:func:`_projected_bfgs`) needs 15-30 scores where a derivative-free one needed
    several hundred; its result is put on a fixed lattice (:func:`_lattice_min`) so
    that QGIS's numpy gives the same model. ``n_db`` is then replaced by its mean given
    the data (:func:`_nugget_posterior`, every nugget from one eigendecomposition,
    :func:`_nugget_scores`), and the sill's degrees of freedom are estimated
    (:func:`_sill_dof`): the CE90 of a predicted vertex accounts for both parameters'
    uncertainty (:func:`ce90_factor`). On the sample project and the conflation
    simulation the chosen models are those of the former Nelder-Mead search, at a
    fifth of its time (issue 32, benchmarks/README.md).

    Parameters
    ----------
    xy : numpy.ndarray, shape (n, 2)
        Measured points.
    resid : numpy.ndarray, shape (n, c)
        Their displacements less the trend.
    known_noise : numpy.ndarray, shape (n,)
        Each point's known noise variance per component (m^2).
    kind : str
        ``"exponential"``, ``"gaussian"`` or ``"auto"``.
    k : int
        Neighbours per leave-one-out prediction (the ``[conflation] k``).
    max_targets : int
        The score is summed over at most this many held-out points (a random subset,
        seeded: the same points every run; all points serve as neighbours), so a
        score costs the same from ``max_targets`` measured points on.
    corr : numpy.ndarray, shape (n, r), optional
        The points' noise shared with each other: covariance ``corr corr'`` (part of
        ``known_noise`` on the diagonal), e.g. the images' height error through their
        orientation (:func:`_orientation_basis`); a field must not take it for the
        database's.

    Returns
    -------
    CovarianceModel
        Without enough pairs for a semivariogram a pure nugget model (no correlated
        signal). ``fit`` holds the semivariogram, its least-squares fit and the score.
    """
    noise_pt = np.asarray(known_noise, float)
    noise = float(np.mean(noise_pt)) if len(noise_pt) else 0.0
    total = float(np.mean(resid ** 2)) if resid.size else 0.0
    lag, gam, cnt = empirical_semivariogram(xy, resid)
    fit = {"lags": lag.tolist(), "semivariance": gam.tolist(), "pairs": cnt.astype(int).tolist()}
    if lag.size < 4 or len(xy) < 4:
        return CovarianceModel(kind if kind in ("exponential", "gaussian") else "exponential",
                               0.0, 0.0, max(total - noise, 0.0), noise,
                               {**fit, "status": "too few pairs: white noise only"})
    # the measured points' own noise is part of the nugget: it cannot be smaller
    floor = min(noise, 0.999 * float(gam.max()))
    setup = _loo_setup(xy, k, max_targets, corr=corr)
    scale = max(total, float(gam.max()), 1e-12)
    best = None
    fits = {}
    for kd in (("exponential", "gaussian") if kind == "auto" else (kind,)):
        nug, sill, length = _fit_grid(lag, gam, cnt, kd, floor)
        start = (max(nug - noise, 0.05 * scale), max(sill, 0.05 * scale),
                 length if sill > 0 else float(np.median(lag)))
        theta, score = _fit_loo(kd, setup, resid, noise_pt, start, scale, lag)
        wls = fits[kd] = {"nugget": nug, "sill": sill, "length": length}
        if best is None or score < best[2]:
            best = (kd, theta, score, wls)
    kd, theta, score, wls = best
    white = _fit_white(kd, setup, resid, noise_pt, scale)
    status = "fitted"
    if white[1] <= score + 4.0:  # a signal must earn its two parameters (AIC)
        theta, score, status = np.array([white[0], 0.0, 0.0]), white[1], "white noise (AIC)"
        # no signal: its shape does not matter, and the near-tie between the two shapes'
        # scores must not make the label depend on the platform's rounding
        kd = "exponential" if kind == "auto" else kd
        wls = fits[kd]
    nug, post = _nugget_posterior(theta, kd, setup, resid, noise_pt)
    model = CovarianceModel(kd, float(theta[1]), float(theta[2]), nug, noise,
                            {**fit, "status": status, "fitted_nugget": wls["nugget"],
                             "semivariogram_fit": wls, "loo_score": score,
                             "loo_score_white": white[1], "nugget_best": float(theta[0]),
                             "loo_targets": int(len(setup[0]))}, post)
    model.sill_dof = _sill_dof(model, xy, resid.shape[1])
    return model


def _nonneg_pair(f: np.ndarray, g: np.ndarray, w: np.ndarray):
    """Per row: ``a, b >= 0`` minimising ``sum w (g - a - b f)^2`` (the KKT candidates)."""
    sw, sf, sff = w.sum(1), (w * f).sum(1), (w * f * f).sum(1)
    sg, sfg = (w * g).sum(1), (w * f * g).sum(1)
    det = sw * sff - sf * sf
    with np.errstate(invalid="ignore", divide="ignore"):
        cands = [((sff * sg - sf * sfg) / det, (sw * sfg - sf * sg) / det),  # both free
                 (np.zeros_like(sw), np.maximum(sfg / sff, 0.0)),            # a = 0
                 (np.maximum(sg / sw, 0.0), np.zeros_like(sw))]             # b = 0
    best_a, best_b = cands[2]
    best = ((g - best_a[:, None]) ** 2 * w).sum(1)
    for a, b in cands[:2]:
        ok = np.isfinite(a) & np.isfinite(b) & (a >= 0) & (b >= 0)
        a, b = np.where(ok, a, 0.0), np.where(ok, b, 0.0)
        sse = np.where(ok, ((g - a[:, None] - b[:, None] * f) ** 2 * w).sum(1), np.inf)
        better = sse < best
        best_a, best_b, best = (np.where(better, a, best_a), np.where(better, b, best_b),
                                np.where(better, sse, best))
    return best_a, best_b, best


def _fit_grid(lag, gam, cnt, kind: str, floor: float, n_lengths: int = 241):
    """``(nugget, sill, length)`` of the semivariogram model, weighted least squares.

    For each length on a geometric grid the model is linear in the nugget (>= floor)
    and the sill (>= 0) and solved exactly; the best length wins. Cressie's weights
    ``N_h / gamma(h)^2`` (the short lags count as much as the long ones), with the
    model of the previous round, four rounds. No iterative optimiser: the same data
    give the same model on every platform (QGIS's numpy and scipy included).
    """
    lengths = np.geomspace(lag[0] / 10.0, lag[-1] * 10.0, n_lengths)
    u = lag[None, :] / lengths[:, None]
    f = 1.0 - (np.exp(-u) if kind == "exponential" else np.exp(-u * u))
    g = np.broadcast_to(gam - floor, f.shape)
    model = np.maximum(gam, 1e-12 * max(float(gam.max()), 1e-300))
    for _ in range(4):
        w = np.broadcast_to(cnt / model ** 2, f.shape)
        a, b, sse = _nonneg_pair(f, g, w)
        i = int(np.argmin(sse))
        model = np.maximum(floor + a[i] + b[i] * f[i], 1e-12 * max(float(gam.max()), 1e-300))
    return float(floor + a[i]), float(b[i]), float(lengths[i])


def _neighbours(tree, xy: np.ndarray, k: int, skip_self: bool):
    """Distances and indices (b, k) of the k nearest measured points."""
    kk = k + 1 if skip_self else k
    dist, idx = tree.query(xy, k=kk)
    dist = np.asarray(dist, float).reshape(len(xy), kk)
    idx = np.asarray(idx).reshape(len(xy), kk)
    if skip_self:
        return dist[:, 1:], idx[:, 1:]
    return dist, idx


def _system(cov: CovarianceModel, dd, dist, noise_nb, u_nb=None, u_tgt=None, signal=None):
    """Kriging matrix (b, k, k) and right side (b, k) of ``k`` neighbours.

    ``C(dd) + diag(n_db + noise)`` against ``C(dist)``; with ``u_nb`` (b, k, r) the
    neighbours' noise is correlated, ``u u'`` (the images' shared error, e.g. of their
    orientation; ``noise`` holds each point's whole variance, so the diagonal keeps it),
    and a target that is itself a measured point (leave-one-out; ``u_tgt`` (b, r))
    shares it with them: the right side gains ``u_nb u_tgt``. ``signal``: ``(C(dd),
    C(dist))`` when the caller has them already (not modified).
    """
    diag = np.arange(dd.shape[1])
    a = cov(dd) if signal is None else signal[0].copy()
    c = cov(dist) if signal is None else signal[1]
    if u_nb is None:
        a[:, diag, diag] += cov.nugget + noise_nb
        return a, c
    own = np.einsum("bkr,bkr->bk", u_nb, u_nb)
    a += np.matmul(u_nb, np.swapaxes(u_nb, 1, 2))
    a[:, diag, diag] += cov.nugget + np.maximum(noise_nb - own, 0.0)
    if u_tgt is not None:
        c = c + np.einsum("bkr,br->bk", u_nb, u_tgt)
    return a, c


def _loo_setup(xy: np.ndarray, k: int, max_targets: int, seed: int = 0, corr=None):
    """Targets (a random subset of at most ``max_targets`` points), their ``k`` nearest
    other points (all points serve as neighbours) and the distances: fixed while the
    parameters of :func:`_loo_score` change."""
    from scipy.spatial import cKDTree

    n = len(xy)
    tgt = np.arange(n)
    if n > max_targets:
        tgt = np.sort(np.random.default_rng(seed).choice(n, max_targets, replace=False))
    k = int(min(k, n - 1))
    dist, idx = _neighbours(cKDTree(xy), xy[tgt], k, skip_self=True)
    px, py = xy[idx, 0], xy[idx, 1]
    dd = np.hypot(px[:, :, None] - px[:, None, :], py[:, :, None] - py[:, None, :])
    return tgt, dist, idx, dd, corr


def _loo_score(theta, kind: str, setup, resid: np.ndarray, noise: np.ndarray) -> float:
    """Negative leave-one-out log predictive density (per component, constants dropped)
    of ``theta = (nugget_db, sill, length)``: ``sum log s2 + e^2 / s2`` with ``e`` the
    held-out point's error and ``s2`` its predicted variance (kriging variance + database
    noise + the point's own noise; with ``corr`` in ``setup`` the noise shared with the
    neighbours, :func:`_system`)."""
    tgt, dist, idx, dd, corr = setup
    cov = CovarianceModel(kind, theta[1], theta[2], theta[0])
    a, c = _system(cov, dd, dist, noise[idx], None if corr is None else corr[idx],
                   None if corr is None else corr[tgt])
    try:
        w = np.linalg.solve(a, c[:, :, None])[:, :, 0]
    except np.linalg.LinAlgError:  # a singular system: no admissible parameters
        return float("inf")
    e = resid[tgt] - np.einsum("bk,bkc->bc", w, resid[idx])
    sig = cov.sill - np.einsum("bk,bk->b", w, c)
    s2 = (np.maximum(sig, 0.0) if corr is None else sig) + cov.nugget + noise[tgt]
    if not np.all(s2 > 0):  # a perfect prediction claimed: not admissible
        return float("inf")
    return float(np.sum(resid.shape[1] * np.log(s2) + (e ** 2).sum(axis=1) / s2))


def _loo_score_grad(x, kind: str, setup, resid: np.ndarray, noise: np.ndarray):
    """:func:`_loo_score` of ``theta = exp(x)`` and its gradient in ``x`` (the
    logarithms of nugget, sill and length), in closed form: one batched solve.

    With ``w = A^-1 c`` the held-out point's weights, ``e`` its error and ``s2`` its
    variance, the score's derivative is ``sum alpha ds2 + g' dw`` with ``alpha = c/s2 -
    |e|^2/s2^2`` and ``g = -alpha c - 2 R e / s2`` (``R`` the neighbours' residuals);
    ``dw = A^-1 (dc - dA w)``, so ``lambda = A^-1 g`` (``A`` symmetric) gives every
    parameter's share ``lambda' (dc - dA w)`` (the adjoint). ``lambda = -alpha w - 2
    (A^-1 R) e / s2`` comes from the same solve as ``w`` (right sides ``c`` and ``R``).
    ``(inf, 0)`` where the score is inf.
    """
    theta = np.exp(np.asarray(x, float))
    tgt, dist, idx, dd, corr = setup
    cov = CovarianceModel(kind, theta[1], theta[2], theta[0])
    s_dd, s_dist = cov(dd), cov(dist)  # the signal's share of a and c: d/d log sill
    a, c = _system(cov, dd, dist, noise[idx], None if corr is None else corr[idx],
                   None if corr is None else corr[tgt], signal=(s_dd, s_dist))
    r_nb = resid[idx]
    try:  # the weights and A^-1 R together: one factorisation
        sol = np.linalg.solve(a, np.concatenate([c[:, :, None], r_nb], axis=2))
    except np.linalg.LinAlgError:
        return float("inf"), np.zeros(3)
    w, a_r = sol[:, :, 0], sol[:, :, 1:]
    e = resid[tgt] - np.matmul(w[:, None, :], r_nb)[:, 0, :]
    sig = cov.sill - (w * c).sum(axis=1)
    live = np.ones_like(sig) if corr is not None else (sig > 0).astype(float)
    s2 = sig * live + cov.nugget + noise[tgt]
    if not np.all(s2 > 0):
        return float("inf"), np.zeros(3)
    m = resid.shape[1]
    e2 = (e ** 2).sum(axis=1)
    score = float(np.sum(m * np.log(s2) + e2 / s2))
    alpha = m / s2 - e2 / s2 ** 2
    # lambda = A^-1 g with g = -alpha c - 2 R e / s2, from the solution above
    lam = -(alpha * live)[:, None] * w - (2.0 / s2)[:, None] * np.matmul(a_r, e[:, :, None])[..., 0]
    u_dd, u_dist = dd / theta[2], dist / theta[2]
    h_dd, h_dist = ((u_dd, u_dist) if kind == "exponential" else (2 * u_dd ** 2, 2 * u_dist ** 2))
    grad = np.zeros(3)
    grad[0] = theta[0] * float(np.sum(alpha - (lam * w).sum(axis=1)))
    for j, (da, dc) in ((1, (s_dd, s_dist)), (2, (s_dd * h_dd, s_dist * h_dist))):
        direct = (theta[1] if j == 1 else 0.0) * live - live * (w * dc).sum(axis=1)
        da_w = np.matmul(da, w[:, :, None])[:, :, 0]
        grad[j] = float(np.sum(alpha * direct) + np.sum(lam * (dc - da_w)))
    return score, grad


def _fit_loo(kind: str, setup, resid, noise, start, scale: float, lags):
    """``(nugget_db, sill, length), score`` minimising :func:`_loo_score` (bounded
    quasi-Newton, L-BFGS-B on the logarithms from ``start``, with the closed-form
    gradient of :func:`_loo_score_grad`; then polished on a lattice).

    Nugget and sill lie between ``1e-6 scale`` and ``2 scale`` (``scale``: the larger of
    the residuals' mean square and the largest semivariance), the length between a
    tenth of the shortest and twice the longest lag of the semivariogram. Predictions
    from the nearest points see the field near the origin only (for the exponential
    function ``C0 / L``): sill and length are not told apart beyond the data's extent,
    and without these bounds a field could grow a sill and a range it never showed.
    About 15-30 scores with their gradients instead of the several hundred of a
    derivative-free search (issue 32).
    """
    floor = 1e-6 * scale
    lo = np.array([np.log(floor)] * 2 + [np.log(lags[0] / 10.0)])
    hi = np.array([np.log(2 * scale)] * 2 + [np.log(lags[-1] * 2.0)])
    x0 = np.clip(np.log(np.maximum(np.asarray(start, float), floor)), lo, hi)

    def f(x):
        return _loo_score(np.exp(x), kind, setup, resid, noise)

    x1 = _projected_bfgs(lambda x: _loo_score_grad(x, kind, setup, resid, noise), x0, lo, hi)
    x, fx = _lattice_min(f, x1, lo, hi, max_moves=1)
    theta = np.exp(x)
    theta[:2] = np.where(theta[:2] <= 10 * floor, 0.0, theta[:2])
    if theta[1] == 0.0:  # no signal: the length means nothing (a plateau); white noise
        theta[2] = 0.0
        fx = _loo_score(theta, kind, setup, resid, noise)
    return theta, fx


def _projected_bfgs(fg, x0, lo, hi, max_iter: int = 60, xtol: float = 1e-3,
                    ftol: float = 1e-4, max_step: float = 1.0):
    """Minimise ``f`` in the box ``[lo, hi]`` from ``x0``: BFGS on the free variables
    (``fg(x) = (f, gradient)``), steps projected onto the box, backtracking (Armijo).

    A few dozen evaluations for the three logarithmic parameters of :func:`_fit_loo`;
    stops when a step moves every coordinate by less than ``xtol`` or ``f`` no longer
    decreases. A variable at a bound whose gradient pushes outwards stays there.
    """
    x = np.clip(np.asarray(x0, float), lo, hi)
    fx, g = fg(x)
    if not np.isfinite(fx):
        return x
    h, first, gamma, was = np.eye(len(x)), True, 1.0, np.zeros(len(x), bool)
    for _ in range(max_iter):
        fixed = ((x <= lo) & (g > 0)) | ((x >= hi) & (g < 0))
        if np.any(fixed != was):  # another active set: forget the curvature across it
            h, was = np.eye(len(x)) * gamma, fixed
        hf = np.where(fixed[:, None] | fixed[None, :], 0.0, h)
        d = -hf @ np.where(fixed, 0.0, g)
        if not g @ d < 0:  # not a descent direction: restart from steepest descent
            h, d = np.eye(len(x)) * gamma, -gamma * np.where(fixed, 0.0, g)
        t, moved = min(1.0, max_step / max(float(np.max(np.abs(d))), 1e-300)), False
        for _ in range(30):
            xn = np.clip(x + t * d, lo, hi)
            fn, gn = fg(xn)
            if np.isfinite(fn) and fn <= fx + 1e-4 * (g @ (xn - x)):
                moved = True
                break
            t *= 0.3
        if not moved:
            break
        sv, yv = xn - x, gn - g
        x, done = xn, (np.max(np.abs(sv)) < xtol or fx - fn < ftol)
        fx, g = fn, gn
        if done:
            break
        sy = float(sv @ yv)
        if sy > 1e-12:
            if first:  # the first step sets the scale of the inverse Hessian
                gamma, first = sy / float(yv @ yv), False
                h = np.eye(len(x)) * gamma
            rho = 1.0 / sy
            v = np.eye(len(x)) - rho * np.outer(sv, yv)
            h = v @ h @ v.T + rho * np.outer(sv, sv)
    return x


def _lattice_min(f, x, lo, hi, step: float = 0.05, max_moves: int = 200):
    """Polish a minimum on the fixed lattice ``step * Z^3`` (logarithms: 5 %).

    The optimiser's path depends on the last bits of its sums, which differ between
    numpy builds (QGIS's and the command line's); ending on the lattice (the best of
    the rounded optimum and its 6 neighbours along the axes, repeated up to
    ``max_moves`` times while a neighbour is really better) gives both the same
    parameters. :func:`_fit_loo` makes one such move: its quasi-Newton optimum is
    converged, and further moves only creep along the flat ridge of sill and length
    (differences of the score far below its own uncertainty).
    """
    lo_i, hi_i = np.ceil(lo / step - 1e-9), np.floor(hi / step + 1e-9)
    cur = np.clip(np.round(np.asarray(x) / step), lo_i, hi_i)
    seen: dict = {}

    def val(i):
        key = tuple(int(v) for v in i)
        if key not in seen:
            seen[key] = f(np.asarray(i, float) * step)
        return seen[key]

    moves = np.vstack([np.eye(3), -np.eye(3)])
    best = val(cur)
    for _ in range(max_moves):
        cand = [np.clip(cur + m, lo_i, hi_i) for m in moves]
        vals = [val(c) for c in cand]
        j = int(np.argmin(vals))
        if not vals[j] < best - 1e-9 * max(abs(best), 1.0):
            break
        cur, best = cand[j], vals[j]
    return cur * step, float(best)


def _fit_white(kind: str, setup, resid, noise, scale: float):
    """The white-noise-only model (no signal): ``n_db`` minimising :func:`_loo_score`
    on a logarithmic grid (one parameter) and its score. Without shared noise the
    held-out point's prediction is 0 and the score is closed-form (400 values); with it
    the neighbours still predict the shared part (:func:`_loo_score`, 71 values)."""
    if setup[4] is not None:
        grid = np.geomspace(1e-6 * scale, 10 * scale, 71)
        sc = _nugget_scores((0.0, 0.0, 0.0), kind, setup, resid, noise)(grid)
        i = int(np.argmin(sc))
        return float(grid[i]), float(sc[i])
    grid = np.geomspace(1e-6 * scale, 10 * scale, 400)
    tgt = setup[0]
    r2 = (resid[tgt] ** 2).sum(axis=1)
    s2 = grid[:, None] + noise[tgt][None, :]
    sc = np.sum(resid.shape[1] * np.log(s2) + r2[None, :] / s2, axis=1)
    i = int(np.argmin(sc))
    return float(grid[i]), float(sc[i])


def _nugget_scores(theta, kind: str, setup, resid, noise) -> Callable:
    """``scores(grid)``: :func:`_loo_score` of ``(g, theta[1], theta[2])`` for every
    nugget ``g`` of ``grid``, from one eigendecomposition per held-out point.

    The nugget enters the kriging matrix as ``g I`` only, so with ``A0 = V diag(l) V'``
    (the matrix without it) ``(A0 + g I)^-1 = V diag(1 / (l + g)) V'``: every nugget
    costs a few products instead of a solve. inf where a system is singular or a
    variance not positive (as :func:`_loo_score`).
    """
    tgt, dist, idx, dd, corr = setup
    cov = CovarianceModel(kind, theta[1], theta[2], 0.0)
    a, c = _system(cov, dd, dist, noise[idx], None if corr is None else corr[idx],
                   None if corr is None else corr[tgt])
    lam, vec = np.linalg.eigh(a)
    q = np.matmul(c[:, None, :], vec)[:, 0, :]  # V' c
    qp = q[:, :, None] * np.matmul(np.swapaxes(vec, 1, 2), resid[idx])  # (b, k, comp)
    qq = q * q
    tiny = 1e-12 * np.maximum(np.abs(lam).max(axis=1), 1e-300)
    r_t, n_t, m = resid[tgt], noise[tgt], resid.shape[1]

    def scores(grid) -> np.ndarray:
        grid = np.asarray(grid, float)
        den = lam[None, :, :] + grid[:, None, None]  # (grid, b, k)
        singular = np.any(np.abs(den) <= tiny[None, :, None], axis=(1, 2))
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / den
            e = r_t[None] - np.matmul(inv[:, :, None, :], qp[None])[:, :, 0, :]
            sig = cov.sill - (inv * qq[None]).sum(axis=2)
            s2 = (np.maximum(sig, 0.0) if corr is None else sig) + grid[:, None] + n_t[None]
            ok = ~singular & np.all(s2 > 0, axis=1)
            sc = np.sum(m * np.log(s2) + (e ** 2).sum(axis=2) / s2, axis=1)
        return np.where(ok, sc, np.inf)

    return scores


def _nugget_posterior(theta, kind: str, setup, resid, noise, n_grid: int = 41):
    """The database's white noise ``n_db`` as its mean given the data, not its best fit,
    and its distribution given the data ``(x, w)`` (values ``n_db / mean`` with weights,
    None when the likelihood cannot be evaluated or the mean is 0).

    ``n_db`` is the difference of two similar variances (the held-out points' scatter
    and their known noise); its best fit is often 0 (the boundary) where the truth is a
    few cm^2, and a vertex's variance built on it is too small. With a flat prior on
    ``n_db >= 0`` and the leave-one-out likelihood ``exp(-score / 2)`` (the signal's
    parameters fixed at their fit), the mean of ``n_db`` is the variance a prediction
    should carry for it. The grid runs from 0 to where the likelihood has fallen by
    ``e^-10`` (found on two coarse grids), ``n_grid`` values.
    """
    tgt = setup[0]

    scores = _nugget_scores(theta, kind, setup, resid, noise)

    hi = float(theta[0]) + max(float(np.mean((resid[tgt] ** 2).sum(axis=1)
                                             / resid.shape[1])), 1e-12)
    for _ in range(2):  # narrow the range to where the likelihood is
        grid = np.linspace(0.0, hi, 21)
        sc = scores(grid)
        if not np.isfinite(sc).any():
            return float(theta[0]), None
        i = int(np.nanargmin(sc))
        above = np.flatnonzero((sc - sc[i] > 20.0) & (np.arange(21) > i))
        if not above.size:
            break
        hi = float(grid[above[0]])
    grid = np.linspace(0.0, hi, n_grid)
    sc = scores(grid)
    w = np.exp(-(sc - np.nanmin(sc)) / 2.0)
    w[~np.isfinite(w)] = 0.0
    w = w / np.sum(w)
    mean = float(np.sum(w * grid))
    keep = w > 1e-9
    return mean, ((grid[keep] / mean, w[keep] / w[keep].sum()) if mean > 0 else None)


def _sill_dof(cov: CovarianceModel, xy: np.ndarray, n_comp: int, max_points: int = 1500,
              seed: int = 0) -> float:
    """Degrees of freedom ``nu`` of the sill's estimate: ``Var(C0_hat) = 2 C0^2 / nu``.

    The field's variance is seen through one realisation at ``m`` correlated places per
    component: the mean square of the field's values there varies from realisation to
    realisation by ``2 tr(C^2) / (c m^2)`` (``C`` the fitted signal covariance between
    the points, ``c`` components), so ``nu = c m^2 C0^2 / tr(C^2)``: ``c m`` for
    uncorrelated values, between ``c`` and a few ``c`` where the measured points span
    only a few correlation lengths (the patches of the field that the data saw). The
    noise's share of the sill's error is left out: a signal is kept only when it beats
    white noise by the AIC margin (:func:`fit_covariance`), and with it ``nu`` stays at
    least ``c``. The pair sum is taken on a random subset of at most ``max_points``
    points (scaled by the number of pairs). Inf without a signal.
    """
    m = len(xy)
    if cov.sill <= 0 or cov.length <= 0 or m < 2:
        return float("inf")
    from scipy.spatial.distance import pdist

    pick = (np.sort(np.random.default_rng(seed).choice(m, max_points, replace=False))
            if m > max_points else np.arange(m))
    ns = len(pick)
    off = 2.0 * float(np.sum(cov(pdist(xy[pick])) ** 2)) * m * (m - 1) / (ns * (ns - 1))
    return float(n_comp * m * m * cov.sill ** 2 / (m * cov.sill ** 2 + off))


def _variance_nodes(nu: float, n: int = 16):
    """Nodes and weights of ``X = nu / chi2_nu`` (the posterior of a variance with ``nu``
    degrees of freedom relative to its estimate): generalised Gauss-Laguerre on the
    chi-square density for ``nu < 30``, Gauss-Hermite on the Wilson-Hilferty cube for
    larger ``nu``, ``X = 1`` for ``nu`` inf."""
    if not np.isfinite(nu) or nu > 1e6:
        return np.ones(1), np.ones(1)
    if nu < 30:
        from scipy.special import roots_genlaguerre

        y, w = roots_genlaguerre(n, nu / 2.0 - 1.0)  # chi2 = 2 y, y ~ Gamma(nu / 2)
        return nu / (2.0 * y), w / w.sum()
    z, w = np.polynomial.hermite_e.hermegauss(n)
    c = 2.0 / (9.0 * nu)
    return 1.0 / np.maximum(1.0 - c + z * np.sqrt(c), 1e-3) ** 3, w / w.sum()


def _gauss_rule(x: np.ndarray, w: np.ndarray, n: int = 8):
    """An ``n``-point Gauss rule of the discrete distribution ``(x, w)`` (Stieltjes'
    procedure, Golub-Welsch): it integrates polynomials of degree ``2 n - 1`` exactly,
    with ``n`` nodes instead of all of ``x``."""
    x, w = np.asarray(x, float), np.asarray(w, float) / np.sum(w)
    n = int(min(n, len(x)))
    alpha, beta = np.zeros(n), np.zeros(n)
    p_prev, p = np.zeros_like(x), np.ones_like(x)
    norm_prev = 1.0
    for k in range(n):
        norm = float(np.sum(w * p * p))
        if norm <= 1e-300:
            n = k
            break
        alpha[k] = float(np.sum(w * x * p * p)) / norm
        beta[k] = norm / norm_prev if k else 0.0
        p_prev, p = p, (x - alpha[k]) * p - beta[k] * p_prev
        norm_prev = norm
    jac = np.diag(alpha[:n]) + np.diag(np.sqrt(beta[1:n]), 1) + np.diag(np.sqrt(beta[1:n]), -1)
    nodes, vec = np.linalg.eigh(jac)
    return nodes, vec[0] ** 2


def _ce90_table(cov: CovarianceModel, n_grid: int = 33) -> np.ndarray:
    """``kappa(f_s, f_n)`` on a ``n_grid x n_grid`` lattice of ``[0, 1]^2``: the CE90 of
    the predictive distribution over that of the plug-in normal (:func:`ce90_factor`).

    A vertex's variance ``V`` is made of the signal's part ``f_s V`` (proportional to
    the sill), the database noise's ``f_n V`` and a known rest; the predictive
    distribution of its circular error is the normal's mixed over the parameters'
    distributions, ``P(R > r) = E exp(-r^2 / (2 V (f_t + f_s X_s + f_n X_n)))`` with
    ``X_s = nu / chi2_nu`` (:func:`_variance_nodes`; the Student-t construction) and
    ``X_n`` the database noise's distribution given the data
    (``cov.nugget_posterior``, as an 8-point Gauss rule, :func:`_gauss_rule`). With
    ``cov.sill_prior = (S0, nu0)`` (the database's stated variance, :func:`_sill_prior`)
    the sill's distribution is the posterior of the conjugate prior, ``X_s = q nu' /
    chi2_nu'`` with ``nu' = nu + nu0`` and ``q = (nu C0 + nu0 S0) / (nu' C0)``: it
    matters only where ``nu`` is a few (the sill seen on a few patches). ``r`` solves
    ``P = 0.1`` by Newton's method on ``log r^2``, safeguarded by bisection in the
    bracket of the smallest and the largest mixed variance. Lattice points with
    ``f_s + f_n > 1`` take the value of ``(f_s, f_n) / (f_s + f_n)``.
    """
    xs, ws = _variance_nodes(cov.sill_dof if cov.sill > 0 else float("inf"))
    if cov.sill_prior is not None and cov.sill > 0 and np.isfinite(cov.sill_dof):
        # the prior's scale and degrees of freedom join the estimate's (conjugate
        # scaled inverse chi-square): X_s = r nu' / chi2_nu'
        (s0, nu0), nu = cov.sill_prior, cov.sill_dof
        xs, ws = _variance_nodes(nu + nu0)
        xs = xs * (nu * cov.sill + nu0 * s0) / ((nu + nu0) * cov.sill)
    xn, wn = (_gauss_rule(*cov.nugget_posterior) if cov.nugget_posterior is not None
              else (np.ones(1), np.ones(1)))
    f = np.linspace(0.0, 1.0, n_grid)
    fs, fn = np.meshgrid(f, f, indexing="ij")
    tot = np.maximum(fs + fn, 1.0)
    fs, fn = (fs / tot).ravel(), (fn / tot).ravel()
    ft = np.maximum(1.0 - fs - fn, 0.0)
    a = np.maximum(ft[:, None, None] + fs[:, None, None] * xs[None, :, None]
                   + fn[:, None, None] * xn[None, None, :], 1e-12).reshape(len(fs), -1)
    w = (ws[:, None] * wn[None, :]).ravel()
    rho0 = np.log(10.0)
    # log r^2 / (2 V) between the all-small and the all-large case; Newton's steps on
    # the logarithm, bisection where a step leaves the bracket
    lo, hi = np.log(rho0 * a.min(axis=1)), np.log(rho0 * a.max(axis=1))
    x = np.full(len(a), np.log(rho0))
    x = np.clip(x, lo, hi)
    live = np.arange(len(a))  # the lattice points still iterating
    for _ in range(200):
        xl, al = x[live], a[live]
        rho = np.exp(xl)
        e = np.exp(-rho[:, None] / al)
        h = e @ w - 0.1
        lo[live], hi[live] = np.where(h > 0, xl, lo[live]), np.where(h > 0, hi[live], xl)
        slope = -rho * ((e / al) @ w)
        with np.errstate(divide="ignore", invalid="ignore"):
            new = xl - h / slope
        bad = ~((new > lo[live]) & (new < hi[live]))
        new = np.where(bad, 0.5 * (lo[live] + hi[live]), new)
        x[live] = new
        live = live[np.abs(new - xl) >= 1e-13]
        if not live.size:
            break
    rho = np.exp(x)
    return np.sqrt(rho / rho0).reshape(n_grid, n_grid)


def ce90_factor(cov: Optional[CovarianceModel], v_signal: np.ndarray, v_noise: np.ndarray,
                v_total: np.ndarray) -> np.ndarray:
    """CE90 of the predictive distribution over the CE90 of the plug-in normal.

    The covariance of a predicted vertex is built on estimated parameters: the
    database noise ``n_db`` (its mean given the data, whose distribution
    ``cov.nugget_posterior`` keeps) and the sill ``C0`` (estimated with
    ``cov.sill_dof`` degrees of freedom). Their uncertainty widens the distribution
    of the vertex's error beyond the normal of the same covariance, most where the
    sill dominates (far from measured points: there the sill is seen on a few
    correlation lengths only). The factor is bilinear in a table of ``(f_s, f_n) =
    (v_signal, v_noise) / v_total`` (:func:`_ce90_table`, once per model).

    Parameters
    ----------
    cov : CovarianceModel or None
        None: 1 everywhere.
    v_signal, v_noise, v_total : numpy.ndarray, shape (n,)
        The parts of a vertex's variance (per axis) that scale with the sill and with
        the database noise, and the whole variance.

    Returns
    -------
    numpy.ndarray, shape (n,)
        At least 1 (1 where ``v_total`` is not positive or not finite).
    """
    v_total = np.asarray(v_total, float)
    out = np.ones(v_total.shape)
    if cov is None:
        return out
    if cov._table is None:
        cov._table = _ce90_table(cov)
    tab = cov._table
    ok = np.isfinite(v_total) & (v_total > 0)
    n = tab.shape[0] - 1
    with np.errstate(invalid="ignore", divide="ignore"):
        fs = np.clip(np.asarray(v_signal, float)[ok] / v_total[ok], 0.0, 1.0) * n
        fn = np.clip(np.asarray(v_noise, float)[ok] / v_total[ok], 0.0, 1.0) * n
    fs, fn = np.nan_to_num(fs), np.nan_to_num(fn)
    i, j = np.minimum(fs.astype(np.int64), n - 1), np.minimum(fn.astype(np.int64), n - 1)
    u, v = fs - i, fn - j
    out[ok] = ((1 - u) * (1 - v) * tab[i, j] + u * (1 - v) * tab[i + 1, j]
               + (1 - u) * v * tab[i, j + 1] + u * v * tab[i + 1, j + 1])
    return np.maximum(out, 1.0)


def _solve_chunk(models: list, xy_m, dist, idx, tgt=None) -> list:
    """Simple kriging of one chunk for each ``(cov, resid, noise[, carry[, u]])`` of
    ``models`` (same measured points and neighbours): prediction (b, c), signal error
    variance (b,) and the kriging weights' sums of ``carry`` (b, f) (None without
    ``carry``). ``u`` (m, r): the measured points' shared noise (:func:`_system`);
    ``tgt`` (b,): the targets' own indices when they are measured points (leave-one-out),
    whose noise is shared with their neighbours (the variance is then relative to
    the held-out point's own noise, which the caller adds)."""
    out = []
    dd = None
    for cov, resid, noise, *rest in models:
        carry = rest[0] if rest else None
        u = rest[1] if len(rest) > 1 else None
        nc = 0 if carry is None else carry.shape[1]
        if cov.sill <= 0 or cov.length <= 0:  # no correlated signal: the trend alone
            out.append((np.zeros((len(idx), resid.shape[1])), np.zeros(len(idx)),
                        None if carry is None else np.zeros((len(idx), nc))))
            continue
        if dd is None:  # the neighbours' distances, once for all models
            px, py = xy_m[idx, 0], xy_m[idx, 1]  # (b, k)
            dd = np.hypot(px[:, :, None] - px[:, None, :], py[:, :, None] - py[:, None, :])
        u_t = None if u is None or tgt is None else u[tgt]
        a, c = _system(cov, dd, dist, noise[idx], None if u is None else u[idx], u_t)
        w = np.linalg.solve(a, c[:, :, None])[:, :, 0]
        sig = cov.sill - np.einsum("bk,bk->b", w, c)
        out.append((np.einsum("bk,bkc->bc", w, resid[idx]),
                    np.maximum(sig, 0.0) if u_t is None else sig,
                    None if carry is None else np.einsum("bk,bkf->bf", w, carry[idx])))
    return out


def krige(cov: CovarianceModel, xy_m: np.ndarray, resid: np.ndarray, noise: np.ndarray,
          xy_p: np.ndarray, k: int, *, skip_self: bool = False, chunk: int = 20000,
          progress: Optional[Callable[[float], None]] = None,
          is_cancelled: Optional[Callable[[], bool]] = None):
    """Predict the residual field at ``xy_p`` from the ``k`` nearest measured points.

    Parameters
    ----------
    cov : CovarianceModel
    xy_m : numpy.ndarray, shape (m, 2)
        Measured points.
    resid : numpy.ndarray, shape (m, c)
        Their residuals (displacement less trend).
    noise : numpy.ndarray, shape (m,)
        Their known noise variance per component.
    xy_p : numpy.ndarray, shape (n, 2)
        Where to predict.
    k : int
        Neighbours (at most ``m``, or ``m - 1`` with ``skip_self``).
    skip_self : bool
        ``xy_p`` are the measured points themselves, each left out of its own
        prediction (leave-one-out).
    chunk : int
        Targets per batched solve (memory ``chunk * k^2`` floats).
    progress, is_cancelled : callable, optional
        ``progress(fraction)`` after each chunk; ``is_cancelled()`` true raises
        :class:`~vectoradjust.errors.CancelledError`.

    Returns
    -------
    pred : numpy.ndarray, shape (n, c)
    var : numpy.ndarray, shape (n,)
        Variance of the signal's prediction error ``C(0) - c' (C + N)^-1 c``.
    nearest : numpy.ndarray, shape (n,)
        Distance to the nearest measured point used.
    """
    (res,), nearest = _krige_many([(cov, resid, noise, None)], xy_m, xy_p, k, skip_self,
                                  chunk, progress, is_cancelled)
    return res[0], res[1], nearest


def _krige_many(models: list, xy_m, xy_p, k: int, skip_self: bool = False,
                chunk: int = 20000, progress=None, is_cancelled=None):
    """:func:`krige` for several ``(cov, resid, noise[, carry])`` on the same measured
    points: one KD-tree query and one distance matrix per chunk. ``carry`` (m, f), per
    measured point, is summed with the kriging weights (the trend's design, whose error
    the prediction carries only by ``G(x) - sum w_i G(x_i)``, :func:`_trend_cov`).
    Returns ``[(pred, var, wsum)], nearest`` (``wsum`` None without ``carry``)."""
    from scipy.spatial import cKDTree

    n = len(xy_p)
    k = int(min(k, len(xy_m) - (1 if skip_self else 0)))
    out = [(np.zeros((n, m[1].shape[1])), np.full(n, float(m[0].sill)),
            None if len(m) < 4 or m[3] is None else np.zeros((n, m[3].shape[1])))
           for m in models]
    nearest = np.full(n, np.inf)
    if n == 0 or k < 1:
        return out, nearest
    tree = cKDTree(xy_m)
    for s in range(0, n, chunk):
        if is_cancelled is not None and is_cancelled():
            raise CancelledError("The conflation was cancelled", "Run it again when ready")
        e = min(s + chunk, n)
        dist, idx = _neighbours(tree, xy_p[s:e], k, skip_self)
        tgt = np.arange(s, e) if skip_self else None
        for (pred, var, ws), (p, v, w) in zip(out, _solve_chunk(models, xy_m, dist, idx, tgt)):
            pred[s:e], var[s:e] = p, v
            if ws is not None:
                ws[s:e] = w
        nearest[s:e] = dist[:, 0]
        if progress is not None:
            progress(e / n)
    return out, nearest


def cross_validate(cov: CovarianceModel, xy_m: np.ndarray, resid: np.ndarray,
                   noise: np.ndarray, k: int, factor: float) -> dict:
    """Leave-one-out cross-validation of the field at the measured points.

    Each measured point is predicted from its ``k`` nearest other measured points and
    compared with its own (noisy) residual; the error's predicted variance is the
    kriging variance plus the database noise plus the point's own noise.

    Parameters
    ----------
    factor : float
        Radius (LE90 or CE90 factor) of the predicted sigma the share is counted in:
        :data:`CE90_CIRCULAR` for two components, :data:`LE90` for one.

    Returns
    -------
    dict
        ``count``, ``rmse`` (over the components, per point the root of the sum of
        squares), ``rmse_trend_only`` (the same without the signal),
        ``share_within_90`` and the mean predicted sigma.
    """
    m = len(xy_m)
    if m < 3:
        return {"count": int(m), "rmse": None, "rmse_trend_only": None,
                "share_within_90": None, "mean_sigma": None}
    pred, var, _ = krige(cov, xy_m, resid, noise, xy_m, k, skip_self=True)
    return _cv_stats(cov, resid, noise, pred, var, factor)


def _cv_stats(cov: CovarianceModel, resid, noise, pred, var, factor: float) -> dict:
    """The leave-one-out figures from the held-out predictions."""
    m = len(resid)
    err = resid - pred
    sig = np.sqrt(var + cov.nugget + noise)
    size = np.sqrt((err ** 2).sum(axis=1))
    return {"count": int(m), "rmse": float(np.sqrt(np.mean(size ** 2))),
            "rmse_trend_only": float(np.sqrt(np.mean((resid ** 2).sum(axis=1)))),
            "share_within_90": float(np.mean(size <= factor * sig)),
            "mean_sigma": float(np.mean(sig))}


# --------------------------------------------------------------------------- a run
@dataclass
class _Trend:
    """The trend at the object points and what its error is made of.

    ``t`` (n, 3) the trend; ``g`` (n, 3, q) its design in the estimated parameters (the
    database offset's, then one per applied mean) and ``c`` (q, q) their covariance, so
    that the trend's error is ``g dT``; ``fixed`` (3,) the variance no prediction
    reduces (a mean not applied stays in every vertex); ``covered`` (3,) the axes of
    the offset model; ``mean`` and ``mean_var`` (3,) the applied means and their
    variances (0 elsewhere).
    """

    t: np.ndarray
    g: np.ndarray
    c: np.ndarray
    fixed: np.ndarray
    covered: np.ndarray
    mean: np.ndarray
    mean_var: np.ndarray

    def cov(self, sel=slice(None)) -> np.ndarray:
        """Covariance (n, 3, 3) of the trend alone (no field) at the points ``sel``."""
        g = self.g[sel]
        return np.einsum("niq,qr,njr->nij", g, self.c, g) + np.diag(self.fixed)


def _trend_design(rec: Optional[dict], xyz: np.ndarray, mean: np.ndarray,
                  mean_var: np.ndarray):
    """``t``, ``g``, ``c`` of :class:`_Trend` at ``xyz``: the offset's ``-G(x) T`` and
    the means of the axes ``mean_var > 0``."""
    from vectoradjust.adjust.offsets import _kind_design

    n = len(xyz)
    t = np.zeros((n, 3))
    gs, cs = [np.zeros((n, 3, 0))], []
    if rec is not None:
        g = _kind_design(rec["kind"], xyz, np.asarray(rec["center"], float))
        t = -np.einsum("niq,q->ni", g, np.asarray(rec["values"], float))
        gs.append(g)
        cs.append(np.asarray(rec["cofactor"], float) * float(rec["variance_factor"]))
    for a in np.flatnonzero(np.asarray(mean_var) > 0):
        t[:, a] = mean[a]
        col = np.zeros((n, 3, 1))
        col[:, a, 0] = 1.0
        gs.append(col)
        cs.append(np.array([[float(mean_var[a])]]))
    g = np.concatenate(gs, axis=2)
    c = np.zeros((g.shape[2], g.shape[2]))
    i = 0
    for b in cs:
        c[i:i + len(b), i:i + len(b)] = b
        i += len(b)
    return t, g, c


def _trend(rec: Optional[dict], db_xyz: np.ndarray, dm: np.ndarray, common: np.ndarray,
           mean_var: Optional[np.ndarray] = None) -> _Trend:
    """The trend at every object point (:class:`_Trend`).

    ``-G(x) T`` of the estimated offset (database minus images, so the displacement is
    its negative); axes the offset model does not cover get the measured points' mean
    ``m`` where it differs from zero by more than 1.96 times the larger of its scatter's
    standard error and ``sqrt(common)`` (3,), the adjusted points' mean variance: a
    common height error of a stereo model, larger than its covariance says when the
    adjustment is strained, must not move good database heights (DEM heights). Its
    variance is ``mean_var`` (3,; default ``common``), the variance of the points' mean
    (:func:`_mean_variance`), at least the scatter's; where the mean is not applied, the
    vertex keeps an error of about ``m``, so its variance is ``m^2 + mean_var``, and no
    prediction removes it (``fixed``).
    """
    g0 = np.zeros((1, 3, 0))
    if rec is not None:
        from vectoradjust.adjust.offsets import _kind_design

        g0 = _kind_design(rec["kind"], db_xyz[:1], np.asarray(rec["center"], float))
    covered = np.abs(g0).sum(axis=(0, 2)) > 0 if len(db_xyz) else np.zeros(3, bool)
    mean_var = common if mean_var is None else mean_var
    mean, applied_var, fixed = np.zeros(3), np.zeros(3), np.zeros(3)
    for a in np.flatnonzero(~covered):
        col = dm[:, a][np.isfinite(dm[:, a])]
        if col.size:
            m, scatter = float(col.mean()), col.var() / col.size
            var = max(scatter, float(mean_var[a]))
            if abs(m) > 1.96 * np.sqrt(max(scatter, float(common[a]))):
                mean[a], applied_var[a] = m, max(var, 1e-300)
            else:
                fixed[a] = m * m + var
    t, g, c = _trend_design(rec, db_xyz, mean, applied_var)
    return _Trend(t, g, c, fixed, covered, mean, applied_var)


def _trend_cov(tr: _Trend, sel, ws_h: Optional[np.ndarray], ws_v: Optional[np.ndarray]):
    """Covariance (n, 3, 3) of the trend's error in the prediction at the points ``sel``.

    The prediction ``t(x) + sum w_i (d_i - t(x_i))`` carries the trend's error ``g dT``
    as ``(g(x) - sum w_i g(x_i)) dT``: near measured points (``sum w`` about 1) the
    collocation has put the field back around the measured displacements and the
    trend's error cancels; far from them (``w`` about 0) it counts in full. ``ws_h``
    (n, 2 q) and ``ws_v`` (n, q) are the kriging weights' sums of ``g`` over the
    measured points (:func:`_krige_many`, horizontal and vertical weights); the error's
    correlation with the neighbours' own data is left out (it is small beyond the
    neighbourhood that fixed ``T``). Plus ``fixed``.
    """
    h = tr.g[sel].copy()
    q = h.shape[2]
    if ws_h is not None:
        h[:, :2, :] -= ws_h.reshape(len(h), 2, q)
    if ws_v is not None:
        h[:, 2, :] -= ws_v
    return np.einsum("niq,qr,njr->nij", h, tr.c, h) + np.diag(tr.fixed)


def _trend_field_cov(g_m: np.ndarray, xy_m: np.ndarray, covs, max_points: int = 1500,
                     seed: int = 0) -> np.ndarray:
    """Covariance (q, q) the correlated field adds to the estimated trend's error.

    The offset (and an applied mean) is estimated from the measured points as if their
    database errors were independent (the adjustment's cofactor holds each point's own
    variance); the field correlates them, so the estimate also carries the field's
    weighted mean over the measured points: ``A (sum_{i != j} g_i' C(r_ij) g_j) A`` with
    ``A = (sum g_i' g_i)^-1`` (the offset's least-squares weights; a mean: ``1/n``) and
    ``C`` the fitted signal covariance of the row's component (``covs``: horizontal for
    X and Y, vertical for Z). The pair sum is taken on a random subset of at most
    ``max_points`` points and scaled by the number of pairs (an unbiased estimate).
    """
    m, q = g_m.shape[0], g_m.shape[2]
    if q == 0 or m < 2 or all(c is None or c.sill <= 0 or c.length <= 0 for c in covs):
        return np.zeros((q, q))
    from scipy.spatial.distance import pdist, squareform

    a = np.linalg.pinv(np.einsum("naq,nar->qr", g_m, g_m))
    pick = (np.sort(np.random.default_rng(seed).choice(m, max_points, replace=False))
            if m > max_points else np.arange(m))
    ns = len(pick)
    dist = squareform(pdist(xy_m[pick]))
    mid = np.zeros((q, q))
    for rows, cov in (((0, 1), covs[0]), ((2,), covs[1])):
        if cov is None or cov.sill <= 0 or cov.length <= 0:
            continue
        k = cov(dist)
        np.fill_diagonal(k, 0.0)
        for r in rows:
            gr = g_m[pick, r, :]
            mid += gr.T @ k @ gr
    mid *= m * (m - 1) / (ns * (ns - 1))
    out = a @ mid @ a
    return 0.5 * (out + out.T)


@dataclass
class _Field:
    """One component group's field at the unmeasured object points."""

    pred: np.ndarray
    var: np.ndarray
    nearest: np.ndarray
    cov: Optional[CovarianceModel]
    cv: dict
    wsum: Optional[np.ndarray] = None  # kriging weights' sums of the trend's design


def _fields(xy_m, resid, noise, xy_u, s: ConflationSettings, report, cancel, carry=None,
            corr_v=None):
    """Fit, predict and cross-validate the horizontal and the vertical field.

    Each group (X and Y sharing one covariance function; Z) uses the measured points
    where it is finite; when both use the same points the KD-tree queries and the
    neighbours' distance matrices are shared. ``carry`` (horizontal (m, fh), vertical
    (m, fv)) is summed with each group's kriging weights (``_Field.wsum``; no field:
    None, the weights are zero). ``corr_v`` (m, r): the images' height error the
    measured points share (:func:`_orientation_basis`), in the vertical fit and system.
    """
    carry = carry or (None, None)
    corr = (None, corr_v)
    groups = [(resid[:, :2], noise[:, :2].mean(axis=1), CE90_CIRCULAR),
              (resid[:, 2:], noise[:, 2], LE90)]
    n_u = len(xy_u)
    oks = [np.isfinite(r).all(axis=1) for r, _, _ in groups]
    covs = [fit_covariance(xy_m[ok], r[ok], nz[ok], s.model, s.k,
                           corr=None if u is None else u[ok])
            if ok.sum() >= s.min_points else None
            for ok, (r, nz, _), u in zip(oks, groups, corr)]
    live = [i for i, c in enumerate(covs) if c is not None]
    fields = [_Field(np.full((n_u, r.shape[1]), np.nan), np.full(n_u, np.nan),
                     np.full(n_u, np.inf), None, {"count": int(ok.sum()), "rmse": None})
              for ok, (r, _, _) in zip(oks, groups)]
    batches = ([live] if len(live) == 2 and np.array_equal(*oks) else [[i] for i in live])
    for b, batch in enumerate(batches):
        ok = oks[batch[0]]
        models = [(covs[i], groups[i][0][ok], groups[i][1][ok],
                   None if carry[i] is None else carry[i][ok],
                   None if corr[i] is None else corr[i][ok]) for i in batch]
        part = (b, len(batches))
        res, nearest = _krige_many(models, xy_m[ok], xy_u, s.k, progress=lambda f, p=part:
                                   report((p[0] + f) / p[1]), is_cancelled=cancel)
        loo, _ = _krige_many([(*m[:3], None, m[4]) for m in models], xy_m[ok], xy_m[ok], s.k,
                             skip_self=True, is_cancelled=cancel)
        for i, (pred, var, ws), (lp, lv, _), m in zip(batch, res, loo, models):
            cv = (_cv_stats(covs[i], m[1], m[2], lp, lv, groups[i][2]) if ok.sum() >= 3 else
                  {"count": int(ok.sum()), "rmse": None})
            fields[i] = _Field(pred, var, nearest, covs[i], cv, ws)
    return fields[0], fields[1]


def _vertex_columns(d, meas_v, adj, cov, source, ce_factor=None) -> None:
    """Write the conflated vertices into ``d.vertices`` / ``d.adjusted_coords`` (in place);
    ``ce_factor`` (per vertex, :func:`ce90_factor`) scales the predicted vertices' CE90."""
    from vectoradjust.accuracy.tables import _feature_geometry, cov_stats

    v = d.vertices
    db = d.shape.layer.coords
    u = ~meas_v
    sig, ce, le = cov_stats(cov[u])
    if ce_factor is not None:
        ce = ce * ce_factor[u]
    for a, ax in enumerate("XYZ"):
        col = np.array(v[f"Adj{ax}"], float)
        col[u] = adj[u, a]
        v[f"Adj{ax}"] = col
        vcol = np.array(v[f"V{ax.lower()}"], float)
        vcol[u] = adj[u, a] - db[u, a]
        v[f"V{ax.lower()}"] = vcol
        scol = np.array(v[f"Sigma{ax}"], float)
        scol[u] = sig[:, a]
        v[f"Sigma{ax}"] = scol
    for name, val in (("CE90", ce), ("LE90", le)):
        col = np.array(v[name], float)
        col[u] = val
        v[name] = col
    v["Source"] = source
    d.adjusted_coords = np.column_stack([v["AdjX"], v["AdjY"], v["AdjZ"]])
    d.features.update(_feature_geometry(d.shape.layer, d.adjusted_coords))


#: distance bands (m) from the nearest measured point of the truth check's coverage table
DISTANCE_BANDS = (0.0, 50.0, 100.0, 200.0, np.inf)


def band_coverage(near: np.ndarray, inside_h: np.ndarray, inside_v: np.ndarray,
                  edges=DISTANCE_BANDS) -> list:
    """Coverage per distance band: ``[{"band", "count", "ce90", "le90"}]``.

    ``near`` (n,) the distance to the nearest measured point, ``inside_h`` and
    ``inside_v`` (n,) whether the truth lies within the CE90 / LE90 (NaN: no LE90);
    ``edges`` the bands' limits (m), lower inclusive.
    """
    near = np.asarray(near, float)
    out = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        m = (near >= lo) & (near < hi)
        v = np.asarray(inside_v, float)[m]
        v = v[np.isfinite(v)]
        out.append({"band": f"{lo:g}-{hi:g}" if np.isfinite(hi) else f">{lo:g}",
                    "count": int(m.sum()),
                    "ce90": float(np.mean(np.asarray(inside_h, float)[m])) if m.any() else None,
                    "le90": float(np.mean(v)) if v.size else None})
    return out


def _truth_check(out, d, meas_v, source, near=None) -> Optional[dict]:
    """RMSE of the unmeasured vertices to the truth before and after, CE90/LE90 coverage
    (also per distance band of ``near``, each vertex's distance to the nearest measured
    point, :func:`band_coverage`)."""
    from vectoradjust.adjust.shapepoints import lookup

    truth = (getattr(out.data, "truth", None) or {}).get(d.name)
    if truth is None:
        return None
    tid, txyz = truth
    ti = lookup(np.asarray(tid), d.shape.vertex_ids)
    m = (~meas_v) & (ti >= 0) & np.isin(source, ("interpolated", "extrapolated"))
    if not m.any():
        return None
    v = d.vertices
    t = np.asarray(txyz, float)[ti[m]]
    db = d.shape.layer.coords[m]
    adj = np.column_stack([v["AdjX"], v["AdjY"], v["AdjZ"]])[m]
    e_db, e_adj = np.hypot(*(db[:, :2] - t[:, :2]).T), np.hypot(*(adj[:, :2] - t[:, :2]).T)
    ez = np.abs(adj[:, 2] - t[:, 2])
    okz = np.isfinite(ez) & np.isfinite(v["LE90"][m])
    r_db, r_adj = float(np.sqrt(np.mean(e_db ** 2))), float(np.sqrt(np.mean(e_adj ** 2)))
    in_v = np.where(okz, ez <= np.where(okz, v["LE90"][m], 0.0), np.nan)
    bands = (band_coverage(np.asarray(near, float)[m], e_adj <= v["CE90"][m], in_v)
             if near is not None else None)
    return {"bands": bands, "count": int(m.sum()), "rmse_database_truth_horizontal": r_db,
            "rmse_conflated_truth_horizontal": r_adj,
            "reduction": float(1.0 - r_adj / r_db) if r_db > 0 else None,
            "share_within_ce90": float(np.mean(e_adj <= v["CE90"][m])),
            "rmse_database_truth_z": float(np.sqrt(np.nanmean((db[:, 2] - t[:, 2]) ** 2))),
            "rmse_conflated_truth_z": (float(np.sqrt(np.mean(ez[okz] ** 2)))
                                       if okz.any() else None),
            "share_within_le90": float(np.mean(ez[okz] <= v["LE90"][m][okz]))
            if okz.any() else None}


def _measured_objects(d):
    """Bundle point of every object point (-1: not measured), measured vertex mask."""
    sp = d.shape
    meas_v = np.asarray(d.vertex_point) >= 0
    obj_pt = np.full(sp.n_objects, -1, np.int64)
    obj_pt[sp.vertex_object[meas_v]] = d.vertex_point[meas_v]
    return obj_pt, meas_v


def _image_weights(q: np.ndarray, prior_weight: np.ndarray) -> tuple:
    """``Q^-1``, ``P_img = Q^-1 - P_prior``, where ``Q`` is usable (finite, positive
    definite) and where ``P_img`` is positive definite (a point on one image only has
    rank 2: not ok)."""
    usable = np.isfinite(q).all(axis=(1, 2))
    usable[usable] = np.linalg.eigvalsh(q[usable])[:, 0] > 0
    q_inv = np.broadcast_to(np.eye(3), q.shape).copy()
    q_inv[usable] = np.linalg.inv(q[usable])
    p_img = q_inv - prior_weight
    p_img = 0.5 * (p_img + np.swapaxes(p_img, 1, 2))
    ev = np.linalg.eigvalsh(p_img)
    ok = usable & (ev[:, 0] > 1e-6 * np.maximum(ev[:, 2], 1e-300))
    return q_inv, p_img, usable, ok


def image_only(result, problem, pts: np.ndarray, min_share: float = 0.1,
               scale: Optional[float] = None):
    """What the images alone say about measured shape points: position and covariance.

    The adjusted shape point is a weighted mean of the images' intersection and the
    database prior ``X_prior = X_db - G T``: ``X_hat - X_prior = Q P_img (X_img -
    X_prior)`` with ``Q = (P_img + P_prior)^-1`` its cofactor, so its displacement is
    shrunk towards the database by the prior's weight. The collocation needs the
    unshrunk observation ``X_img = X_prior + P_img^-1 Q^-1 (X_hat - X_prior)`` with
    covariance ``scale P_img^-1``, ``P_img = Q^-1 - P_prior`` (per point; the
    correlation with other points through the orientation is left out).

    Parameters
    ----------
    result : BundleResult
    problem : BundleProblem
        The final problem (priors).
    pts : numpy.ndarray of int
        Bundle points.
    min_share : float
        An axis where the images carry less than this share of the weight is NaN
        (the images say next to nothing there).
    scale : float, optional
        Variance factor of the images' share (default: the run's). An a-posteriori
        sigma0^2 driven by the databases' residuals (a correlated error the prior
        does not know) says nothing about the images; :func:`conflate_database` passes
        the image group's ``v'Pv / r``.

    Returns
    -------
    xyz : numpy.ndarray, shape (p, 3)
    var : numpy.ndarray, shape (p, 3)
        Variances per axis (m^2).
    """
    vf = result.variance_factor
    scale = vf if scale is None or not np.isfinite(scale) else float(scale)
    q_inv, p_img, usable, ok = _image_weights(result.point_cov[pts] / vf, problem
                                              .prior_weight[pts])
    npp_inv = getattr(result, "npp_inv", None)
    redo = usable & ~ok
    if redo.any() and npp_inv is not None:
        # the marginal covariance holds the orientation's (and offsets') shared error;
        # where it exceeds what the prior allows (weak control: P_img not positive),
        # take the point given the adjusted orientation (N_pp^-1), whose weight is the
        # images' and the prior's alone
        qi2, pi2, us2, ok2 = _image_weights(np.asarray(npp_inv, float)[pts[redo]],
                                            problem.prior_weight[pts[redo]])
        q_inv[redo], p_img[redo], ok[redo] = qi2, pi2, ok2 & us2
    share = np.einsum("nii->ni", p_img) / np.einsum("nii->ni", q_inv)
    q_img = np.full_like(p_img, np.nan)
    q_img[ok] = np.linalg.inv(p_img[ok])
    prior = problem.prior_xyz[pts]
    shift = np.einsum("nij,njk,nk->ni", q_img, q_inv, result.xyz[pts] - prior)
    var = scale * np.einsum("nii->ni", q_img)
    bad = (share < min_share) | ~ok[:, None]
    xyz = np.where(bad, np.nan, prior + shift)
    return xyz, np.where(bad, np.nan, var)


def _orientation_basis(result, problem, pts: np.ndarray, scale: float, axis: int = 2,
                       max_rank: int = 40) -> Optional[np.ndarray]:
    """The images' shared error of the image-only positions (:func:`image_only`) of the
    points ``pts`` on one axis, as a basis ``U`` (p, r): covariance ``U U'``.

    The adjusted points share the orientation's error: ``Z S^-1 Z'`` of their joint
    covariance (:meth:`BundleResult.joint_covariance`, ``Z = N_pp^-1 N_pe`` per point);
    the image-only position carries it through ``T = P_img^-1 Q^-1`` (the undoing of
    the prior's pull). Its rank is at most the orientation's 6 parameters per image:
    with at most ``max_rank`` of them ``U = Z L`` (``S^-1 = L L'``) exactly; with more,
    the directions above ``1e-6`` of the largest eigenvalue, at most ``max_rank``.
    Scaled by the images' variance factor ``scale``. None when the run kept no
    factorisation (nothing shared is then modelled).
    """
    if any(getattr(result, a, None) is None for a in ("s_inv", "npp_inv", "nep_obs")):
        return None
    import scipy.sparse as sps

    prob = result.problem
    pts = np.asarray(pts, np.int64)
    p, n6 = len(pts), 6 * prob.n_images
    q = result.point_cov[pts] / result.variance_factor
    good = np.isfinite(q).all(axis=(1, 2))
    q_inv = np.linalg.pinv(np.where(good[:, None, None], q, np.eye(3)), hermitian=True)
    row = np.einsum("nj,njk->nk", np.linalg.pinv(q_inv - problem.prior_weight[pts],
                                                 hermitian=True)[:, axis], q_inv)  # T[axis]
    pos = np.full(prob.n_points, -1, np.int64)
    pos[pts] = np.arange(p)
    sel = np.flatnonzero(pos[prob.obs_point] >= 0)
    i = pos[prob.obs_point[sel]]
    contrib = np.einsum("kab,kcb->kac", result.npp_inv[prob.obs_point[sel]],
                        result.nep_obs[sel])  # (s, 3, 6): N_pp^-1 N_pe
    vals = np.einsum("kc,kcj->kj", row[i], contrib)
    z = sps.coo_matrix((vals.ravel(), (np.repeat(i, 6), (6 * prob.obs_image[sel][:, None]
                                                          + np.arange(6)).ravel())),
                       shape=(p, n6)).tocsr()
    s_inv = 0.5 * (result.s_inv + result.s_inv.T)
    try:  # S^-1 = half half' (Cholesky: unique, the same on every numpy build)
        half = np.linalg.cholesky(s_inv)
    except np.linalg.LinAlgError:
        lam, vec = np.linalg.eigh(s_inv)
        half = vec * np.sqrt(np.maximum(lam, 0.0))
    if n6 <= max_rank:  # few images: exact, no eigen-decomposition
        u = np.asarray(z @ half)
    else:
        ev, ew = np.linalg.eigh(half.T @ (z.T @ z).toarray() @ half)  # (6n, 6n)
        keep = np.flatnonzero(ev > 1e-6 * max(float(ev[-1]), 1e-300))[::-1][:max_rank]
        u = np.asarray(z @ (half @ ew[:, keep]))
    u = u * np.sqrt(scale)
    u[~good] = 0.0
    return u


def _image_scale(out) -> float:
    """Variance factor of the images' share: 1 with ``covariance_scale = "a-priori"``,
    else the image coordinates' ``v'Pv / r`` (summary ``variance_factors``), at least 1."""
    if getattr(out.result, "covariance_scale", "") == "a-priori":
        return 1.0
    groups = (out.summary.get("variance_factors") or {}).get("groups") or {}
    f = (groups.get("image") or {}).get("factor")
    return max(float(f), 1.0) if f is not None and np.isfinite(f) else float("nan")


def _mean_variance(result, pts: np.ndarray) -> np.ndarray:
    """Variance per axis (3,) of the mean of the adjusted points ``pts``.

    ``1' C 1 / p^2`` of their joint covariance ``s0^2 [D + Z S^-1 Z' + (QB) Q_TT (QB)']``
    (:meth:`BundleResult.joint_covariance`) without forming it: the sums of the
    per-point blocks ``D``, of the rows ``Z_j`` and of ``(QB)_j`` are enough. The errors
    the points share (the orientation, the offsets) count in full, each point's own
    error (its intersection) by ``1/p``. Without the factorisation: the mean of the
    points' variances (every error taken as shared, an upper bound).
    """
    pts = np.unique(np.asarray(pts, np.int64))
    if not len(pts):
        return np.zeros(3)
    if any(getattr(result, a, None) is None for a in ("s_inv", "npp_inv", "nep_obs")):
        return np.nanmean(np.einsum("nii->ni", result.point_cov[pts]), axis=0)
    prob = result.problem
    n, p = prob.n_images, len(pts)
    inset = np.zeros(prob.n_points, bool)
    inset[pts] = True
    sel = np.flatnonzero(inset[prob.obs_point])
    contrib = np.einsum("kab,kcb->kac", result.npp_inv[prob.obs_point[sel]],
                        result.nep_obs[sel])  # (s, 3, 6): N_pp^-1 N_pe per observation
    z = np.zeros((n, 3, 6))
    np.add.at(z, prob.obs_image[sel], contrib)
    z = np.transpose(z, (1, 0, 2)).reshape(3, 6 * n)
    total = result.npp_inv[pts].sum(axis=0) + z @ result.s_inv @ z.T
    if result.offset_cofactor is not None:
        qb = result.offset_qb[pts].sum(axis=0)
        total = total + qb @ result.offset_cofactor @ qb.T
    return result.variance_factor * np.diagonal(total).copy() / p ** 2


def _sill_prior(spec, cov: CovarianceModel) -> tuple:
    """``(S0, nu0)``: the database's statement about its field's variance, the prior of
    the horizontal sill (:func:`_ce90_table`).

    The database's stated horizontal sigma (``[[vectors]] sigma``, its error once the
    offset is removed) less its stated systematic part and the fitted white noise:
    ``S0 = max(sigma_h^2 - systematic_h^2 - n_db, 0)``, with :data:`SILL_PRIOR_DOF`
    degrees of freedom (the statement known to about +-50 % in variance). Where the
    measured points see the field on a few patches only (``sill_dof`` of a few: e.g.
    the images cover a part of the database) the data cannot tell how large the field
    is elsewhere; the statement then carries the far vertices' variance.
    """
    sig = np.asarray(spec.sigma, float)[:2]
    s0 = float(np.mean(sig ** 2) - spec.systematic_variance[0] - cov.nugget)
    return max(s0, 0.0), SILL_PRIOR_DOF


def _predicted_objects(out, d, rec, s, obj_pt, report, cancel):
    """Displacement, covariance and nearest distance of the unmeasured object points."""
    db = d.shape.object_xyz
    m_obj, u_obj = np.flatnonzero(obj_pt >= 0), np.flatnonzero(obj_pt < 0)
    x_img, photo = image_only(out.result, out.problem, obj_pt[m_obj], scale=_image_scale(out))
    dm = x_img - db[m_obj]
    noise = photo + d.spec.identification_variance
    common = np.nanmean(np.einsum("nii->ni", out.result.point_cov[obj_pt[m_obj]]), axis=0)
    tr = _trend(rec, db, dm, common, _mean_variance(out.result, obj_pt[m_obj]))
    t, covered = tr.t, tr.covered
    # the field models the deviations from the mean; a mean not applied (above) must
    # not come back through a long-range field
    dev = dm - t[m_obj]  # (a point seen on one image has no image-only position: NaN)
    mean = np.array([np.nanmean(c) if np.isfinite(c).any() else 0.0 for c in dev.T])
    resid = dev - np.where(covered, 0.0, mean)
    xy_m, xy_u = db[m_obj, :2], db[u_obj, :2]
    g_m = tr.g[m_obj]
    corr_v = _orientation_basis(out.result, out.problem, obj_pt[m_obj], _image_scale(out))
    fh, fv = _fields(xy_m, resid, noise, xy_u, s, report, cancel,
                     (np.column_stack([g_m[:, :2, :].reshape(len(m_obj), -1),
                                       np.ones(len(m_obj))]), g_m[:, 2, :]), corr_v)
    wsum_h, fh.wsum = _split_weight_sum(fh.wsum, len(u_obj))
    if fh.cov is not None:
        fh.cov.sill_prior = _sill_prior(d.spec, fh.cov)
    disp = t[u_obj] + np.column_stack([fh.pred, fv.pred])
    extra = _trend_field_cov(g_m, xy_m, (fh.cov, fv.cov))
    cov_field = _trend_cov(replace(tr, c=extra, fixed=np.zeros(3)), u_obj, fh.wsum, fv.wsum)
    tr = replace(tr, c=tr.c + extra)
    cov = _trend_cov(tr, u_obj, fh.wsum, fv.wsum)
    nug_h = fh.cov.nugget if fh.cov is not None else np.nan
    nug_v = fv.cov.nugget if fv.cov is not None else np.nan
    cov[:, 0, 0] += fh.var + nug_h
    cov[:, 1, 1] += fh.var + nug_h
    cov[:, 2, 2] += fv.var + nug_v
    kappa = _horizontal_factor(fh.cov, wsum_h, cov_field, cov)
    model = FieldModel(xy_m, resid, noise, fh.cov, fv.cov, rec, tr.mean, tr.mean_var, s.k,
                       tr.fixed, extra, corr_v)
    info = {"trend": {"offset": rec.get("kind") if rec else None,
                      "axes_from_offset": [a for a, c in zip("XYZ", covered) if c],
                      "axes_from_mean": [a for a, c in zip("XYZ", covered) if not c],
                      "mean": [None if c else float(t[0, a]) if len(t) else None
                               for a, c in enumerate(covered)],
                      "mean_sigma": [None if c else float(np.sqrt(tr.mean_var[a]
                                                                  + tr.fixed[a]))
                                     if len(t) else None for a, c in enumerate(covered)]},
            "covariance": {"horizontal": fh.cov.as_dict() if fh.cov else None,
                           "vertical": fv.cov.as_dict() if fv.cov else None},
            "cross_validation": {"horizontal": fh.cv, "vertical": fv.cv}}
    return u_obj, disp, cov, kappa, fh, info, model


def _split_weight_sum(wsum: Optional[np.ndarray], n: int):
    """The kriging weights' sum (last column of the horizontal ``carry``, a column of
    ones) and the sums of the trend's design (the other columns)."""
    if wsum is None:
        return np.zeros(n), None
    return wsum[:, -1].copy(), wsum[:, :-1]


def _horizontal_factor(cov_h: Optional[CovarianceModel], wsum: np.ndarray,
                       cov_field: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """:func:`ce90_factor` of the horizontal prediction, per axis (the mean of X and Y).

    The part of the variance that the sill's error moves: where the prediction leans
    on the field's prior variance rather than on its neighbours. Raising the covariance
    by a constant ``a`` (a larger sill, the same local behaviour, which the
    leave-one-out fit sees well) raises the error variance of the same weights by
    ``a (1 - sum w)^2``: ``C0 (1 - sum w)^2``, plus what the field adds to the trend's
    error (``cov_field``, proportional to the sill). The noise's part is the
    database noise.
    """
    v_total = 0.5 * (cov[:, 0, 0] + cov[:, 1, 1])
    if cov_h is None:
        return np.ones(len(cov))
    v_sig = (cov_h.sill * (1.0 - wsum) ** 2
             + 0.5 * (cov_field[:, 0, 0] + cov_field[:, 1, 1]))
    return ce90_factor(cov_h, v_sig, np.full(len(cov), cov_h.nugget), v_total)


@dataclass
class FieldModel:
    """A database's fitted displacement field, to predict it anywhere (maps, rasters).

    Attributes
    ----------
    xy : numpy.ndarray, shape (m, 2)
        Measured object points.
    resid : numpy.ndarray, shape (m, 3)
        Their displacement less the trend (NaN where the images say too little).
    noise : numpy.ndarray, shape (m, 3)
        Their known noise variance per axis.
    cov_h, cov_v : CovarianceModel or None
    rec : dict or None
        The offset record (trend ``-G T``).
    mean : numpy.ndarray, shape (3,)
        Applied mean of the axes the offset does not cover (0 on the others) ...
    mean_var : numpy.ndarray, shape (3,)
        ... and its variance (0: not applied).
    k : int
    fixed : numpy.ndarray, shape (3,)
        Variance of a mean not applied (it stays in every vertex).
    trend_field_cov : numpy.ndarray, optional
        What the field adds to the trend parameters' covariance
        (:func:`_trend_field_cov`).
    corr_v : numpy.ndarray, shape (m, r), optional
        The images' height error the measured points share (:func:`_orientation_basis`).
    """

    xy: np.ndarray
    resid: np.ndarray
    noise: np.ndarray
    cov_h: Optional[CovarianceModel]
    cov_v: Optional[CovarianceModel]
    rec: Optional[dict]
    mean: np.ndarray
    mean_var: np.ndarray
    k: int
    fixed: np.ndarray = field(default_factory=lambda: np.zeros(3))
    trend_field_cov: Optional[np.ndarray] = None
    corr_v: Optional[np.ndarray] = None

    def predict(self, xy: np.ndarray, ce90_factor: bool = False):
        """Displacement (n, 3) and its variance per axis (n, 3) at ``xy`` (n, 2).

        The same prediction as the vertices get (trend + collocation, with the
        database's white noise and the trend's error as the prediction carries it,
        :func:`_trend_cov`), NaN where a component has no field. With ``ce90_factor``
        also the horizontal CE90's factor (n,) for the parameters' uncertainty
        (:func:`ce90_factor`; the vertices' CE90 is the plug-in one times it).
        """
        def design(p):
            return _trend_design(self.rec, np.column_stack([p, np.zeros(len(p))]),
                                 self.mean, self.mean_var)

        t, g, c = design(xy)
        if self.trend_field_cov is not None:
            c = c + self.trend_field_cov
        tr = _Trend(t, g, c, np.asarray(self.fixed, float), np.zeros(3, bool), self.mean,
                    self.mean_var)
        g_m = design(self.xy)[1]
        disp, var, ws = t.copy(), np.zeros((len(xy), 3)), [None, None]
        for i, (cols, cov) in enumerate((([0, 1], self.cov_h), ([2], self.cov_v))):
            if cov is None:
                disp[:, cols] = np.nan
                var[:, cols] = np.nan
                continue
            ok = np.isfinite(self.resid[:, cols]).all(axis=1)
            carry = g_m[ok][:, cols, :].reshape(int(ok.sum()), -1)
            if i == 0:  # and the weights' sum (_split_weight_sum)
                carry = np.column_stack([carry, np.ones(len(carry))])
            u = None if i == 0 or self.corr_v is None else self.corr_v[ok]
            ((pred, kv, ws[i]),), _ = _krige_many(
                [(cov, self.resid[ok][:, cols], self.noise[ok][:, cols].mean(axis=1), carry,
                  u)], self.xy[ok], xy, self.k)
            disp[:, cols] += pred
            var[:, cols] += (kv + cov.nugget)[:, None]
            if i == 0:
                wsum_h, ws[0] = _split_weight_sum(ws[0], len(xy))
        tcov = _trend_cov(tr, slice(None), *ws)
        var = var + np.einsum("nii->ni", tcov)
        if not ce90_factor:
            return disp, var
        if self.cov_h is None:
            return disp, var, np.ones(len(xy))
        tfield = (np.zeros_like(tr.c) if self.trend_field_cov is None
                  else np.asarray(self.trend_field_cov, float))
        fcov = _trend_cov(replace(tr, c=tfield, fixed=np.zeros(3)), slice(None), *ws)
        cov = np.zeros((len(xy), 3, 3))
        cov[:, 0, 0], cov[:, 1, 1] = var[:, 0], var[:, 1]
        return disp, var, _horizontal_factor(self.cov_h, wsum_h, fcov, cov)


def conflate_database(out, d, rec: Optional[dict], s: ConflationSettings,
                      report: Optional[Callable[[float], None]] = None,
                      cancel: Optional[Callable[[], bool]] = None) -> dict:
    """Correct every unmeasured vertex of one database (``d.vertices`` etc. in place).

    Parameters
    ----------
    out : AdjustmentRun
        With ``result`` (points and covariances) and ``d.vertices`` tabulated.
    d : DatabaseResult
    rec : dict or None
        The database's estimated offset (``Solution.offsets[name]``), None without.
    s : ConflationSettings
    report, cancel : callable, optional
        ``report(fraction)``; ``cancel()`` true raises ``CancelledError``.

    Returns
    -------
    dict
        summary.json's entry: status, vertices per source, trend, covariance functions,
        leave-one-out cross-validation and (simulations) the comparison with the truth.
    """
    report = report or (lambda f: None)
    obj_pt, meas_v = _measured_objects(d)
    n_meas = int((obj_pt >= 0).sum())
    source = np.where(meas_v, "measured", "unchanged").astype(object)
    entry: dict = {"name": d.name, "measured_points": n_meas}
    scope = np.asarray(d.features.get("LengthSDOf", []), object)
    entry["length_sd"] = {
        "covers": "measured and conflated vertices; those left at their database position "
                  "count as fixed (features: LengthSDOf)",
        "features_with_unmeasured_vertices": int((scope == "measured vertices").sum())}
    if not s.enabled or n_meas < s.min_points or meas_v.all():
        d.vertices["Source"] = source
        entry["status"] = ("disabled" if not s.enabled else "nothing to predict"
                           if meas_v.all() else
                           f"not done: {n_meas} measured points, fewer than min_points = "
                           f"{s.min_points}")
        entry["vertices"] = {k: int((source == k).sum()) for k in SOURCES}
        return entry
    u_obj, disp, cov, kappa, fh, info, d.conflation = _predicted_objects(
        out, d, rec, s, obj_pt, report, cancel)
    if fh.cov is None:  # no horizontal field: nothing honest to predict with
        d.conflation = None
        d.vertices["Source"] = source
        n_img = info["cross_validation"]["horizontal"]["count"]
        entry.update({"status": f"not done: {n_img} of {n_meas} measured points have a "
                      f"position from the images alone, fewer than min_points = "
                      f"{s.min_points}", **info,
                      "vertices": {k: int((source == k).sum()) for k in SOURCES}})
        return entry
    nobj = d.shape.n_objects
    db = d.shape.object_xyz
    adj_o = np.full((nobj, 3), np.nan)
    cov_o = np.full((nobj, 3, 3), np.nan)
    near_o = np.full(nobj, np.inf)
    kappa_o = np.ones(nobj)
    adj_o[u_obj] = db[u_obj] + np.where(np.isfinite(disp), disp, 0.0)
    cov_o[u_obj] = cov
    kappa_o[u_obj] = kappa
    near_o[u_obj] = fh.nearest
    cov_m = fh.cov
    if cov_m is None:  # no field fitted (too few finite residuals)
        maxd = s.max_distance or np.inf
    else:
        maxd = s.max_distance or (cov_m.practical_range if cov_m.sill > 0 else
                                  (max(cov_m.fit.get("lags") or [np.inf])))
    vo = d.shape.vertex_object
    u = ~meas_v
    # interpolated: among the measured points (inside their convex hull) and within
    # max_distance of one; anywhere else the field is extrapolated
    inside = inside_hull(db[vo[meas_v], :2], db[:, :2])
    source[u] = np.where((near_o[vo[u]] <= maxd) & inside[vo[u]], "interpolated",
                         "extrapolated")
    _vertex_columns(d, meas_v, adj_o[vo], cov_o[vo], source, kappa_o[vo])
    if info["covariance"]["vertical"] is None:  # too few heights: Z unchanged
        d.vertices["Vz"][u] = np.nan
    entry.update({"status": "conflated", "max_distance": float(maxd), **info,
                  "vertices": {k: int((source == k).sum()) for k in SOURCES},
                  "truth": _truth_check(out, d, meas_v, source, near_o[vo])})
    return entry


def inside_hull(points: np.ndarray, query: np.ndarray, chunk: int = 65536) -> np.ndarray:
    """Which ``query`` points (n, 2) lie in the convex hull of ``points`` (m, 2).

    ``scipy.spatial.ConvexHull`` and its facets' half-planes (a point on the boundary,
    to 1e-9 of the hull's extent, is inside); all False where the points span no area
    (fewer than three, or on one line). Linear in ``n`` (chunks of ``chunk`` points).
    """
    from scipy.spatial import ConvexHull, QhullError

    query = np.asarray(query, float)
    out = np.zeros(len(query), bool)
    pts = np.unique(np.asarray(points, float)[np.isfinite(points).all(axis=1)], axis=0)
    if len(pts) < 3:
        return out
    try:
        hull = ConvexHull(pts)
    except QhullError:  # collinear: no area
        return out
    eq = hull.equations  # (f, 3): normal . x + offset <= 0 inside
    tol = 1e-9 * float(np.ptp(pts, axis=0).max())
    for lo in range(0, len(query), chunk):
        q = query[lo:lo + chunk]
        out[lo:lo + chunk] = np.all(q @ eq[:, :2].T + eq[:, 2] <= tol, axis=1)
    return out


def _horizontal(rec: Optional[dict]) -> Optional[dict]:
    """An offset record without the height of a DEM (``dem_height``): the DEM's
    systematic height error, estimated so that it does not pull the stereo model, is
    left to the conflation's own height rule (:func:`_trend`: a common height
    displacement is applied only where it exceeds one measured point's height error, and
    counted in the variance where not), not applied to every unmeasured vertex."""
    if rec is None or not rec.get("dem_height") or "Z" not in rec["axes"]:
        return rec
    keep = [i for i, a in enumerate(rec["axes"]) if a != "Z"]
    if not keep:
        return None
    cof = np.asarray(rec["cofactor"], float)[np.ix_(keep, keep)]
    kinds = {("X", "Y"): "shift"}
    return {**rec, "axes": [rec["axes"][i] for i in keep],
            "kind": kinds.get(tuple(rec["axes"][i] for i in keep), rec["kind"]),
            "values": [rec["values"][i] for i in keep],
            "sigma": [rec["sigma"][i] for i in keep], "cofactor": cof.tolist()}


def conflate_run(out, offsets: Optional[dict], settings: ConflationSettings,
                 progress: Optional[Callable[[float, str], None]] = None,
                 is_cancelled: Optional[Callable[[], bool]] = None) -> dict:
    """Conflate every database of a run; returns summary.json's ``conflation``.

    Parameters
    ----------
    out : AdjustmentRun
    offsets : dict or None
        ``Solution.offsets`` (per database name).
    settings : ConflationSettings
    progress : callable, optional
        ``progress(fraction, message)``.
    is_cancelled : callable, optional

    Returns
    -------
    dict
        The settings and one entry per database (:func:`conflate_database`).
    """
    entries = []
    n = max(len(out.databases), 1)
    for i, d in enumerate(out.databases):
        msg = f"conflation of {d.name}"

        def report(f, i=i, msg=msg):
            if progress is not None:
                progress((i + f) / n, msg)

        entries.append(conflate_database(out, d, _horizontal((offsets or {}).get(d.name)),
                                         settings,
                                         report, is_cancelled))
    return {"enabled": settings.enabled, "k": settings.k, "model": settings.model,
            "max_distance": settings.max_distance, "min_points": settings.min_points,
            "databases": entries}


def field_grid(d, cell: Optional[float] = None, max_cells: int = 40000) -> Optional[dict]:
    """The displacement field of a conflated database on a regular grid.

    Parameters
    ----------
    d : DatabaseResult
        Conflated (``d.conflation`` set).
    cell : float, optional
        Cell size (m); default: the extent over ``sqrt(max_cells)``, rounded up to 1-2-5.
    max_cells : int
        At most this many cells (the cell grows when needed).

    Returns
    -------
    dict or None
        ``x0``, ``y0`` (upper left corner), ``cell``, ``dx``, ``dy``, ``dz`` and
        ``ce90``, ``le90`` arrays (rows from north to south); None without a field.
    """
    model = getattr(d, "conflation", None)
    xy = np.asarray(d.shape.layer.coords, float)[:, :2] if len(d.shape.layer.coords) else None
    if model is None or xy is None:
        return None
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    ext = float(max((hi - lo).max(), 1.0))
    need = ext / np.sqrt(max_cells)
    if cell is None or cell < need:
        e = 10.0 ** np.floor(np.log10(need))
        cell = float(next(m * e for m in (1.0, 2.0, 5.0, 10.0) if m * e >= need))
    nx = int(np.ceil((hi[0] - lo[0]) / cell)) + 1
    ny = int(np.ceil((hi[1] - lo[1]) / cell)) + 1
    x0, y0 = float(lo[0] - cell / 2), float(hi[1] + cell / 2)
    gx = x0 + cell * (np.arange(nx) + 0.5)
    gy = y0 - cell * (np.arange(ny) + 0.5)
    xx, yy = np.meshgrid(gx, gy)
    disp, var, kappa = model.predict(np.column_stack([xx.ravel(), yy.ravel()]),
                                     ce90_factor=True)
    sig_h = kappa * np.sqrt(np.maximum(var[:, :2].mean(axis=1), 0.0))
    shape = (ny, nx)
    return {"x0": x0, "y0": y0, "cell": cell, "dx": disp[:, 0].reshape(shape),
            "dy": disp[:, 1].reshape(shape), "dz": disp[:, 2].reshape(shape),
            "ce90": (CE90_CIRCULAR * sig_h).reshape(shape),
            "le90": (LE90 * np.sqrt(np.maximum(var[:, 2], 0.0))).reshape(shape)}
