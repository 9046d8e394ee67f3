"""Variance component estimation (Foerstner's iterative estimator) for the bundle adjustment.

The observations are split into groups that share an unknown variance factor: the image
coordinates, the control points, and each road database's shape points, the latter
usually split into a horizontal (``"OSM:h"``: X and Y from the database) and a vertical
group (``"OSM:v"``: Z from a DEM, far better than the XY). Starting from the given
sigmas, each group's factor is estimated as (``docs/method.md`` section 3)

    sigma_k^2 = v_k' P_k v_k / r_k,   r_k = sum of the redundancy numbers of group k,

the group's weights are divided by it (``P_k <- P_k / sigma_k^2``, i.e. its sigmas are
multiplied by ``sigma_k``) and the adjustment is repeated until every factor is 1 within
a tolerance. The sigmas then in use are the estimated standard deviations of the groups:
for a database's horizontal group, how accurate the database really is (in metres, per
axis). This replaces the manual two-pass procedure of the dissertation.

A group whose redundancy is (nearly) zero cannot be estimated (its residuals say nothing
about its accuracy): its factor stays 1 and a note says so. Points with a full 3x3 prior
weight matrix ``W`` are scaled as ``D W D`` with ``D = diag(1/sigma_k)`` of their axes'
groups, and their share of ``v'Pv`` is split over the axes as ``v_a (W v)_a`` (exact when
``W`` has no correlation between axes of different groups).

How precise an estimate is: the variance of ``sigma_k^2`` is about ``2 sigma_k^4 /
sum r_i^2`` over the group's observations (Foerstner; the diagonal of the Helmert matrix
``tr(Q_vv P_k Q_vv P_k)``), so a group of ``n`` observations whose redundancy numbers are
all ``r`` has a relative standard deviation ``sqrt(2 / n) / r``. Heights from a DEM that is
better than the stereo heights have ``r`` of a few percent: 3000 shape points then give
their vertical sigma only to +-15 %, too imprecise for an LE90 that covers the truth 85-95 %
of the time (which needs the sigma within -12 % / +19 %). With ``max_relative_sd`` such a
group is put back to its stated sigma and not estimated; a note gives the estimate with its
standard deviation.

This module imports only numpy and heart modules.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Optional

import numpy as np

from vectoradjust.adjust.bundle import BundleProblem, BundleResult, adjust
from vectoradjust.adjust.reliability import Reliability, reliability
from vectoradjust.errors import AdjustmentError

__all__ = ["VCEResult", "variance_components", "group_statistics"]

_RHO_MAX = 0.95  # largest convergence ratio extrapolated (step multiplied by at most 20)
_MAX_JUMP = float(np.log(10.0))  # an extrapolated step changes a variance 10-fold at most


@dataclass
class VCEResult:
    """Result of :func:`variance_components`.

    Attributes
    ----------
    result : BundleResult
        The adjustment with the final weights.
    problem : BundleProblem
        The problem with the final (estimated) sigmas and weights.
    reliability : Reliability
        Reliability of the final adjustment (a-priori sigma0 = 1).
    groups : list of str
        Group labels, in order of first appearance (image, point, EO labels).
    history : list of dict
        Per iteration: ``{"iteration", "factors": {group: sigma_k^2}, "redundancy":
        {group: r_k}}`` (factors of that iteration's adjustment, before rescaling).
    scale : dict of str to float
        Product over iterations of ``sqrt(factor)``: by how much each group's sigmas
        were multiplied.
    sigma : dict of str to float
        The group's final a-priori standard deviation in its unit (image coordinates:
        mm; point priors: m; EO priors: m or rad), the RMS over its members when their
        sigmas differ.
    sigma_initial : dict of str to float
        The same before the estimation.
    redundancy : dict of str to float
        ``r_k`` of the final adjustment.
    count : dict of str to int
        Number of (scalar) observations in each group.
    estimable : dict of str to bool
        False for a group with too little redundancy (kept at factor 1).
    iterations : int
        Adjustments run.
    converged : bool
        Whether every factor came within ``tol`` of 1.
    tol : float
        Convergence tolerance used.
    notes : list of str
        Human-readable remarks (groups not estimable, held at a bound, non-convergence).
    findings : list of dict
        Bounded groups held at their bound (``group``, ``estimated_ratio``, ``bound``,
        ``text``).
    relative_sd : dict of str to float
        Approximate relative standard deviation of each group's estimated variance,
        ``sqrt(2 / sum r_i^2)`` (final adjustment).
    imprecise : dict of str to dict
        Groups put back to their stated sigma because their estimate was too imprecise:
        ``{"sigma", "sigma_sd", "relative_sd"}`` of the estimate that was not applied.
    """

    result: BundleResult
    problem: BundleProblem
    reliability: Reliability
    groups: list
    history: list
    scale: dict
    sigma: dict
    sigma_initial: dict
    redundancy: dict
    count: dict
    estimable: dict
    iterations: int
    converged: bool
    tol: float = 1e-3
    notes: list = field(default_factory=list)
    findings: list = field(default_factory=list)
    relative_sd: dict = field(default_factory=dict)
    imprecise: dict = field(default_factory=dict)

    @property
    def factors(self) -> dict:
        """Each group's factor ``sigma_k^2`` in the last adjustment (1 = converged)."""
        return dict(self.history[-1]["factors"]) if self.history else {}

    @property
    def group_converged(self) -> dict:
        """Per group: whether its last factor is 1 within ``tol``."""
        return {g: abs(f - 1.0) < self.tol for g, f in self.factors.items()}


