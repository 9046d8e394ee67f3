"""The covariance function of the displacement field: the empirical semivariogram and
the leave-one-out fit of ``C0``, ``L`` and ``n_db`` (:func:`fit_covariance`).

Heart module: numpy and scipy only.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, NamedTuple, Optional

import numpy as np

from vectoradjust.conflation.optimize import _lattice_min, _projected_bfgs

__all__ = ["CovarianceModel", "empirical_semivariogram", "fit_covariance"]


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
    functions are fitted and the one with the better score is kept
    (:func:`_best_model`). The score's gradient and expected Hessian are in closed form
    from one batched solve (:func:`_loo_score_fisher`), so a quasi-Newton search
    started from that Hessian (:func:`_projected_bfgs`) needs 5-20 scores; its result
    is put on a fixed lattice (:func:`_lattice_min`) so that QGIS's numpy gives the
    same model. ``n_db`` is then replaced by its mean given the data
    (:func:`_nugget_posterior`, every nugget from one eigendecomposition,
    :func:`_nugget_scores`), and the sill's degrees of freedom are estimated
    (:func:`_sill_dof`): the CE90 of a predicted vertex accounts for both parameters'
    uncertainty (:func:`ce90_factor`). The chosen models are those of the former
    Nelder-Mead search (issue 32, benchmarks/README.md, tests/test_conflation_fit.py).

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
    setup = _loo_setup(xy, k, max_targets, corr=corr)
    scale = max(total, float(gam.max()), 1e-12)
    kd, theta, score, wls, white, status = _best_model(kind, (lag, gam, cnt), noise, setup,
                                                        resid, noise_pt, scale)
    nug, post = _nugget_posterior(theta, kd, setup, resid, noise_pt)
    model = CovarianceModel(kd, float(theta[1]), float(theta[2]), nug, noise,
                            {**fit, "status": status, "fitted_nugget": wls["nugget"],
                             "semivariogram_fit": wls, "loo_score": score,
                             "loo_score_white": white[1], "nugget_best": float(theta[0]),
                             "loo_targets": int(len(setup[0]))}, post)
    model.sill_dof = _sill_dof(model, xy, resid.shape[1])
    return model


def _best_model(kind: str, vario, noise: float, setup, resid, noise_pt, scale: float):
    """The shape (``kind``, or the better scoring of both for ``"auto"``) and its
    parameters (:func:`_fit_loo`, started from the semivariogram's least-squares fit
    ``vario = (lag, gamma, count)``, :func:`_fit_grid`), or white noise where a signal
    does not earn its two parameters (AIC: its score at least 4 better).

    Returns ``kind, theta, score, wls, (white nugget, white score), status``.
    """
    lag, gam, cnt = vario
    # the measured points' own noise is part of the nugget: it cannot be smaller
    floor = min(noise, 0.999 * float(gam.max()))
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
    return kd, theta, score, wls, white, status


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


class _LooSetup(NamedTuple):
    """What the leave-one-out score needs that its parameters do not change
    (:func:`_loo_setup`): held-out points ``tgt`` (b,), their neighbours ``idx`` (b, k)
    at ``dist`` (b, k), the neighbours' distances ``dd`` (b, k, k) and the shared noise
    ``corr`` (n, r) or None; ``lags`` the distinct values of ``dist`` and ``dd``, whose
    indices ``at_dist`` and ``at_dd`` give each entry (a covariance is evaluated once
    per distinct distance and gathered); with ``corr`` the neighbours' shared noise
    ``shared_a = u u'`` (b, k, k), its diagonal ``shared_own`` (b, k) and the part the
    held-out point shares with them, ``shared_c`` (b, k) (:func:`_system`); ``eig``
    the eigendecompositions of :func:`_nugget_scores` by their parameters."""

    tgt: np.ndarray
    dist: np.ndarray
    idx: np.ndarray
    dd: np.ndarray
    corr: Optional[np.ndarray]
    lags: np.ndarray
    at_dist: np.ndarray
    at_dd: np.ndarray
    shared_a: Optional[np.ndarray] = None
    shared_own: Optional[np.ndarray] = None
    shared_c: Optional[np.ndarray] = None
    eig: Optional[dict] = None


def _loo_setup(xy: np.ndarray, k: int, max_targets: int, seed: int = 0,
               corr=None) -> _LooSetup:
    """Targets (a random subset of at most ``max_targets`` points), their ``k`` nearest
    other points (all points serve as neighbours), the distances and the shared noise's
    matrices: fixed while the parameters of :func:`_loo_score` change
    (:class:`_LooSetup`)."""
    from scipy.spatial import cKDTree

    n = len(xy)
    tgt = np.arange(n)
    if n > max_targets:
        tgt = np.sort(np.random.default_rng(seed).choice(n, max_targets, replace=False))
    k = int(min(k, n - 1))
    dist, idx = _neighbours(cKDTree(xy), xy[tgt], k, skip_self=True)
    px, py = xy[idx, 0], xy[idx, 1]
    dd = np.hypot(px[:, :, None] - px[:, None, :], py[:, :, None] - py[:, None, :])
    lags, at_dist, at_dd = _distinct_pairs(xy, tgt, idx)
    setup = _LooSetup(tgt, dist, idx, dd, corr, lags, at_dist, at_dd, eig={})
    if corr is None:
        return setup
    u_nb = corr[idx]
    return setup._replace(shared_a=np.matmul(u_nb, np.swapaxes(u_nb, 1, 2)),
                          shared_own=np.einsum("bkr,bkr->bk", u_nb, u_nb),
                          shared_c=np.einsum("bkr,br->bk", u_nb, corr[tgt]))


def _distinct_pairs(xy: np.ndarray, tgt: np.ndarray, idx: np.ndarray):
    """The distinct point pairs among the targets' neighbourhoods: their distances
    ``lags`` (the last one 0, the diagonal) and each entry's index into them,
    ``at_dist`` (b, k) for target-neighbour pairs and ``at_dd`` (b, k, k) for
    neighbour-neighbour pairs. Neighbourhoods of near targets share most pairs, so
    there are far fewer distinct pairs than entries (one integer sort)."""
    n, k = len(xy), idx.shape[1]
    iu, ju = np.triu_indices(k, 1)
    p = np.concatenate([idx[:, iu], np.broadcast_to(tgt[:, None], idx.shape)], axis=1)
    q = np.concatenate([idx[:, ju], idx], axis=1)
    code = np.minimum(p, q).astype(np.int64) * n + np.maximum(p, q)
    uniq, inv = np.unique(code.ravel(), return_inverse=True)
    inv = inv.reshape(code.shape)
    a, b = uniq // n, uniq % n
    lags = np.append(np.hypot(xy[a, 0] - xy[b, 0], xy[a, 1] - xy[b, 1]), 0.0)
    at_dd = np.full((len(idx), k, k), len(uniq), dtype=inv.dtype)
    at_dd[:, iu, ju] = inv[:, :len(iu)]
    at_dd[:, ju, iu] = inv[:, :len(iu)]
    return lags, inv[:, len(iu):], at_dd


def _loo_score(theta, kind: str, setup: _LooSetup, resid: np.ndarray,
               noise: np.ndarray) -> float:
    """Negative leave-one-out log predictive density (per component, constants dropped)
    of ``theta = (nugget_db, sill, length)``: ``sum log s2 + e^2 / s2`` with ``e`` the
    held-out point's error and ``s2`` its predicted variance (kriging variance + database
    noise + the point's own noise; with ``corr`` in ``setup`` the noise shared with the
    neighbours, :func:`_system`)."""
    return _loo_eval(np.asarray(theta, float), kind, setup, resid, noise, False)[0]


def _loo_score_grad(x, kind: str, setup: _LooSetup, resid: np.ndarray, noise: np.ndarray):
    """:func:`_loo_score` of ``theta = exp(x)`` and its gradient in ``x`` (the
    logarithms of nugget, sill and length), in closed form: one batched solve.

    With ``w = A^-1 c`` the held-out point's weights, ``e`` its error and ``s2`` its
    variance, the score's derivative is ``sum alpha ds2 + 2 e' de / s2`` with ``alpha =
    c/s2 - |e|^2/s2^2`` (``c`` components). For each parameter ``v = dc - dA w``:
    ``dw = A^-1 v``, so ``de = -R' dw = -(A^-1 R)' v`` (``R`` the neighbours' residuals,
    ``A`` symmetric) and ``ds2 = dsill - w' dc - w' v`` (plus the nugget's own share):
    ``A^-1 R`` comes from the same solve as ``w`` (right sides ``c`` and ``R``).
    ``(inf, 0)`` where the score is inf.
    """
    return _loo_eval(np.exp(np.asarray(x, float)), kind, setup, resid, noise, True)


def _loo_score_fisher(x, kind: str, setup: _LooSetup, resid: np.ndarray, noise: np.ndarray):
    """:func:`_loo_score_grad` and the score's expected Hessian in ``x`` (the Fisher
    information of the held-out points' predictive normals, ``sum m ds2 ds2' / s2^2 +
    2 de de' / s2``): from the same solve, since ``de_j = -(A^-1 R)' (dc_j - dA_j w)``.
    ``(inf, 0, 0)`` where the score is inf."""
    return _loo_eval(np.exp(np.asarray(x, float)), kind, setup, resid, noise, True, True)


def _loo_eval(theta: np.ndarray, kind: str, setup: _LooSetup, resid, noise, grad: bool,
              fisher: bool = False, parts: bool = False):
    """``(score, gradient in log theta or None[, Fisher matrix[, per target]]])`` of
    :func:`_loo_score_grad` (:func:`_loo_score_fisher` with ``fisher``; with ``parts``
    also each held-out point's gradient (3, b), :func:`_nugget_temper`).

    The signal's covariance is evaluated at the distinct distances only and gathered
    (``setup.lags``); the weights and ``A^-1 R`` come from one batched solve."""
    nug, sill, length = (float(v) for v in theta)
    s_l = np.zeros(len(setup.lags))
    h_l = s_l
    if sill > 0 and length > 0:
        u = setup.lags / length
        s_l = sill * (np.exp(-u) if kind == "exponential" else np.exp(-u * u))
        h_l = u if kind == "exponential" else 2.0 * u * u  # d log C / d log L
    s_dd, s_dist = s_l[setup.at_dd], s_l[setup.at_dist]
    tgt, idx = setup.tgt, setup.idx
    k = idx.shape[1]
    diag = np.arange(k)
    if setup.shared_a is None:
        a, c, own = s_dd.copy(), s_dist, 0.0
    else:
        a, c, own = s_dd + setup.shared_a, s_dist + setup.shared_c, setup.shared_own
    a[:, diag, diag] += nug + np.maximum(noise[idx] - own, 0.0)
    r_nb = resid[idx]
    fail = ((float("inf"), np.zeros(3), np.zeros((3, 3)), np.zeros((3, len(idx))))[:4 if parts
                                                                                 else 3]
            if fisher else
            (float("inf"), np.zeros(3) if grad else None))
    try:  # the weights (and A^-1 R for the gradient) from one factorisation
        sol = np.linalg.solve(a, np.concatenate([c[:, :, None], r_nb], axis=2) if grad
                              else c[:, :, None])
    except np.linalg.LinAlgError:  # a singular system: no admissible parameters
        return fail
    w, a_r = sol[:, :, 0], sol[:, :, 1:]
    e = resid[tgt] - np.matmul(w[:, None, :], r_nb)[:, 0, :]
    sig = sill - (w * c).sum(axis=1)
    live = (np.ones_like(sig) if setup.shared_a is not None else (sig > 0).astype(float))
    s2 = sig * live + nug + noise[tgt]
    if not np.all(s2 > 0):  # a perfect prediction claimed: not admissible
        return fail
    m = resid.shape[1]
    e2 = (e ** 2).sum(axis=1)
    score = float(np.sum(m * np.log(s2) + e2 / s2))
    if not grad:
        return score, None
    # d/d log theta_j: v_j = dc_j - dA_j w, dw_j = A^-1 v_j, de_j = -(A^-1 R)' v_j (A
    # symmetric: from the same solve), ds2_j = dsill_j - w' dc_j - w' v_j (+ dnugget)
    sh_l = s_l * h_l
    sh_dist = sh_l[setup.at_dist]
    v = np.stack([-nug * w, s_dist - np.matmul(s_dd, w[:, :, None])[:, :, 0],
                  sh_dist - np.matmul(sh_l[setup.at_dd], w[:, :, None])[:, :, 0]])
    dsig = -(v * w[None]).sum(axis=2)
    dsig[1] += sill - (w * s_dist).sum(axis=1)
    dsig[2] -= (w * sh_dist).sum(axis=1)
    ds2 = dsig * live
    ds2[0] += nug
    de = -np.einsum("bkc,jbk->jbc", a_r, v)
    alpha = m / s2 - e2 / s2 ** 2
    out = ds2 @ alpha + 2.0 * np.einsum("jbc,bc->j", de, e / s2[:, None])
    if not fisher:
        return score, out
    # the expected Hessian (Fisher information) of the score, e_i ~ N(0, s2_i I)
    hess = (m * (ds2 / s2) @ (ds2 / s2).T
            + 2.0 * np.einsum("jbc,kbc->jk", de, de / s2[None, :, None]))
    if parts:
        return score, out, hess, ds2 * alpha + 2.0 * np.einsum("jbc,bc->jb", de, e / s2[:, None])
    return score, out, hess


def _fit_loo(kind: str, setup, resid, noise, start, scale: float, lags):
    """``(nugget_db, sill, length), score`` minimising :func:`_loo_score` (bounded
    quasi-Newton, :func:`_projected_bfgs` on the logarithms from ``start``, with the closed-form
    gradient and expected Hessian of :func:`_loo_score_fisher`; then polished on a
    lattice).

    Nugget and sill lie between ``1e-6 scale`` and ``2 scale`` (``scale``: the larger of
    the residuals' mean square and the largest semivariance), the length between a
    tenth of the shortest and twice the longest lag of the semivariogram. Predictions
    from the nearest points see the field near the origin only (for the exponential
    function ``C0 / L``): sill and length are not told apart beyond the data's extent,
    and without these bounds a field could grow a sill and a range it never showed.
    About 5-20 scores with their gradients instead of the several hundred of a
    derivative-free search (issue 32).
    """
    floor = 1e-6 * scale
    lo = np.array([np.log(floor)] * 2 + [np.log(lags[0] / 10.0)])
    hi = np.array([np.log(2 * scale)] * 2 + [np.log(lags[-1] * 2.0)])
    x0 = np.clip(np.log(np.maximum(np.asarray(start, float), floor)), lo, hi)

    def f(x):
        return _loo_score(np.exp(x), kind, setup, resid, noise)

    def fg(x):
        return _loo_score_grad(x, kind, setup, resid, noise)

    x1 = _projected_bfgs(lambda x: _loo_score_fisher(x, kind, setup, resid, noise),
                         x0, lo, hi)
    x, fx = _lattice_min(f, x1, lo, hi, max_moves=1, fg=fg)
    theta = np.exp(x)
    theta[:2] = np.where(theta[:2] <= 10 * floor, 0.0, theta[:2])
    if theta[1] == 0.0:  # no signal: the length means nothing (a plateau); white noise
        theta[2] = 0.0
        fx = _loo_score(theta, kind, setup, resid, noise)
    return theta, fx


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
    variance not positive (as :func:`_loo_score`). The decomposition is kept in
    ``setup.eig`` (the white-noise model's serves its fit and its posterior).
    """
    tgt, dist, idx, dd, corr = setup[:5]
    cov = CovarianceModel(kind, theta[1], theta[2], 0.0)
    a, c = _system(cov, dd, dist, noise[idx], None if corr is None else corr[idx],
                   None if corr is None else corr[tgt])
    signal = cov.sill > 0 and cov.length > 0
    key = (kind if signal else "", cov.sill if signal else 0.0,
           cov.length if signal else 0.0, id(noise))
    cache = getattr(setup, "eig", None)
    if cache is not None and key in cache:
        lam, vec = cache[key]
    else:
        lam, vec = np.linalg.eigh(a)
        if cache is not None:
            cache[key] = (lam, vec)
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
    should carry for it. The score's terms correlate (a point's noise is in its own
    held-out error and in its neighbours'), so the likelihood is too narrow: its
    logarithm is divided by the sandwich ratio ``t >= 1`` (:func:`_nugget_temper`,
    evaluated at the untempered mean) and the grid widened by ``sqrt(t)``. The grid
    runs from 0 to where the likelihood has fallen by ``e^-10`` (found on two coarse
    grids), ``n_grid`` values.
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
    temper = _nugget_temper(theta, mean, kind, setup, resid, noise) if mean > 0 else 1.0
    if temper > 1.0:  # the same likelihood, its logarithm divided by ``temper``
        grid = np.linspace(0.0, hi * np.sqrt(temper), n_grid)
        sc = scores(grid)
        w = np.exp(-(sc - np.nanmin(sc)) / (2.0 * temper))
        w[~np.isfinite(w)] = 0.0
        w = w / np.sum(w)
        mean = float(np.sum(w * grid))
    keep = w > 1e-9
    return mean, ((grid[keep] / mean, w[keep] / w[keep].sum()) if mean > 0 else None)


def _nugget_temper(theta, nug: float, kind: str, setup, resid, noise,
                   max_factor: float = 9.0) -> float:
    """How much more ``n_db`` scatters than the leave-one-out likelihood says: the
    sandwich ratio ``t = J / (2 H)``, at least 1 and at most ``max_factor``.

    The score is a sum over held-out points, but it is no likelihood of independent
    data: a point's white noise enters its own error and, through the kriging weights,
    the errors of the held-out points it is a neighbour of, so their terms correlate
    and the score's curvature ``H`` (its expected Hessian in ``log n_db``,
    :func:`_loo_score_fisher`; ``2 I`` for a likelihood) overstates what the data know.
    ``J`` is the variance of the score's gradient estimated from the terms ``g_i``
    themselves, pairs of held-out points of which one is a neighbour of the other
    included: ``J = g' (I + S) g`` (``S`` that neighbourhood, symmetric), ``4 I`` for
    independent terms. ``t`` is the variance of the sandwich estimate ``H^-1 J H^-1``
    over that of the likelihood's ``2 / H`` (the signal's parameters at their fit,
    ``n_db`` at ``nug``). 1 without a signal and without shared noise: then each
    held-out error is the point's own and the likelihood exact. ``J`` is estimated
    from one realisation, so ``t`` scatters (about +-0.3 where the truth is 1).
    """
    from scipy.sparse import coo_matrix

    tgt, idx = setup[0], setup[2]
    if not (theta[1] > 0 and theta[2] > 0) and setup[4] is None:
        return 1.0  # no signal, no shared noise: a held-out error is the point's own
    x = np.log([max(float(nug), 1e-300), float(theta[1]) or 1e-300, float(theta[2]) or 1.0])
    res = _loo_eval(np.exp(x), kind, setup, resid, noise, True, True, True)
    h, g = float(res[2][0, 0]), res[3][0]
    if not (np.isfinite(h) and h > 0 and np.all(np.isfinite(g))):
        return 1.0
    pos = np.full(len(resid), -1)
    pos[tgt] = np.arange(len(tgt))
    nb = pos[idx]
    rows = np.broadcast_to(np.arange(len(tgt))[:, None], nb.shape)[nb >= 0]
    cols = nb[nb >= 0]
    s = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(tgt),) * 2).tocsr()
    s = ((s + s.T) > 0).astype(float)
    j = float(g @ g + g @ (s @ g))
    return float(np.clip(j / (2.0 * h), 1.0, max_factor))


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
