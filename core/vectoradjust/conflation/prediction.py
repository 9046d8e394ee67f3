"""The prediction at the unmeasured object points and the fitted displacement field that
makes it anywhere (:class:`FieldModel`), with the horizontal CE90 factor per axis.

Heart module: numpy and scipy only.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Optional

import numpy as np

from vectoradjust.conflation.ce90 import ce90_factor
from vectoradjust.conflation.covariance import CovarianceModel
from vectoradjust.conflation.coverage import DISTANCE_BANDS
from vectoradjust.conflation.fields import (
    _fields,
    _Trend,
    _trend,
    _trend_cov,
    _trend_design,
    _trend_field_cov,
)
from vectoradjust.conflation.images import (
    _image_scale,
    _mean_variance,
    _orientation_basis,
    _sill_prior,
    image_only,
)
from vectoradjust.conflation.kriging import _krige_many, band_factors

__all__ = ["FieldModel"]


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
        _calibrate(fh, xy_m, resid[:, :2], noise[:, :2].mean(axis=1), s.k)
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
    cov = _calibrated(cov, fh.band_factor, fh.nearest)
    model = FieldModel(xy_m, resid, noise, fh.cov, fv.cov, rec, tr.mean, tr.mean_var, s.k,
                       tr.fixed, extra, corr_v, fh.band_factor)
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


def _calibrate(fh, xy_m, resid, noise, k: int) -> None:
    """The horizontal field's variance calibration per distance band
    (:func:`band_factors`, from the measured points with a finite residual), in
    ``fh.band_factor`` and its cross-validation figures (summary.json)."""
    ok = np.isfinite(resid).all(axis=1)
    fh.band_factor = band_factors(fh.cov, xy_m[ok], resid[ok], noise[ok], k, DISTANCE_BANDS)
    fh.cv["band_factors"] = {"edges": [float(v) for v in DISTANCE_BANDS[:-1]],
                             "factors": [float(v) for v in fh.band_factor]}


def _calibrated(cov: np.ndarray, factor: Optional[np.ndarray], nearest: np.ndarray):
    """``cov`` (n, 3, 3) with its horizontal block times the calibration factor of each
    point's distance band (:func:`band_factors`; the X-Y covariances too, the
    covariances with Z by its root); unchanged without factors."""
    if factor is None or not len(cov):
        return cov
    band = np.clip(np.searchsorted(np.asarray(DISTANCE_BANDS), nearest, side="right") - 1,
                   0, len(factor) - 1)
    r = np.ones((len(cov), 3))
    r[:, :2] = np.sqrt(np.asarray(factor, float)[band])[:, None]
    return cov * r[:, :, None] * r[:, None, :]


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
    band_factor : numpy.ndarray, optional
        The horizontal variance's calibration per distance band (:func:`band_factors`).
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
    band_factor: Optional[np.ndarray] = None

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
            ((pred, kv, ws[i]),), near = _krige_many(
                [(cov, self.resid[ok][:, cols], self.noise[ok][:, cols].mean(axis=1), carry,
                  u)], self.xy[ok], xy, self.k)
            disp[:, cols] += pred
            var[:, cols] += (kv + cov.nugget)[:, None]
            if i == 0:
                wsum_h, ws[0] = _split_weight_sum(ws[0], len(xy))
                near_h = near
        tcov = _trend_cov(tr, slice(None), *ws)
        var = var + np.einsum("nii->ni", tcov)
        plug_in = var
        if self.cov_h is not None and self.band_factor is not None:
            # the calibration per distance band (near: that of the horizontal field)
            var = np.einsum("nii->ni", _calibrated(var[:, :, None] * np.eye(3), self.band_factor,
                                                    near_h))
        if not ce90_factor:
            return disp, var
        if self.cov_h is None:
            return disp, var, np.ones(len(xy))
        tfield = (np.zeros_like(tr.c) if self.trend_field_cov is None
                  else np.asarray(self.trend_field_cov, float))
        fcov = _trend_cov(replace(tr, c=tfield, fixed=np.zeros(3)), slice(None), *ws)
        cov = np.zeros((len(xy), 3, 3))  # the factor of the plug-in variance, as the vertices'
        cov[:, 0, 0], cov[:, 1, 1] = plug_in[:, 0], plug_in[:, 1]
        return disp, var, _horizontal_factor(self.cov_h, wsum_h, fcov, cov)