def _labels(value, shape: tuple, what: str) -> np.ndarray:
    """Broadcast a label (str) or an array of labels to ``shape`` (per component)."""
    if value is None:
        return np.full(shape, "", dtype=object).astype(str)
    a = np.asarray(value, dtype=object).astype(str)
    if a.ndim == 0:
        return np.full(shape, str(a), dtype=object).astype(str)
    if a.shape == shape[:1]:
        return np.repeat(a[:, None], shape[1], axis=1)
    if a.shape == shape:
        return a
    raise AdjustmentError(
        f"Variance component groups for the {what} have shape {a.shape}; expected "
        f"({shape[0]},) or {shape}",
        f"Give one label per {what.rstrip('s')} or one per {what.rstrip('s')} and axis",
    )


def _point_sigma(weight: np.ndarray) -> np.ndarray:
    """Per-axis standard deviation of point priors (NaN where no prior on that axis)."""
    d = np.einsum("mii->mi", weight)
    out = np.full(d.shape, np.nan)
    det = np.linalg.det(weight) if len(weight) else np.zeros(0)
    full = det > 0
    if full.any():
        out[full] = np.sqrt(np.einsum("mii->mi", np.linalg.inv(weight[full])))
    part = ~full[:, None] & (d > 0)
    out[part] = 1.0 / np.sqrt(d[part])
    return out


def group_statistics(result: BundleResult, rel: Reliability, obs_lab: np.ndarray,
                     pt_lab: np.ndarray, eo_lab: np.ndarray, groups: list):
    """``v'Pv``, redundancy and count of each group.

    Parameters
    ----------
    result : BundleResult
    rel : Reliability
    obs_lab, pt_lab, eo_lab : numpy.ndarray of str
        Labels per component, shapes (k, 2), (m, 3), (n, 6); ``""`` = in no group.
    groups : list of str

    Returns
    -------
    vtpv, redundancy : dict of str to float
    count : dict of str to int
    """
    prob = result.problem
    q_img = result.v_image**2 / prob.obs_sigma**2
    r_img = rel.r_image
    v_p = np.where(np.isfinite(result.v_point), result.v_point, 0.0)
    q_pt = v_p * np.einsum("mij,mj->mi", prob.prior_weight, v_p)
    r_pt = rel.r_point
    has_pt = np.isfinite(r_pt)
    we = prob.eo_weight
    v_e = np.where(we > 0, result.v_eo, 0.0)
    q_eo = we * v_e**2
    r_eo = rel.r_eo
    has_eo = we > 0
    vtpv, red, cnt = {}, {}, {}
    for g in groups:
        mi = obs_lab == g
        mp = (pt_lab == g) & has_pt
        me = (eo_lab == g) & has_eo
        vtpv[g] = float(q_img[mi].sum() + q_pt[mp].sum() + q_eo[me].sum())
        red[g] = float(r_img[mi].sum() + r_pt[mp].sum() + r_eo[me].sum())
        cnt[g] = int(mi.sum() + mp.sum() + me.sum())
    return vtpv, red, cnt


