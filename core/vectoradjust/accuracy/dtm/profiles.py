"""Accuracy of a profile and of a volume computed from a height model.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np
from scipy import sparse

from vectoradjust.accuracy.dtm.grid_accuracy import DTMProduct
from vectoradjust.accuracy.dtm.interpolation import (
    _covariance,
    _row_variance,
    interpolate,
    interpolation_operator,
)

__all__ = [
    "ProfileAccuracy", "profile_accuracy", "VolumeAccuracy", "volume_accuracy",
    "points_in_polygon",
]


@dataclass
class ProfileAccuracy:
    """Heights along a line with their sigmas and the sigmas of height differences.

    Attributes
    ----------
    xy : numpy.ndarray, shape (k, 2)
    chainage : numpy.ndarray, shape (k,)
    h, sigma : numpy.ndarray, shape (k,)
        Height and its sigma (interpolation covariance only).
    sigma_step : numpy.ndarray, shape (k - 1,)
        Sigma of ``h[i+1] - h[i]`` with the covariance between the samples.
    sigma_step_no_cov : numpy.ndarray, shape (k - 1,)
        The same without it (``sqrt(s_i^2 + s_j^2)``).
    sigma_rise, sigma_rise_no_cov : float
        Of the difference end minus start.
    covariance : numpy.ndarray, shape (k, k)
    """

    xy: np.ndarray
    chainage: np.ndarray
    h: np.ndarray
    sigma: np.ndarray
    sigma_step: np.ndarray
    sigma_step_no_cov: np.ndarray
    sigma_rise: float
    sigma_rise_no_cov: float
    covariance: np.ndarray

    def to_dict(self) -> dict:
        """JSON-ready copy (NaN as None)."""
        def lst(v):
            return [None if not np.isfinite(x) else float(x) for x in np.ravel(v)]

        return {"x": lst(self.xy[:, 0]), "y": lst(self.xy[:, 1]),
                "chainage": lst(self.chainage), "h": lst(self.h), "sigma": lst(self.sigma),
                "sigma_step": lst(self.sigma_step),
                "sigma_step_no_cov": lst(self.sigma_step_no_cov),
                "sigma_rise": lst([self.sigma_rise])[0],
                "sigma_rise_no_cov": lst([self.sigma_rise_no_cov])[0]}


def profile_accuracy(product: DTMProduct, line_xy, spacing: Optional[float] = None
                     ) -> ProfileAccuracy:
    """Profile along a polyline: sigma of each sample and of the height differences.

    Parameters
    ----------
    product : DTMProduct
        Its model, method and node grid are used (not its cells).
    line_xy : array_like, shape (n, 2)
        Polyline vertices (n >= 2).
    spacing : float, optional
        Sample spacing along the line (m); default the product's cell size.

    Returns
    -------
    ProfileAccuracy
    """
    v = np.asarray(line_xy, float).reshape(-1, 2)
    if len(v) < 2:
        raise ValueError("a profile needs at least two vertices")
    step = float(abs(product.transform[1]) if spacing is None else spacing)
    seg = np.hypot(*np.diff(v, axis=0).T)
    cum = np.r_[0.0, np.cumsum(seg)]
    ch = np.unique(np.r_[np.arange(0.0, cum[-1], step), cum[-1]])
    xy = np.column_stack([np.interp(ch, cum, v[:, 0]), np.interp(ch, cum, v[:, 1])])
    op, sigma, cov = interpolate(product.model, xy, product.method, product.nodes, full=True)
    d = np.diag(cov)
    step_var = d[1:] + d[:-1] - 2.0 * np.diag(cov, 1)
    rise = d[0] + d[-1] - 2.0 * cov[0, -1]
    return ProfileAccuracy(xy, ch, op.h, sigma, np.sqrt(np.clip(step_var, 0, None)),
                           np.sqrt(d[1:] + d[:-1]), float(np.sqrt(max(rise, 0.0))),
                           float(np.sqrt(d[0] + d[-1])), cov)


def points_in_polygon(xy, polygon) -> np.ndarray:
    """Even-odd rule: which of ``xy`` (q, 2) lie inside ``polygon`` (n, 2) (closed or not)."""
    p = np.asarray(xy, float).reshape(-1, 2)
    poly = np.asarray(polygon, float).reshape(-1, 2)
    inside = np.zeros(len(p), bool)
    x, y = p[:, 0], p[:, 1]
    for (x1, y1), (x2, y2) in zip(poly, np.roll(poly, -1, axis=0)):
        crosses = (y1 > y) != (y2 > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            xc = x1 + (y - y1) * (x2 - x1) / (y2 - y1)
        inside ^= crosses & (x < xc)
    return inside


@dataclass
class VolumeAccuracy:
    """Volume above a reference plane over a polygon, with its sigma.

    Attributes
    ----------
    volume : float
        ``A sum (h_c - z_ref)`` over the cell centres inside the polygon (m^3).
    sigma : float
        ``A sqrt(1' C 1)``: the summed covariance of the cell heights.
    sigma_no_cov : float
        ``A sqrt(sum sigma_c^2)``.
    area : float
    cells : int
    reference : float
    """

    volume: float
    sigma: float
    sigma_no_cov: float
    area: float
    cells: int
    reference: float

    def to_dict(self) -> dict:
        """JSON-ready copy."""
        return dict(self.__dict__)


def volume_accuracy(product: DTMProduct, polygon, reference: float) -> VolumeAccuracy:
    """Volume between the DTM and the plane ``z = reference`` over a polygon.

    The cells of the product whose centres lie inside the polygon (and in the DTM)
    each contribute ``A (h_c - z_ref)``; ``sigma^2 = A^2 f Sigma f'`` with ``f`` the sum
    of their Jacobian rows (the reference plane is exact).

    Parameters
    ----------
    product : DTMProduct
    polygon : array_like, shape (n, 2)
    reference : float
        Height of the reference plane (m).

    Returns
    -------
    VolumeAccuracy
    """
    centres = product.centres()
    inside = points_in_polygon(centres, polygon)
    op = interpolation_operator(product.model, centres[inside], product.method, product.nodes)
    ok = op.valid
    area = abs(product.transform[1] * product.transform[5])
    f = sparse.csr_matrix(op.jacobian[np.flatnonzero(ok)].sum(axis=0))
    var = float(_covariance(product.model, f)[0, 0]) if ok.any() else 0.0
    var_cells = _row_variance(product.model, op.jacobian)
    return VolumeAccuracy(float(area * np.sum(op.h[ok] - reference)),
                          float(area * np.sqrt(max(var, 0.0))),
                          float(area * np.sqrt(np.sum(var_cells[ok]))), float(area * ok.sum()),
                          int(ok.sum()), float(reference))
