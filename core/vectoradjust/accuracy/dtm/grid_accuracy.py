"""Accuracy of a DTM product: the added terms (sampling, terrain variance, mean wavelength,
local mean slope) and :func:`dtm_product`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from vectoradjust.accuracy.dtm.interpolation import interpolate
from vectoradjust.accuracy.dtm.models import HeightModel, NodeGrid
from vectoradjust.accuracy.stats import LE90_FACTOR  # LE90 / sigma, normal error

__all__ = [
    "LI_B", "local_mean_slope", "sampling_per_mille", "sampling_sigma", "terrain_variance",
    "mean_wavelength", "DTMProduct", "dtm_product",
]


#: Li's constant ``b`` of the terrain term.
LI_B = 17.0 / 3072.0



#: Torlegard's per-mille of the flying height: (tan slope, per mille) at flat and mountains
_SAMPLING = ((0.05, 0.3e-3), (0.5, 1.5e-3))



def sampling_per_mille(tan_slope) -> np.ndarray:
    """Torlegard's height sigma as a fraction of the flying height, by the mean slope.

    0.3 per mille (the middle of 0.2-0.4) up to ``tan a = 0.05`` (flat), 1.5 per mille
    (the middle of 1-2, mountains) from ``tan a = 0.5``, linear in ``tan a`` between.
    """
    (t0, k0), (t1, k1) = _SAMPLING
    return np.interp(np.abs(np.asarray(tan_slope, float)), [t0, t1], [k0, k1])


def sampling_sigma(flying_height, tan_slope) -> np.ndarray:
    """Sampling sigma ``k(a) H`` (m) of photogrammetric heights (:func:`sampling_per_mille`)."""
    return sampling_per_mille(tan_slope) * np.asarray(flying_height, float)


def terrain_variance(cell, tan_slope, wavelength) -> np.ndarray:
    """Li's terrain term ``b (1 + 4 S / W) (S tan a)^2`` (m^2), ``b = 17/3072``.

    Parameters
    ----------
    cell : float
        Sampling interval ``S`` (m).
    tan_slope : float or array_like
        ``tan a``, the mean slope.
    wavelength : float
        Mean wavelength ``W`` of the terrain (m); ``inf`` gives ``b (S tan a)^2``.
    """
    s = np.asarray(cell, float)
    ratio = np.where(np.isfinite(wavelength), 4.0 * s / np.asarray(wavelength, float), 0.0)
    return LI_B * (1.0 + ratio) * (s * np.asarray(tan_slope, float)) ** 2


def mean_wavelength(heights: np.ndarray, cell: float) -> float:
    """Mean wavelength of a height grid: twice the mean run between zero crossings.

    The plane fitted to the valid heights is removed first; runs are counted along rows
    and columns. Without a crossing the grid's larger extent is returned.
    """
    h = np.asarray(heights, float)
    r, c = np.nonzero(np.isfinite(h))
    if r.size < 3:
        return float("inf")
    a = np.column_stack([np.ones(r.size), c, r])
    coef = np.linalg.lstsq(a, h[r, c], rcond=None)[0]
    d = np.full_like(h, np.nan)
    d[r, c] = h[r, c] - a @ coef
    crossings = 0
    length = 0
    for m in (d, d.T):
        s = np.sign(m)
        pair = np.isfinite(s[:, 1:]) & np.isfinite(s[:, :-1])
        crossings += int(np.sum(pair & (s[:, 1:] * s[:, :-1] < 0)))
        length += int(pair.sum())
    if crossings == 0:
        return float(max(h.shape) * cell)
    return float(2.0 * length * cell / crossings)


# -------------------------------------------------------------------------- product
@dataclass
class DTMProduct:
    """Per-cell heights and sigmas of a DTM (:func:`dtm_product`).

    Attributes
    ----------
    transform : tuple of 6 floats
        GDAL geotransform of the cells (values at the cell centres).
    height : numpy.ndarray, shape (rows, cols)
        Interpolated height (NaN outside the model).
    sigma_interpolation : numpy.ndarray, shape (rows, cols)
        ``sqrt(F Sigma F')``: from the covariance of the points / nodes.
    sigma : numpy.ndarray, shape (rows, cols)
        With the sampling and terrain terms added to the variance.
    le90 : numpy.ndarray, shape (rows, cols)
        ``1.6449 sigma``.
    tan_slope : numpy.ndarray, shape (rows, cols)
        Slope of the interpolated surface at the cell centre.
    sigma_sampling, sigma_terrain : float
        The added terms (m): their median over the cells with ``terms="local"``, the
        one value of the area with ``terms="area"``.
    sampling_cells, terrain_cells : numpy.ndarray, shape (rows, cols)
        The added terms per cell (m).
    summary : dict
        Method, terms and their inputs, statistics of ``sigma`` and ``le90``.
    model : HeightModel
    method : str
    nodes : NodeGrid or None
        The node grid of a points model's bilinear / bicubic surface.
    """

    transform: tuple
    height: np.ndarray
    sigma_interpolation: np.ndarray
    sigma: np.ndarray
    le90: np.ndarray
    tan_slope: np.ndarray
    sigma_sampling: float
    sigma_terrain: float
    summary: dict
    model: HeightModel
    method: str
    nodes: Optional[NodeGrid] = None
    sampling_cells: Optional[np.ndarray] = None
    terrain_cells: Optional[np.ndarray] = None

    def centres(self) -> np.ndarray:
        """Cell centres ``(rows * cols, 2)``, row-major."""
        return NodeGrid.from_geotransform(self.transform, self.height.shape).xy()


def _stats(v: np.ndarray) -> dict:
    f = v[np.isfinite(v)]
    if f.size == 0:
        return {"n": 0, "min": None, "mean": None, "median": None, "p90": None, "max": None}
    return {"n": int(f.size), "min": float(f.min()), "mean": float(f.mean()),
            "median": float(np.median(f)), "p90": float(np.percentile(f, 90)),
            "max": float(f.max())}


def _grid_frame(model: HeightModel, cell: float, bounds) -> tuple:
    """The cells' geotransform and shape over ``bounds`` (default: the model's extent)."""
    if bounds is None:
        if model.kind == "points":
            lo, hi = model.xyz[:, :2].min(axis=0), model.xyz[:, :2].max(axis=0)
        else:
            xy = model.grid.xy()
            lo, hi = xy.min(axis=0), xy.max(axis=0)
        bounds = (lo[0], lo[1], hi[0], hi[1])
    xmin, ymin, xmax, ymax = (float(v) for v in bounds)
    cols = max(int(np.ceil((xmax - xmin) / cell)), 1)
    rows = max(int(np.ceil((ymax - ymin) / cell)), 1)
    return (xmin, cell, 0.0, ymax, 0.0, -cell), (rows, cols)


def _sampling_interval(model: HeightModel, cell: float) -> float:
    """``S`` of Li's term: the TIN's mean edge length (points) or the node spacing (DEM)."""
    if model.kind == "dem":
        return float(np.hypot(model.grid.dx, model.grid.dy) / np.sqrt(2.0))
    edges = np.concatenate([model.tin.simplices[:, [0, 1]], model.tin.simplices[:, [1, 2]],
                            model.tin.simplices[:, [2, 0]]])
    edges = np.unique(np.sort(edges, axis=1), axis=0)
    xy = model.xyz[:, :2]
    spacing = float(np.mean(np.hypot(*(xy[edges[:, 0]] - xy[edges[:, 1]]).T)))
    return max(spacing, float(cell))


def local_mean_slope(tan_slope: np.ndarray, cell: float, window: float) -> np.ndarray:
    """The mean slope around each cell: ``tan a`` averaged over a square of side
    ``window`` (m; at least 3 x 3 cells, at most 101 x 101), NaN cells left out.

    :func:`dtm_product` takes one mean wavelength ``W`` (a whole rise and fall of the
    terrain, the scale of Torlegard's and Li's mean slopes), at most ten sampling
    intervals: a flat valley beside a steep flank then gets the flat terrain's terms
    and the flank its own.
    """
    from scipy.ndimage import uniform_filter

    t = np.asarray(tan_slope, float)
    k = int(np.clip(np.round(window / cell) if np.isfinite(window) else 101, 3, 101))
    k += 1 - k % 2
    ok = np.isfinite(t)
    num = uniform_filter(np.where(ok, t, 0.0), size=k, mode="nearest")
    den = uniform_filter(ok.astype(float), size=k, mode="nearest")
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(ok & (den > 0), num / den, np.nan)


def _added_terms(tan: np.ndarray, cell: float, w: float, s_len: float,
                 flying_height: Optional[float], terms: str) -> tuple:
    """Sampling sigma and terrain variance per cell (``terms`` local or area)."""
    if terms not in ("local", "area"):
        raise ValueError(f"terms {terms!r}: use 'local' or 'area'")
    mean_tan = float(np.nanmean(tan)) if np.isfinite(tan).any() else 0.0
    slope = (local_mean_slope(tan, cell, min(w, 10.0 * s_len)) if terms == "local"
             else np.where(np.isfinite(tan), mean_tan, np.nan))
    slope = np.where(np.isfinite(slope), slope, mean_tan)
    var_t = terrain_variance(s_len, slope, w)
    s_s = (np.zeros_like(slope) if flying_height is None
           else sampling_sigma(flying_height, slope))
    return mean_tan, s_s, var_t


def dtm_product(model: HeightModel, cell: float, method: str = "tin", *, bounds=None,
                flying_height: Optional[float] = None,
                wavelength: Optional[float] = None, terms: str = "local") -> DTMProduct:
    """Height, sigma and LE90 per cell of a DTM with its interpolation and added terms.

    Parameters
    ----------
    model : HeightModel
        :func:`points_model` (adjusted points) or :func:`dem_model`.
    cell : float
        Cell size (m). With a points model and ``bilinear`` / ``bicubic``, the nodes
        are the cell corners (heights from the TIN) and the cells' values are
        interpolated at their centres.
    method : {"tin", "bilinear", "bicubic"}
    bounds : (xmin, ymin, xmax, ymax), optional
        Default: the extent of the points / DEM nodes.
    flying_height : float, optional
        ``H`` (m) of the sampling term; None: no sampling term.
    wavelength : float, optional
        ``W`` (m) of the terrain term; default :func:`mean_wavelength` of the heights.
    terms : {"local", "area"}
        The slope of the sampling and terrain terms: each cell's
        :func:`local_mean_slope` (default), or the area's mean slope (one value).

    Returns
    -------
    DTMProduct
    """
    if not cell > 0:
        raise ValueError("cell must be positive")
    transform, shape = _grid_frame(model, cell, bounds)
    frame = NodeGrid.from_geotransform(transform, shape)
    nodes = None
    if model.kind == "points" and method != "tin":
        pad = 1 if method == "bilinear" else 2  # bicubic: one more ring of nodes
        nodes = NodeGrid(transform[0] - (pad - 1) * cell, transform[3] + (pad - 1) * cell,
                         cell, -cell, shape[0] + 2 * pad - 1, shape[1] + 2 * pad - 1)
    op, s_int = interpolate(model, frame.xy(), method, nodes)
    tan = np.hypot(op.gradient[:, 0], op.gradient[:, 1])
    h = op.h.reshape(shape)
    w = float(wavelength) if wavelength is not None else mean_wavelength(h, cell)
    s_len = _sampling_interval(model, cell)
    mean_tan, s_s, var_t = _added_terms(tan.reshape(shape), cell, w, s_len, flying_height,
                                        terms)
    s_s, var_t = s_s.ravel(), var_t.ravel()
    sigma = np.sqrt(s_int**2 + s_s**2 + var_t)
    valid = op.valid
    s_s_rep = float(np.median(s_s[valid])) if valid.any() else 0.0
    s_t_rep = float(np.sqrt(np.median(var_t[valid]))) if valid.any() else 0.0
    summary = {
        "method": method, "source": model.kind, "cell": float(cell),
        "cells": int(op.valid.sum()), "shape": list(shape),
        "mean_tan_slope": mean_tan, "mean_slope_percent": 100.0 * mean_tan, "terms": terms,
        "sampling": {"flying_height": flying_height,
                     "per_mille": float(sampling_per_mille(mean_tan)) * 1e3,
                     "sigma": s_s_rep, "cells": _stats(np.where(valid, s_s, np.nan)),
                     "source": "Torlegard: 0.3 per mille of H at <= 5 % "
                     "mean slope, 1.5 per mille at >= 50 %, linear between"},
        "terrain": {"b": LI_B, "sampling_interval": s_len, "wavelength": w,
                    "tan_slope": mean_tan, "sigma": s_t_rep,
                    "cells": _stats(np.where(valid, np.sqrt(var_t), np.nan)),
                    "source": "Li: b (1 + 4 S / W) (S tan a)^2"},
        "sigma_interpolation": _stats(s_int), "sigma": _stats(sigma), "le90": _stats(
            LE90_FACTOR * sigma)}
    if model.kind == "points":
        summary["points"] = int(len(model.xyz))
    else:
        summary.update(node_sigma=model.node_sigma, correlation_length=model.correlation_length)
    return DTMProduct(transform, h, s_int.reshape(shape), sigma.reshape(shape),
                      (LE90_FACTOR * sigma).reshape(shape), tan.reshape(shape), s_s_rep,
                      s_t_rep, summary, model, method, nodes, s_s.reshape(shape),
                      np.sqrt(var_t).reshape(shape))