def _group_sigma(prob: BundleProblem, obs_lab, pt_lab, eo_lab, groups) -> dict:
    sp = _point_sigma(prob.prior_weight)
    se = np.where(prob.eo_weight > 0, prob.eo_sigma, np.nan)
    out = {}
    for g in groups:
        vals = np.concatenate([prob.obs_sigma[obs_lab == g], sp[(pt_lab == g) & np.isfinite(sp)],
                               se[(eo_lab == g) & np.isfinite(se)]])
        out[g] = float(np.sqrt(np.mean(vals**2))) if vals.size else float("nan")
    return out


def _rescale(prob: BundleProblem, factor: dict, obs_lab, pt_lab, eo_lab) -> BundleProblem:
    """Divide each group's weights by its factor (sigmas times sqrt(factor))."""
    def per(lab):
        s = np.ones(lab.shape)
        for g, f in factor.items():
            s[lab == g] = np.sqrt(f)
        return s

    s_img = per(obs_lab)
    s_pt = per(pt_lab)
    s_eo = per(eo_lab)
    d = 1.0 / s_pt
    weight = prob.prior_weight * d[:, :, None] * d[:, None, :]
    return replace(prob, obs_sigma=prob.obs_sigma * s_img, prior_weight=weight,
                   eo_sigma=prob.eo_sigma * s_eo)


def _group_labels(problem: BundleProblem, obs_group, prior_group, eo_group):
    """Per-component labels of images, point priors and EO priors, and the group order."""
    obs_lab = _labels(obs_group, (len(problem.obs_point), 2), "image observations")
    pt_lab = _labels(prior_group, (problem.n_points, 3), "points")
    eo_lab = _labels(eo_group, (problem.n_images, 6), "images")
    has_axis = np.einsum("mii->mi", problem.prior_weight) > 0
    pt_lab = np.where(has_axis, pt_lab, "")
    eo_lab = np.where(problem.eo_weight > 0, eo_lab, "")
    groups: list = []
    for lab in (obs_lab, pt_lab, eo_lab):
        for g in lab.ravel().tolist():
            if g and g not in groups:
                groups.append(g)
    if not groups:
        raise AdjustmentError("Variance component estimation was asked for no group",
                              "Label at least one observation group (e.g. 'image')")
    return obs_lab, pt_lab, eo_lab, groups


def _group_factors(groups, vtpv, red, estimable, frozen_at, it, min_redundancy) -> dict:
    """Each group's factor ``v'Pv / r``, 1 for frozen groups (updates estimable, frozen_at)."""
    factors = {}
    for g in groups:
        if not estimable[g] or red[g] < min_redundancy:
            if estimable[g]:
                estimable[g] = False
                frozen_at[g] = (it, red[g])
            factors[g] = 1.0
            continue
        if vtpv[g] <= 0:
            raise AdjustmentError(
                f"Variance component group {g!r} has zero residuals: its variance cannot "
                "be estimated",
                "Leave that group out of the estimation (label '')",
            )
        factors[g] = vtpv[g] / red[g]
    return factors


def _applied_factors(factors: dict, last_plain: dict, scale: dict, accelerate: bool) -> dict:
    """Factors to rescale by, Aitken-extrapolated if steps shrink (updates last_plain, scale)."""
    applied = {}
    for g, f in factors.items():
        step = float(np.log(f))
        prev = last_plain.get(g)
        rho = step / prev if prev else 0.0
        if accelerate and prev is not None and 0.0 < rho <= _RHO_MAX:
            # linear convergence with ratio rho: jump to the extrapolated limit
            ext = float(np.clip(step / (1.0 - rho), -_MAX_JUMP, _MAX_JUMP))
            applied[g] = float(np.exp(ext if abs(ext) > abs(step) else step))
            last_plain[g] = None
        else:
            applied[g] = f
            last_plain[g] = step
        scale[g] *= float(np.sqrt(applied[g]))
    return applied


