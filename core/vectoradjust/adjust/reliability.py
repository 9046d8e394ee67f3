"""Internal reliability of the bundle adjustment: redundancy numbers, w-test, MDB, snooping.

For the linearised model ``l + v = A x`` with weights ``P`` (a-priori reference variance
``sigma0^2``), the cofactor matrix of the residuals is ``Q_vv = P^-1 - A N^-1 A'`` with
``N = A'PA``. From it (``docs/method.md`` section 3, after Baarda 1968 and Foerstner 1987):

* redundancy numbers ``r_i = (Q_vv P)_ii``, ``0 <= r_i <= 1``, ``sum r_i = n - u``;
* Baarda's w-test ``w_i = v_i / (sigma0 sqrt(q_vv,ii))``, standard normal when the
  stochastic model holds and observation ``i`` has no blunder; an observation is flagged
  when ``|w_i| > k = Phi^-1(1 - alpha0/2)`` (3.2905 for ``alpha0 = 0.001``);
* the minimal detectable bias ``nabla_i = delta0 sigma0 sigma_i / sqrt(r_i)`` with
  ``delta0 = Phi^-1(1 - alpha0/2) + Phi^-1(1 - beta0)`` (4.1321 for 0.001 and 0.2): a
  blunder of that size is found with probability ``1 - beta0``;
* the estimated blunder (suspected error) ``-v_i / r_i`` (a blunder ``e`` in ``l_i``
  shows up as ``v_i = -r_i e``).

Why the a-priori sigma0 (Baarda's w) and not the a-posteriori one (Pope's tau): with
the a-priori value the statistic is exactly standard normal under the null hypothesis,
so the critical value and the MDB follow from the normal distribution alone; the
a-posteriori sigma0 is itself inflated by the blunder being looked for (it masks it) and
the resulting tau statistic follows Pope's tau distribution, whose critical value
depends on the redundancy. The a-priori model is the one the user states (image sigma
in micrometres, GCP sigmas), and a variance component estimation (:mod:`vce`) is the
way to make it right when it is not.

Point priors may carry a full 3x3 weight matrix ``W`` (GCPs with a covariance). For
them the test of component ``a`` uses the general form ``w = (W v)_a / (sigma0
sqrt((W Q_vv W)_aa))`` (Baarda's w for correlated observations), which is the
definition above when ``W`` is diagonal; the MDB is ``delta0 sigma0 /
sqrt((W Q_vv W)_aa)`` and the estimated blunder ``-(W v)_a / (W Q_vv W)_aa``.

Nothing here forms ``N^-1``: the pieces of it that each observation needs come from the
factorisation :func:`vectoradjust.adjust.bundle.adjust` keeps (``S^-1`` of the reduced camera
system, ``N_pp^-1`` and the per-observation ``N_ep`` blocks). Points seen by the same
set of images are processed together, so the cost is a few matrix products per image
set, not a loop over points. This module imports only numpy, scipy and heart modules.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Optional

import numpy as np
from scipy.special import ndtr, ndtri  # not scipy.stats: 0.5 s to import

from vectoradjust.adjust.bundle import (
    BundleProblem,
    BundleResult,
    _group_observations,
    _times_inverse,
    adjust,
    inv3x3,
)
from vectoradjust.errors import AdjustmentError, SingularityError
from vectoradjust.formatting import float_or_none as _num

__all__ = [
    "Reliability",
    "SnoopingResult",
    "critical_value",
    "noncentrality",
    "detection_power",
    "reliability",
    "flagged_observations",
    "data_snooping",
    "subset_problem",
    "EO_NAMES",
]

EO_NAMES = ("XL", "YL", "ZL", "omega", "phi", "kappa")
_CHUNK_OBS = 16384  # observations per block of the cofactors (as adjust.bundle)


def critical_value(alpha0: float = 0.001) -> float:
    """Two-sided critical value of the w-test, ``Phi^-1(1 - alpha0/2)``.

    Parameters
    ----------
    alpha0 : float
        Significance level of the test of one observation.

    Returns
    -------
    float
        3.2905 for ``alpha0 = 0.001``.
    """
    return float(ndtri(1.0 - 0.5 * float(alpha0)))


def noncentrality(alpha0: float = 0.001, beta0: float = 0.2) -> float:
    """Baarda's lower bound of the noncentrality, ``delta0``.

    A blunder that shifts ``w`` by ``delta0`` is detected with probability ``1 - beta0``
    (the small chance of ``w < -k`` is neglected, as in Baarda's definition).

    Parameters
    ----------
    alpha0 : float
        Significance level of the w-test.
    beta0 : float
        Probability of missing the blunder (power ``1 - beta0``).

    Returns
    -------
    float
        ``Phi^-1(1 - alpha0/2) + Phi^-1(1 - beta0)``: 4.1321 for 0.001 and 0.2.
    """
    return critical_value(alpha0) + float(ndtri(1.0 - float(beta0)))


def detection_power(shift, alpha0: float = 0.001) -> np.ndarray:
    """Probability that the two-sided w-test flags an observation whose w is shifted.

    Parameters
    ----------
    shift : array_like
        Expected value of ``w`` under the alternative, ``e sqrt(r) / sigma`` for a
        blunder ``e`` on an observation with standard deviation ``sigma`` and redundancy
        number ``r``.
    alpha0 : float

    Returns
    -------
    numpy.ndarray
        ``Phi(shift - k) + Phi(-shift - k)``.
    """
    k = critical_value(alpha0)
    s = np.abs(np.asarray(shift, float))
    return ndtr(s - k) + ndtr(-s - k)


@dataclass
class Reliability:
    """Reliability measures of every observation of an adjustment.

    Image observations are ``(k, 2)`` (x, y), point priors ``(m, 3)`` (X, Y, Z; NaN for
    points or axes without prior), EO priors ``(n, 6)`` (NaN for free parameters).
    Units: ``qvv`` in the observation's unit squared (mm^2, m^2, m^2 or rad^2), ``w``
    and ``r`` dimensionless, ``mdb`` in the observation's unit (mm, m, m or rad).

    Attributes
    ----------
    r_image, qvv_image, w_image, mdb_image : numpy.ndarray, shape (k, 2)
    flag_image : numpy.ndarray of bool, shape (k, 2)
    r_point, qvv_point, w_point, mdb_point : numpy.ndarray, shape (m, 3)
    flag_point : numpy.ndarray of bool, shape (m, 3)
    r_eo, qvv_eo, w_eo, mdb_eo : numpy.ndarray, shape (n, 6)
    flag_eo : numpy.ndarray of bool, shape (n, 6)
    q_point : numpy.ndarray, shape (m, 3, 3)
        Cofactor (``N^-1`` block) of every point; the covariance is
        ``sigma0_hat^2 q_point``.
    sigma0 : float
        A-priori reference standard deviation used in ``w`` and ``mdb``.
    alpha0, beta0 : float
    critical : float
        ``Phi^-1(1 - alpha0/2)``.
    delta0 : float
        Noncentrality bound (``critical + Phi^-1(1 - beta0)``).
    min_redundancy : float
        Observations with ``r`` below this are not tested (``w`` NaN, never flagged):
        their residual carries no information about their own error.
    sum_r : float
        Sum of all redundancy numbers; equals the degrees of freedom.
    dof : int
        Degrees of freedom of the adjustment.
    """

    r_image: np.ndarray
    qvv_image: np.ndarray
    w_image: np.ndarray
    mdb_image: np.ndarray
    flag_image: np.ndarray
    r_point: np.ndarray
    qvv_point: np.ndarray
    w_point: np.ndarray
    mdb_point: np.ndarray
    flag_point: np.ndarray
    r_eo: np.ndarray
    qvv_eo: np.ndarray
    w_eo: np.ndarray
    mdb_eo: np.ndarray
    flag_eo: np.ndarray
    q_point: np.ndarray
    sigma0: float
    alpha0: float
    beta0: float
    critical: float
    delta0: float
    min_redundancy: float
    sum_r: float
    dof: int
    suspected_image: np.ndarray = field(default=None, repr=False)
    suspected_point: np.ndarray = field(default=None, repr=False)
    suspected_eo: np.ndarray = field(default=None, repr=False)

    @property
    def n_flagged(self) -> int:
        """Number of flagged observations (all kinds)."""
        return int(self.flag_image.sum() + self.flag_point.sum() + self.flag_eo.sum())

    @property
    def max_abs_w_image(self) -> float:
        """Largest ``|w|`` of the image observations (NaN if none is tested)."""
        a = np.abs(self.w_image)
        return float(np.nanmax(a)) if np.isfinite(a).any() else float("nan")


# --------------------------------------------------------------------------- cofactors
def _cofactors(result: BundleResult):
    """Diagonal of ``A Q_xx A'`` for the image observations and ``Q_pp`` of every point.

    Returns
    -------
    aqa : numpy.ndarray, shape (k, 2)
    q_point : numpy.ndarray, shape (m, 3, 3)
    """
    prob = result.problem
    n = prob.n_images
    sinv4 = np.asarray(result.s_inv, float).reshape(n, 6, n, 6)
    npp_inv = np.asarray(result.npp_inv, float)
    nep = np.asarray(result.nep_obs, float)
    a_eo = np.asarray(result.a_eo, float)
    a_pt = np.asarray(result.a_pt, float)
    q_point = npp_inv.copy()
    aqa = np.zeros((len(prob.obs_point), 2))
    six = np.arange(6)
    groups = _group_observations(prob.obs_point, prob.obs_image, prob.n_points)
    for imgs, pts, obs in zip(groups.images, groups.points, groups.obs):
        c = len(imgs)
        sg = sinv4[np.ix_(imgs, six, imgs, six)].reshape(6 * c, 6 * c)
        sdiag = sinv4[imgs, :, imgs, :]  # (c, 6, 6): Q_ee(i, i)
        step = max(1, _CHUNK_OBS // c)
        for lo in range(0, len(pts), step):
            p = pts[lo: lo + step]
            o = obs[lo: lo + step].T  # (c, g), arrays below laid out (c, ..., g)
            qpp, aqa_o = _block_cofactors(nep[o], a_eo[o], a_pt[o], npp_inv[p], sg, sdiag)
            q_point[p] = qpp
            aqa[o] = aqa_o
    if result.offset_cofactor is not None:
        aqa, q_point = _offset_cofactors(result, aqa, q_point)
    return aqa, q_point


def _block_cofactors(nep, ae, ap, inv, sg, sdiag):
    """``Q_pp`` of ``g`` points seen by the same ``c`` images and ``diag(A Q A')`` of
    their image rows.

    ``nep (c, g, 6, 3)``, ``ae (c, g, 2, 6)``, ``ap (c, g, 2, 3)`` per observation,
    ``inv (g, 3, 3)`` = ``N_pp^-1``, ``sg (6c, 6c)`` = ``S^-1`` of the images, ``sdiag``
    its diagonal 6x6 blocks. Returns ``(g, 3, 3)`` and ``(c, g, 2)``; explicit products
    on arrays laid out ``(c, ..., g)`` (see :mod:`vectoradjust.adjust.bundle`).
    """
    c, g = nep.shape[:2]
    inv_t = inv.transpose(1, 2, 0)
    y = _times_inverse(np.ascontiguousarray(nep.transpose(0, 2, 3, 1)), inv_t)  # (c,6,3,g)
    # G = S^-1 Z' restricted to the images of the set (Q_ep = -G)
    gm = np.einsum("ab,bmg->amg", sg, y.reshape(6 * c, 3, g)).reshape(c, 6, 3, g)
    qpp = inv_t + (y.reshape(6 * c, 3, 1, g) * gm.reshape(6 * c, 1, 3, g)).sum(axis=0)
    qpp = 0.5 * (qpp + qpp.transpose(1, 0, 2))
    ae = ae.transpose(0, 2, 3, 1)  # (c, 2, 6, g)
    ap = ap.transpose(0, 2, 3, 1)  # (c, 2, 3, g)
    t_ee = (np.einsum("arig,aij->arjg", ae, sdiag) * ae).sum(axis=2)
    t_ep = ((ae[:, :, :, None, :] * gm[:, None]).sum(axis=2) * ap).sum(axis=2)
    t_pp = ((ap[:, :, :, None, :] * qpp[None, None]).sum(axis=2) * ap).sum(axis=2)
    return qpp.transpose(2, 0, 1), (t_ee - 2.0 * t_ep + t_pp).transpose(0, 2, 1)


def _offset_cofactors(result: BundleResult, aqa: np.ndarray, q_point: np.ndarray):
    """The database offsets' share of ``A Q A'``: image rows and point priors.

    With the offsets ``T`` (prior ``X_db = X + G T``) the joint cofactors are
    ``Q_x += (QB) Q_TT (QB)'``, ``Q_e += u Q_TT u'``, ``Q_ex += -u Q_TT (QB)'`` and
    ``Q_xT = -(QB) Q_TT``; so an image row ``a_e, a_p`` gains ``c Q_TT c'`` with
    ``c = a_p (QB) - a_e u``, and a point prior ``[I G]`` gains
    ``(QB - G) Q_TT (QB - G)'``.
    """
    prob = result.problem
    cof, qb, u, g = (result.offset_cofactor, result.offset_qb, result.offset_u,
                     result.offset_g)
    n = prob.n_images
    u_img = u.reshape(n, 6, -1)[prob.obs_image]  # (k, 6, q)
    # matmul on the stacks of small blocks (several times faster than einsum)
    c = np.matmul(result.a_pt, qb[prob.obs_point]) - np.matmul(result.a_eo, u_img)
    if getattr(result, "offset_a", None) is not None:  # self-calibration: rows' own partials
        c = c - result.offset_a
    aqa = aqa + (np.matmul(c, cof) * c).sum(axis=2)
    d = qb - g
    return aqa, q_point + np.matmul(np.matmul(d, cof), np.swapaxes(d, 1, 2))


# --------------------------------------------------------------------------- reliability
def _check_factorisation(result: BundleResult) -> None:
    """Raise :class:`AdjustmentError` if ``result`` lacks the kept factorisation."""
    if result.problem is None or result.s_inv is None or result.npp_inv is None \
            or result.nep_obs is None or result.a_eo is None or result.a_pt is None:
        raise AdjustmentError(
            "The adjustment result does not carry the normal-equation factorisation needed "
            "for reliability statistics",
            "Pass the BundleResult returned by vectoradjust.adjust.bundle.adjust",
        )


def _image_tests(result: BundleResult, aqa, s0, k_crit, d0, min_redundancy):
    """``r, q_vv, w, mdb, flag, suspected`` of the image observations (uncorrelated)."""
    prob = result.problem
    var = prob.obs_sigma**2
    qvv_i = var - aqa
    r_i = qvv_i / var
    v_i = np.asarray(result.v_image, float)
    tested = r_i >= min_redundancy
    with np.errstate(divide="ignore", invalid="ignore"):
        w_i = np.where(tested, v_i / (s0 * np.sqrt(np.where(tested, qvv_i, 1.0))), np.nan)
        mdb_i = np.where(r_i > 0, d0 * s0 * prob.obs_sigma / np.sqrt(np.maximum(r_i, 0.0)),
                         np.inf)
        sus_i = np.where(tested, -v_i / np.where(tested, r_i, 1.0), np.nan)
    flag_i = np.abs(np.nan_to_num(w_i)) > k_crit
    return r_i, qvv_i, w_i, mdb_i, flag_i, sus_i


def _point_tests(result: BundleResult, q_point, s0, k_crit, d0, min_redundancy):
    """``r, q_vv, w, mdb, flag, suspected`` of the point priors (``W`` possibly full)."""
    wgt = np.asarray(result.problem.prior_weight, float)
    has_axis = np.einsum("mii->mi", wgt) > 0
    qw = np.matmul(q_point, wgt)
    r_p = np.where(has_axis, 1.0 - np.einsum("mii->mi", qw), np.nan)
    wqw = wgt - np.matmul(wgt, qw)  # W Q_vv W = W - W Q_pp W
    d_wqw = np.einsum("mii->mi", wqw)
    det = np.linalg.det(wgt) if len(wgt) else np.zeros(0)
    cov = inv3x3(np.where((det > 0)[:, None, None], wgt, np.eye(3)))
    qvv_p = np.where(has_axis & (det > 0)[:, None],
                     np.einsum("mii->mi", cov) - np.einsum("mii->mi", q_point), np.nan)
    v_p = np.where(np.isfinite(result.v_point), result.v_point, 0.0)
    wv = np.einsum("mij,mj->mi", wgt, v_p)
    tested_p = has_axis & (r_p >= min_redundancy) & (d_wqw > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        safe = np.where(tested_p, d_wqw, 1.0)
        w_p = np.where(tested_p, wv / (s0 * np.sqrt(safe)), np.nan)
        mdb_p = np.where(has_axis, np.where(d_wqw > 0, d0 * s0 / np.sqrt(
            np.maximum(d_wqw, 1e-300)), np.inf), np.nan)
        sus_p = np.where(tested_p, -wv / safe, np.nan)
    flag_p = np.abs(np.nan_to_num(w_p)) > k_crit
    return r_p, qvv_p, w_p, mdb_p, flag_p, sus_p


def _eo_tests(result: BundleResult, s0, k_crit, d0, min_redundancy):
    """``r, q_vv, w, mdb, flag, suspected`` of the EO priors (diagonal)."""
    prob = result.problem
    n = prob.n_images
    we = prob.eo_weight
    has_eo = we > 0
    sdiag = np.einsum("iaia->ia", np.asarray(result.eo_cofactor()).reshape(n, 6, n, 6))
    with np.errstate(divide="ignore", invalid="ignore"):
        var_e = np.where(has_eo, 1.0 / np.where(has_eo, we, 1.0), np.nan)
        qvv_e = np.where(has_eo, var_e - sdiag, np.nan)
        r_e = np.where(has_eo, 1.0 - we * sdiag, np.nan)
        v_e = np.where(has_eo, result.v_eo, 0.0)
        tested_e = has_eo & (r_e >= min_redundancy)
        w_e = np.where(tested_e, v_e / (s0 * np.sqrt(np.where(tested_e, qvv_e, 1.0))), np.nan)
        mdb_e = np.where(has_eo, np.where(r_e > 0, d0 * s0 * np.sqrt(var_e)
                                          / np.sqrt(np.maximum(r_e, 1e-300)), np.inf), np.nan)
        sus_e = np.where(tested_e, -v_e / np.where(tested_e, r_e, 1.0), np.nan)
    flag_e = np.abs(np.nan_to_num(w_e)) > k_crit
    return r_e, qvv_e, w_e, mdb_e, flag_e, sus_e


def _cached_cofactors(result: BundleResult):
    """:func:`_cofactors` of a result, computed once: they depend on its factorisation
    and offsets only, not on sigma0 or the covariance scale (the run asks twice: for the
    groups' variance factor and for the w-tests)."""
    key = (result.s_inv, result.npp_inv, getattr(result, "offset_cofactor", None))
    cached = getattr(result, "_cofactor_cache", None)  # the same arrays (identity)
    if cached is not None and all(a is b for a, b in zip(cached[0], key)):
        return cached[1]
    value = _cofactors(result)
    try:
        result._cofactor_cache = (key, value)
    except AttributeError:  # a result type without a __dict__: recompute next time
        pass
    return value


def reliability(
    result: BundleResult,
    *,
    sigma0: float = 1.0,
    alpha0: float = 0.001,
    beta0: float = 0.2,
    min_redundancy: float = 1e-6,
) -> Reliability:
    """Redundancy numbers, Baarda's w-test and minimal detectable biases.

    Parameters
    ----------
    result : BundleResult
        A converged adjustment (its kept factorisation ``s_inv``, ``npp_inv``,
        ``nep_obs``, ``a_eo``, ``a_pt`` and ``problem`` are used).
    sigma0 : float
        A-PRIORI reference standard deviation (1 when the given sigmas are right).
    alpha0 : float
        Significance level of each observation's test (0.001: critical value 3.2905).
    beta0 : float
        Type II error for the MDB (0.2: power 80 %, ``delta0 = 4.1321``).
    min_redundancy : float
        Observations with a smaller redundancy number are not tested.

    Returns
    -------
    Reliability

    Raises
    ------
    AdjustmentError
        If the result does not carry the factorisation (not from :func:`adjust`).
    """
    _check_factorisation(result)
    s0 = float(sigma0)
    k_crit = critical_value(alpha0)
    d0 = noncentrality(alpha0, beta0)
    aqa, q_point = _cached_cofactors(result)
    r_i, qvv_i, w_i, mdb_i, flag_i, sus_i = _image_tests(result, aqa, s0, k_crit, d0,
                                                         min_redundancy)
    r_p, qvv_p, w_p, mdb_p, flag_p, sus_p = _point_tests(result, q_point, s0, k_crit, d0,
                                                         min_redundancy)
    r_e, qvv_e, w_e, mdb_e, flag_e, sus_e = _eo_tests(result, s0, k_crit, d0, min_redundancy)
    sum_r = float(np.sum(r_i) + np.nansum(r_p) + np.nansum(r_e))
    return Reliability(
        r_image=r_i, qvv_image=qvv_i, w_image=w_i, mdb_image=mdb_i, flag_image=flag_i,
        r_point=r_p, qvv_point=qvv_p, w_point=w_p, mdb_point=mdb_p, flag_point=flag_p,
        r_eo=r_e, qvv_eo=qvv_e, w_eo=w_e, mdb_eo=mdb_e, flag_eo=flag_e, q_point=q_point,
        sigma0=s0, alpha0=float(alpha0), beta0=float(beta0), critical=k_crit, delta0=d0,
        min_redundancy=float(min_redundancy), sum_r=sum_r, dof=int(result.dof),
        suspected_image=sus_i, suspected_point=sus_p, suspected_eo=sus_e,
    )


# --------------------------------------------------------------------------- reporting
def flagged_observations(
    rel: Reliability,
    result: BundleResult,
    point_ids,
    image_ids,
    point_kind=None,
) -> list:
    """The flagged observations as JSON-ready records, largest ``|w|`` first.

    Parameters
    ----------
    rel : Reliability
    result : BundleResult
        The adjustment ``rel`` was computed from.
    point_ids : sequence of str, length m
        Id of every bundle point.
    image_ids : sequence of str, length n
        Id of every image of the adjustment.
    point_kind : sequence of str, length m, optional
        ``"control"``, ``"shape"``, ``"tie"`` per point (copied into the records).

    Returns
    -------
    list of dict
        Keys ``kind`` (``"image"``, ``"point prior"``, ``"eo prior"``), ``image``,
        ``point``, ``point_kind``, ``observation`` (index of the image observation, or
        None), ``component`` (``x``/``y``, ``X``/``Y``/``Z`` or an EO name), ``unit``,
        ``residual``, ``w``, ``redundancy``, ``suspected_error`` (``-v/r``, the
        estimated blunder) and ``mdb``. Image coordinates are in micrometres, point
        priors and EO positions in metres, EO angles in degrees.
    """
    prob = result.problem
    pid = np.asarray(point_ids).astype(str)
    iid = np.asarray(image_ids).astype(str)
    kinds = None if point_kind is None else np.asarray(point_kind).astype(str)
    out = []
    k, a = np.nonzero(rel.flag_image)
    for kk, aa in zip(k.tolist(), a.tolist()):
        j = int(prob.obs_point[kk])
        out.append({
            "kind": "image", "image": str(iid[prob.obs_image[kk]]), "point": str(pid[j]),
            "point_kind": None if kinds is None else str(kinds[j]), "observation": kk,
            "component": "xy"[aa], "unit": "um",
            "residual": _num(1000.0 * result.v_image[kk, aa]), "w": _num(rel.w_image[kk, aa]),
            "redundancy": _num(rel.r_image[kk, aa]),
            "suspected_error": _num(1000.0 * rel.suspected_image[kk, aa]),
            "mdb": _num(1000.0 * rel.mdb_image[kk, aa]),
        })
    m, a = np.nonzero(rel.flag_point)
    for j, aa in zip(m.tolist(), a.tolist()):
        out.append({
            "kind": "point prior", "image": None, "point": str(pid[j]),
            "point_kind": None if kinds is None else str(kinds[j]), "observation": None,
            "component": "XYZ"[aa], "unit": "m", "residual": _num(result.v_point[j, aa]),
            "w": _num(rel.w_point[j, aa]), "redundancy": _num(rel.r_point[j, aa]),
            "suspected_error": _num(rel.suspected_point[j, aa]), "mdb": _num(rel.mdb_point[j, aa]),
        })
    i, a = np.nonzero(rel.flag_eo)
    for ii, aa in zip(i.tolist(), a.tolist()):
        scale = 1.0 if aa < 3 else float(np.degrees(1.0))
        out.append({
            "kind": "eo prior", "image": str(iid[ii]), "point": None, "point_kind": None,
            "observation": None, "component": EO_NAMES[aa], "unit": "m" if aa < 3 else "deg",
            "residual": _num(scale * result.v_eo[ii, aa]), "w": _num(rel.w_eo[ii, aa]),
            "redundancy": _num(rel.r_eo[ii, aa]),
            "suspected_error": _num(scale * rel.suspected_eo[ii, aa]),
            "mdb": _num(scale * rel.mdb_eo[ii, aa]),
        })
    out.sort(key=lambda d: -abs(d["w"] if d["w"] is not None else 0.0))
    return out


# --------------------------------------------------------------------------- snooping
@dataclass
class SnoopingResult:
    """Result of :func:`data_snooping`.

    Attributes
    ----------
    result : BundleResult
        Final adjustment (after every removal).
    problem : BundleProblem
        The problem of ``result`` (observations and points removed, images unchanged).
    removed : list of dict
        One record per removed measurement, in order: ``iteration``, ``observation``
        (index in the ORIGINAL problem), ``image``, ``point`` (original indices),
        ``component`` tested largest (``x``/``y``), ``w``, ``redundancy``,
        ``suspected_error_um`` (estimated blunder, micrometres), ``mdb_um``,
        ``dropped_points`` (original indices of points dropped because too few
        observations were left) and ``dropped_observations`` (their other measurements).
    reliability : Reliability
        Reliability of the final adjustment.
    observation_index : numpy.ndarray of int
        For each observation of ``problem``, its index in the original problem.
    point_index : numpy.ndarray of int
        For each point of ``problem``, its index in the original problem.
    clean : bool
        True when no image observation of the final adjustment is flagged (False when
        the removal limit stopped the procedure).
    iterations : int
        Adjustments run.
    """

    result: BundleResult
    problem: BundleProblem
    removed: list
    reliability: Reliability
    observation_index: np.ndarray
    point_index: np.ndarray
    clean: bool
    iterations: int


def subset_problem(problem: BundleProblem, keep_obs, keep_points=None):
    """A problem with only some image observations and points (images unchanged).

    Parameters
    ----------
    problem : BundleProblem
    keep_obs : array_like of bool, shape (k,)
        Observations to keep.
    keep_points : array_like of bool, shape (m,), optional
        Points to keep (default: all); observations of dropped points are dropped too.

    Returns
    -------
    sub : BundleProblem
    obs_index : numpy.ndarray of int
        Original index of each kept observation.
    point_index : numpy.ndarray of int
        Original index of each kept point.
    """
    keep_obs = np.asarray(keep_obs, bool).copy()
    if keep_points is None:
        keep_points = np.ones(problem.n_points, bool)
    keep_points = np.asarray(keep_points, bool)
    keep_obs &= keep_points[problem.obs_point]
    pmap = np.full(problem.n_points, -1, np.int64)
    point_index = np.flatnonzero(keep_points)
    pmap[point_index] = np.arange(len(point_index))
    obs_index = np.flatnonzero(keep_obs)
    sub = replace(
        problem,
        xyz0=problem.xyz0[point_index].copy(),
        prior_xyz=problem.prior_xyz[point_index].copy(),
        prior_weight=problem.prior_weight[point_index].copy(),
        obs_point=pmap[problem.obs_point[obs_index]],
        obs_image=problem.obs_image[obs_index].copy(),
        obs_xy=problem.obs_xy[obs_index].copy(),
        obs_sigma=problem.obs_sigma[obs_index].copy(),
    )
    return sub, obs_index, point_index


def data_snooping(
    problem: BundleProblem,
    *,
    alpha0: float = 0.001,
    beta0: float = 0.2,
    sigma0: float = 1.0,
    max_removals: Optional[int] = None,
    adjust_kwargs: Optional[dict] = None,
) -> SnoopingResult:
    """Baarda's iterative data snooping on the image measurements.

    Repeat: adjust, compute the w-test; if the largest ``|w|`` of an image coordinate
    exceeds the critical value, remove that measurement (its x AND y) and adjust again.
    A point without prior left on fewer than two images, or any point left without
    observations, is dropped as well (and reported). Only image measurements are
    removed; flagged priors (GCPs, shape points) stay in the reliability report.

    Parameters
    ----------
    problem : BundleProblem
    alpha0, beta0, sigma0 : float
        As in :func:`reliability`.
    max_removals : int, optional
        Stop after this many removed measurements (default: 10 % of them, at least 1).
    adjust_kwargs : dict, optional
        Passed to :func:`vectoradjust.adjust.bundle.adjust`.

    Returns
    -------
    SnoopingResult

    Raises
    ------
    SingularityError
        If a removal leaves the adjustment without a datum (the message names it).
    """
    kw = dict(adjust_kwargs or {})
    n_obs0 = len(problem.obs_point)
    if max_removals is None:
        max_removals = max(1, n_obs0 // 10)
    keep_obs = np.ones(n_obs0, bool)
    keep_pts = np.ones(problem.n_points, bool)
    removed: list = []
    cur, obs_index, point_index = problem, np.arange(n_obs0), np.arange(problem.n_points)
    iterations = 0
    while True:
        res = _adjust_after(cur, kw, removed)
        iterations += 1
        rel = reliability(res, sigma0=sigma0, alpha0=alpha0, beta0=beta0)
        aw = np.abs(rel.w_image)
        if not np.isfinite(aw).any() or np.nanmax(aw) <= rel.critical:
            return SnoopingResult(res, cur, removed, rel, obs_index, point_index, True,
                                  iterations)
        if len(removed) >= max_removals:
            return SnoopingResult(res, cur, removed, rel, obs_index, point_index, False,
                                  iterations)
        kc, comp = divmod(int(np.nanargmax(aw)), 2)
        removed.append(_remove(problem, rel, kc, comp, obs_index, keep_obs, keep_pts,
                               iterations))
        cur, obs_index, point_index = subset_problem(problem, keep_obs, keep_pts)


def _adjust_after(problem: BundleProblem, kw: dict, removed: list) -> BundleResult:
    """Adjust ``problem``; a singular system after removals names the last removal."""
    try:
        return adjust(problem, **kw)
    except SingularityError as exc:
        if not removed:
            raise
        last = removed[-1]
        raise SingularityError(
            f"Data snooping removed the measurement of point index {last['point']} on "
            f"image index {last['image']} (|w| = {abs(last['w']):.2f}) and the adjustment "
            f"became singular: {exc.what}",
            "Check that measurement and its neighbours by hand, or switch snooping off",
            details={"removed": removed},
        ) from exc


def _remove(problem: BundleProblem, rel: Reliability, kc: int, comp: int,
            obs_index: np.ndarray, keep_obs: np.ndarray, keep_pts: np.ndarray,
            iteration: int) -> dict:
    """Remove observation ``kc`` of the current problem (component ``comp`` tested largest).

    Clears it in ``keep_obs`` (original indexing, in place), drops the points left with
    too few observations (fewer than two without a prior, or none) from ``keep_pts``
    and ``keep_obs``, and returns the record of :attr:`SnoopingResult.removed`.
    """
    k0 = int(obs_index[kc])
    j0 = int(problem.obs_point[k0])
    keep_obs[k0] = False
    # points left with too few observations
    cnt = np.bincount(problem.obs_point[keep_obs], minlength=problem.n_points)
    drop = keep_pts & (((cnt < 2) & ~problem.has_prior) | (cnt == 0))
    dropped_pts = np.flatnonzero(drop)
    dropped_obs = np.flatnonzero(keep_obs & drop[problem.obs_point])
    keep_pts &= ~drop
    keep_obs &= keep_pts[problem.obs_point]
    return {
        "iteration": iteration, "observation": k0, "image": int(problem.obs_image[k0]),
        "point": j0, "component": "xy"[comp], "w": float(rel.w_image[kc, comp]),
        "redundancy": float(rel.r_image[kc, comp]),
        "suspected_error_um": float(1000.0 * rel.suspected_image[kc, comp]),
        "mdb_um": float(1000.0 * rel.mdb_image[kc, comp]),
        "dropped_points": dropped_pts.tolist(),
        "dropped_observations": dropped_obs.tolist(),
    }