def _hold_at_bounds(applied, scale, bounds, estimable, findings, factors, it) -> None:
    """Hold a bounded group at its bound (updates applied, scale, estimable, findings)."""
    for g, b in bounds.items():
        if g not in scale or not estimable.get(g, False):
            continue
        s = scale[g]
        if 1.0 / b <= s <= b:
            continue
        held = 1.0  # back to the stated sigma: a finding, not a weight to apply
        applied[g] *= (held / s) ** 2
        scale[g] = held
        estimable[g] = False
        findings.append({
            "group": g, "iteration": it, "bound": float(b),
            "estimated_ratio": float(s), "factor": float(factors[g]),
            "text": (f"FINDING: the sigma of group {g!r} was estimated at {s:.3g} times its "
                     f"stated value (bound {b:g}); the stated sigma is kept, the estimate is "
                     "not applied. The observations disagree with the stated accuracy of this "
                     "well-known group: look for a biased road database (estimate its "
                     "offset), blunders in the measurements, or a wrong stated sigma"),
        })


def _frozen_notes(groups, estimable, frozen_at, scale, min_redundancy, held=()) -> list:
    """Notes on the groups that were not estimated (too little redundancy)."""
    notes = []
    for g in groups:
        if not estimable[g] and g not in held:
            at, r_at = frozen_at[g]
            if at == 1:
                notes.append(f"group {g!r} has a total redundancy of {r_at:.3g} (< "
                             f"{min_redundancy:g}): its accuracy cannot be estimated from the "
                             "residuals and its sigma was kept")
            else:
                notes.append(f"group {g!r}: its total redundancy fell to {r_at:.3g} (< "
                             f"{min_redundancy:g}) at iteration {at} as its sigma shrank; it "
                             f"was frozen at {scale[g]:.4g} times its initial sigma, which is "
                             "not a reliable estimate (the group is not separable from the "
                             "others with this geometry)")
    return notes


def _nonconvergence_note(history: list, red: dict, tol: float, max_iterations: int) -> str:
    """The note that names the groups whose factor is not yet 1 within ``tol``."""
    slow = [f"{g!r} ({f:.4f}, redundancy {red[g]:.3g})"
            for g, f in history[-1]["factors"].items() if abs(f - 1.0) >= tol]
    return (f"variance component estimation did not converge in {max_iterations} "
            f"iterations: the factor of {', '.join(slow)} is not yet 1 within "
            f"{tol:g}; the last sigmas are reported (slow convergence means the group is "
            "weakly separable from the others, e.g. DEM heights from stereo heights, "
            "and its estimate is imprecise; raise max_iterations to go on)")


def variance_components(
    problem: BundleProblem,
    obs_group="image",
    prior_group=None,
    *,
    eo_group=None,
    max_iterations: int = 30,
    tol: float = 1e-3,
    min_redundancy: float = 1.0,
    accelerate: bool = True,
    adjust_kwargs: Optional[dict] = None,
    bounds: Optional[dict] = None,
    max_relative_sd: Optional[float] = None,
    precise_only=None,
) -> VCEResult:
    """Estimate the variance factor of each observation group (Foerstner).

    Parameters
    ----------
    problem : BundleProblem
        The adjustment with its initial sigmas.
    obs_group : str or array_like of str, shape (k,) or (k, 2)
        Group of every image observation (``""``: not estimated).
    prior_group : str or array_like of str, shape (m,) or (m, 3), optional
        Group of every point prior, per point or per point and axis (e.g. ``"OSM:h"``
        for X, Y and ``"OSM:v"`` for Z); ignored for points without prior; ``""`` or
        None: not estimated.
    eo_group : str or array_like of str, shape (n,) or (n, 6), optional
        Group of the EO priors (default: not estimated).
    max_iterations : int
        Adjustments at most.
    tol : float
        Converged when every factor is within ``tol`` of 1.
    min_redundancy : float
        Groups with a smaller total redundancy ``r_k`` are not estimated.
    accelerate : bool
        Foerstner's iteration converges linearly, slowly for groups that are weakly
        separable from others (e.g. DEM heights vs stereo heights). With ``accelerate``,
        a group whose last two plain steps ``log f`` shrink by a steady ratio
        ``0 < rho <= 0.95`` takes the extrapolated step ``log f / (1 - rho)`` (Aitken),
        every other iteration (changing the variance at most 10-fold). The fixed point
        and the convergence test (every factor
        of an actual adjustment within ``tol`` of 1) are unchanged.
    adjust_kwargs : dict, optional
        Passed to :func:`vectoradjust.adjust.bundle.adjust`.
    bounds : dict of str to float, optional
        Safeguards for well-known groups, e.g. ``{"image": 3.0, "control": 3.0}``: a
        group whose estimated sigma leaves ``[sigma / b, b sigma]`` of its stated value is
        put back to its stated sigma and not estimated further, and a finding in ``notes``
        (and ``findings``) says so: a control or image sigma estimated many times its stated
        value means the data disagree (a biased database, a blunder), not that the
        control is worse than surveyed.
    max_relative_sd : float, optional
        A group whose estimated variance has an (approximate) relative standard deviation
        ``sqrt(2 / sum r_i^2)`` above this at convergence is put back to its stated sigma,
        not estimated further, and the others are estimated again; ``notes`` gives the
        estimate that was not applied with its standard deviation. None: no such test.
    precise_only : callable, optional
        ``precise_only(group) -> bool``: which groups ``max_relative_sd`` applies to
        (default: all).

    Returns
    -------
    VCEResult

    Raises
    ------
    AdjustmentError
        If the labels do not fit the problem, or a group's residuals are all zero.
    NonConvergenceError, SingularityError
        From the adjustment.
    """
    kw = dict(adjust_kwargs or {})
    obs_lab, pt_lab, eo_lab, groups = _group_labels(problem, obs_group, prior_group, eo_group)
    st = _State(problem, obs_lab, pt_lab, eo_lab, groups, kw, int(max_iterations), float(tol),
                float(min_redundancy), bool(accelerate), dict(bounds or {}))
    st.iterate()
    while max_relative_sd is not None and st.drop_imprecise(max_relative_sd, precise_only):
        st.iterate()
    return st.finish(problem)


@dataclass
class _State:
    """The iteration of :func:`variance_components` and what it has found so far."""

    prob: BundleProblem
    obs_lab: np.ndarray
    pt_lab: np.ndarray
    eo_lab: np.ndarray
    groups: list
    kw: dict
    max_iterations: int
    tol: float
    min_redundancy: float
    accelerate: bool
    bounds: dict
    scale: dict = field(default_factory=dict)
    estimable: dict = field(default_factory=dict)
    frozen_at: dict = field(default_factory=dict)
    findings: list = field(default_factory=list)
    history: list = field(default_factory=list)
    imprecise: dict = field(default_factory=dict)
    relative_sd: dict = field(default_factory=dict)
    converged: bool = False
    res: Optional[BundleResult] = None
    rel: Optional[Reliability] = None
    red: dict = field(default_factory=dict)
    cnt: dict = field(default_factory=dict)
    it: int = 0

    def __post_init__(self):
        self.scale = {g: 1.0 for g in self.groups}
        self.estimable = {g: True for g in self.groups}

    def iterate(self) -> None:
        """Adjust and rescale until every factor is 1 within ``tol`` (or the limit)."""
        last_plain: dict = {}  # log-factor of each group's last plain (unextrapolated) step
        self.converged = False
        for k in range(self.max_iterations):
            self.it += 1
            self.res = adjust(self.prob, **self.kw)
            self.rel = reliability(self.res)
            vtpv, self.red, self.cnt = group_statistics(
                self.res, self.rel, self.obs_lab, self.pt_lab, self.eo_lab, self.groups)
            factors = _group_factors(self.groups, vtpv, self.red, self.estimable,
                                     self.frozen_at, self.it, self.min_redundancy)
            self.history.append({"iteration": self.it, "factors": dict(factors),
                                 "redundancy": dict(self.red)})
            if all(abs(f - 1.0) < self.tol for f in factors.values()):
                self.converged = True
                break
            if k + 1 == self.max_iterations:
                break
            applied = _applied_factors(factors, last_plain, self.scale, self.accelerate)
            _hold_at_bounds(applied, self.scale, self.bounds, self.estimable, self.findings,
                            factors, self.it)
            self.prob = _rescale(self.prob, applied, self.obs_lab, self.pt_lab, self.eo_lab)

    def drop_imprecise(self, max_relative_sd: float, precise_only) -> bool:
        """Put groups whose estimate is too imprecise back to their stated sigma."""
        self.relative_sd = group_relative_sd(self.rel, self.obs_lab, self.pt_lab, self.eo_lab,
                                             self.groups)
        now = _group_sigma(self.prob, self.obs_lab, self.pt_lab, self.eo_lab, self.groups)
        back = {}
        for g, rsd in self.relative_sd.items():
            if (not self.estimable[g] or g in self.imprecise or rsd <= max_relative_sd
                    or (precise_only is not None and not precise_only(g))):
                continue
            self.imprecise[g] = {"sigma": now[g], "sigma_sd": 0.5 * rsd * now[g],
                                 "relative_sd": rsd, "scale": self.scale[g],
                                 "bound": float(max_relative_sd)}
            back[g] = 1.0 / self.scale[g] ** 2
            self.scale[g] = 1.0
            self.estimable[g] = False
        if back:
            self.prob = _rescale(self.prob, back, self.obs_lab, self.pt_lab, self.eo_lab)
        return bool(back)

    def finish(self, problem: BundleProblem) -> VCEResult:
        """The :class:`VCEResult` of the iteration."""
        labs = (self.obs_lab, self.pt_lab, self.eo_lab, self.groups)
        if not self.relative_sd:
            self.relative_sd = group_relative_sd(self.rel, *labs)
        notes = _frozen_notes(self.groups, self.estimable, self.frozen_at, self.scale,
                              self.min_redundancy,
                              held=[f["group"] for f in self.findings] + list(self.imprecise))
        notes.extend(f["text"] for f in self.findings)
        notes.extend(_imprecise_note(g, e, _group_sigma(problem, *labs)[g])
                     for g, e in self.imprecise.items())
        if not self.converged:
            notes.append(_nonconvergence_note(self.history, self.red, self.tol,
                                              self.max_iterations))
        return VCEResult(
            result=self.res, problem=self.prob, reliability=self.rel, groups=self.groups,
            history=self.history, scale=self.scale, sigma=_group_sigma(self.prob, *labs),
            sigma_initial=_group_sigma(problem, *labs), redundancy=self.red, count=self.cnt,
            estimable=self.estimable, iterations=self.it, converged=self.converged,
            tol=self.tol, notes=notes, findings=self.findings, relative_sd=self.relative_sd,
            imprecise=self.imprecise,
        )


def group_relative_sd(rel: Reliability, obs_lab: np.ndarray, pt_lab: np.ndarray,
                      eo_lab: np.ndarray, groups: list) -> dict:
    """Approximate relative standard deviation of each group's variance estimate.

    ``sqrt(2 / sum r_i^2)`` over the group's observations (the diagonal of the Helmert
    matrix; exact for a group of independent observations whose redundancy is not shared
    with other groups' parameters).

    Parameters
    ----------
    rel : Reliability
    obs_lab, pt_lab, eo_lab : numpy.ndarray of str
        Labels per component (see :func:`group_statistics`).
    groups : list of str

    Returns
    -------
    dict of str to float
        ``inf`` for a group without redundancy.
    """
    r_pt = np.where(np.isfinite(rel.r_point), rel.r_point, 0.0)
    out = {}
    for g in groups:
        s2 = float(np.sum(rel.r_image[obs_lab == g] ** 2) + np.sum(r_pt[pt_lab == g] ** 2)
                   + np.sum(rel.r_eo[(eo_lab == g) & np.isfinite(rel.r_eo)] ** 2))
        out[g] = float(np.sqrt(2.0 / s2)) if s2 > 0 else float("inf")
    return out


def _imprecise_note(g: str, e: dict, stated: float) -> str:
    return (f"group {g!r}: its sigma was estimated at {e['sigma']:.3g} +- {e['sigma_sd']:.2g} "
            f"(+-{100 * e['relative_sd']:.0f} % in variance, more than the "
            f"{100 * e['bound']:.0f} % a 90 % accuracy figure can bear): too imprecise to "
            f"apply, the stated {stated:.3g} is used. Its redundancy is shared with the images "
            "(e.g. DEM heights better than the stereo heights); state the accuracy you know "
            "(for heights from a DEM: its vertical accuracy as the third value of sigma); a "
            "large stated sigma leaves the coordinate to the images")
