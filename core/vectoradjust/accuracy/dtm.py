"""DTM and contour accuracy (Filin & Doytsher 1998; Torlegard; Li 1993).

A height interpolated in a DTM is a linear (first-order) function of the quantities
that define it: the adjusted points' X, Y, Z (a TIN, or a grid whose nodes were
interpolated from the points) or the heights of a DEM's nodes. Its variance is
``F Sigma F'`` with ``F`` the interpolation's Jacobian and ``Sigma`` the FULL
covariance of those quantities (``DESIGN.md`` section 6). Two further terms are added
to the variance:

* **sampling** (Torlegard et al. 1986): photogrammetric heights hold 0.2-0.4 per mille
  of the flying height ``H`` on flat terrain and 1-2 per mille in mountains. We take
  0.3 per mille up to a mean slope of 5 % and 1.5 per mille from 50 %, linear in the
  slope's tangent in between (:func:`sampling_sigma`).
* **terrain** (Li 1993): ``b (1 + 4 S / W) (S tan a)^2`` with ``b = 17/3072``, ``S``
  the sampling interval, ``a`` the mean slope and ``W`` the mean wavelength of the
  terrain (:func:`terrain_variance`; ``W`` from the zero crossings of the detrended
  heights, :func:`mean_wavelength`).

Both use each cell's own mean slope, averaged over about one wavelength around it (at
most ten sampling intervals; :func:`local_mean_slope`), so that a flat valley and a
steep flank beside it get their own terms; ``terms="area"`` gives the whole area one
value, as the sources do.

Interpolations (:func:`interpolation_operator`):

* ``tin``: linear in the Delaunay triangles of the points. Moving a vertex ``i``
  horizontally changes the height at ``q`` by ``-w_i(q) grad h`` (the surface is a
  plane in the triangle), so ``d h / d(X_i, Y_i, Z_i) = w_i (-g_x, -g_y, 1)``.
* ``bilinear`` and ``bicubic`` (Keys' cubic convolution, ``a = -1/2``) on a node grid.
  With adjusted points, the nodes are the cell corners and their heights the TIN's
  (``F = W_grid F_tin``). With a DEM, the nodes are its cells (GDAL "pixel is area":
  the cell centres) and their covariance ``sigma_n^2 exp(-d / L)`` (the DEM's stated
  node sigma and correlation length ``L``; ``L = 0``: independent nodes).

Products: per-cell sigma and LE90 (:func:`dtm_product`), contour segments with their
horizontal uncertainty ``sigma_z / tan(slope)`` (:func:`contour_segments`), profile
(:func:`profile_accuracy`) and volume (:func:`volume_accuracy`) standard deviations.

Heart module: numpy and scipy only.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np
from scipy import sparse
from scipy.spatial import Delaunay

from vectoradjust.accuracy.stats import LE90_FACTOR  # LE90 / sigma, normal error

__all__ = [
    "LI_B",
    "local_mean_slope",
    "LE90_FACTOR",
    "NodeGrid",
    "HeightModel",
    "Interpolated",
    "points_model",
    "dem_model",
    "interpolation_operator",
    "interpolate",
    "keys_weights",
    "sampling_per_mille",
    "sampling_sigma",
    "terrain_variance",
    "mean_wavelength",
    "DTMProduct",
    "dtm_product",
    "ContourSegments",
    "contour_segments",
    "ProfileAccuracy",
    "profile_accuracy",
    "VolumeAccuracy",
    "volume_accuracy",
    "points_in_polygon",
    "run_points_model",
    "run_flying_height",
    "run_dem_model",
]

#: Li's constant ``b`` of the terrain term.
LI_B = 17.0 / 3072.0
METHODS = ("tin", "bilinear", "bicubic")
#: Torlegard's per-mille of the flying height: (tan slope, per mille) at flat and mountains
_SAMPLING = ((0.05, 0.3e-3), (0.5, 1.5e-3))
_CHUNK = 1024


# --------------------------------------------------------------------------- models
@dataclass(frozen=True)
class NodeGrid:
    """A regular grid of height nodes: node ``(r, c)`` at ``(x0 + c dx, y0 + r dy)``.

    Attributes
    ----------
    x0, y0 : float
        Position of node ``(0, 0)``.
    dx, dy : float
        Spacing (``dy < 0`` for a north-up raster's rows).
    rows, cols : int
    """

    x0: float
    y0: float
    dx: float
    dy: float
    rows: int
    cols: int

    @classmethod
    def from_geotransform(cls, transform, shape) -> NodeGrid:
        """Nodes at the cell centres of a GDAL geotransform ``(x0, dx, 0, y0, 0, -dy)``."""
        gx, sx, rx, gy, ry, sy = (float(v) for v in transform)
        if rx != 0.0 or ry != 0.0:
            raise ValueError("rotated grids are not supported")
        return cls(gx + 0.5 * sx, gy + 0.5 * sy, sx, sy, int(shape[0]), int(shape[1]))

    def xy(self) -> np.ndarray:
        """Node positions ``(rows * cols, 2)`` in row-major order."""
        c, r = np.meshgrid(np.arange(self.cols), np.arange(self.rows))
        return np.column_stack([self.x0 + c.ravel() * self.dx, self.y0 + r.ravel() * self.dy])


@dataclass
class HeightModel:
    """What a DTM's heights are interpolated from, with its covariance.

    Attributes
    ----------
    kind : {"points", "dem"}
    xyz : numpy.ndarray, shape (n, 3)
        Adjusted points (``points``); empty for a DEM.
    covariance : numpy.ndarray, shape (3n, 3n) or None
        Full covariance of the points' X, Y, Z (``points``).
    grid : NodeGrid or None
        The DEM's nodes (``dem``).
    heights : numpy.ndarray, shape (rows, cols) or None
        The DEM's node heights (NaN: no data).
    node_sigma : float
        Stated sigma of a DEM node (m).
    correlation_length : float
        ``L`` of the node covariance ``sigma_n^2 exp(-d / L)`` (m; 0: independent).
    """

    kind: str
    xyz: np.ndarray
    covariance: Optional[np.ndarray] = None
    grid: Optional[NodeGrid] = None
    heights: Optional[np.ndarray] = None
    node_sigma: float = 0.0
    correlation_length: float = 0.0
    _tin: Optional[Delaunay] = field(default=None, repr=False)

    @property
    def tin(self) -> Delaunay:
        """The Delaunay triangulation of the points (built once)."""
        if self._tin is None:
            self._tin = Delaunay(self.xyz[:, :2])
        return self._tin

    def parameter_covariance(self, cols: np.ndarray) -> np.ndarray:
        """Covariance of the parameters ``cols`` (point coordinates or node indices)."""
        if self.kind == "points":
            return self.covariance[np.ix_(cols, cols)]
        g = self.grid
        r, c = np.divmod(cols, g.cols)
        xy = np.column_stack([c * g.dx, r * g.dy])
        d = np.sqrt(((xy[:, None, :] - xy[None, :, :]) ** 2).sum(axis=-1))
        s2 = self.node_sigma ** 2
        if self.correlation_length > 0:
            return s2 * np.exp(-d / self.correlation_length)
        return s2 * (d == 0)


def points_model(xyz, covariance) -> HeightModel:
    """A height model from adjusted points and their full covariance.

    Parameters
    ----------
    xyz : array_like, shape (n, 3)
    covariance : array_like, shape (3n, 3n)
        ``BundleResult.joint_covariance(points)`` (X, Y, Z per point).

    Returns
    -------
    HeightModel
    """
    xyz = np.asarray(xyz, float).reshape(-1, 3)
    cov = np.asarray(covariance, float)
    if cov.shape != (3 * len(xyz), 3 * len(xyz)):
        raise ValueError(f"covariance {cov.shape} does not match {len(xyz)} points")
    if len(xyz) < 3:
        raise ValueError("a TIN needs at least 3 points")
    return HeightModel("points", xyz, cov)


def dem_model(heights, transform, node_sigma: float, correlation_length: float = 0.0,
              nodata: Optional[float] = None) -> HeightModel:
    """A height model from a DEM whose nodes carry a stated sigma and correlation length.

    Parameters
    ----------
    heights : array_like, shape (rows, cols)
    transform : sequence of 6 floats
        GDAL geotransform (cell-centred values).
    node_sigma : float
        Sigma of a node height (m).
    correlation_length : float
        ``L`` of ``sigma_n^2 exp(-d / L)`` (m); 0: independent nodes.
    nodata : float, optional

    Returns
    -------
    HeightModel
    """
    h = np.array(heights, float)
    if nodata is not None:
        h[h == nodata] = np.nan
    if not node_sigma >= 0 or not correlation_length >= 0:
        raise ValueError("node_sigma and correlation_length must be >= 0")
    return HeightModel("dem", np.zeros((0, 3)), grid=NodeGrid.from_geotransform(transform, h.shape),
                       heights=h, node_sigma=float(node_sigma),
                       correlation_length=float(correlation_length))


# ------------------------------------------------------------------- interpolation
@dataclass
class Interpolated:
    """Heights at query points as a linear function of the model's parameters.

    Attributes
    ----------
    h : numpy.ndarray, shape (q,)
        Heights (NaN outside the model).
    jacobian : scipy.sparse.csr_matrix, shape (q, m)
        ``d h / d parameters`` (zero rows outside).
    gradient : numpy.ndarray, shape (q, 2)
        ``d h / d(X, Y)`` of the surface at the query points.
    valid : numpy.ndarray of bool, shape (q,)
    """

    h: np.ndarray
    jacobian: sparse.csr_matrix
    gradient: np.ndarray
    valid: np.ndarray


def keys_weights(t: np.ndarray, a: float = -0.5) -> np.ndarray:
    """Keys' cubic convolution weights of the nodes at ``-1, 0, 1, 2`` for offset ``t``.

    Parameters
    ----------
    t : numpy.ndarray
        Fractional position in ``[0, 1]``.
    a : float
        Kernel parameter (-1/2: third-order accurate).

    Returns
    -------
    numpy.ndarray, shape (..., 4)
        Weights (they sum to 1) and, second, their derivatives by ``t``.
    """
    t = np.asarray(t, float)
    s = np.stack([1 + t, t, 1 - t, 2 - t], axis=-1)
    sign = np.array([1.0, 1.0, -1.0, -1.0])  # d s / d t

    def k(s):
        near = (a + 2) * s**3 - (a + 3) * s**2 + 1
        far = a * s**3 - 5 * a * s**2 + 8 * a * s - 4 * a
        return np.where(s <= 1, near, far)

    def dk(s):
        near = 3 * (a + 2) * s**2 - 2 * (a + 3) * s
        far = 3 * a * s**2 - 10 * a * s + 8 * a
        return np.where(s <= 1, near, far)

    return np.stack([k(s), dk(s) * sign], axis=0)


def _axis_weights(frac: np.ndarray, n: int, method: str):
    """Node indices, weights and weight derivatives along one axis."""
    if method == "bilinear":
        i0 = np.clip(np.floor(frac), 0, max(n - 2, 0)).astype(np.int64)
        t = frac - i0
        idx = i0[:, None] + np.arange(2)
        w = np.column_stack([1 - t, t])
        dw = np.column_stack([-np.ones_like(t), np.ones_like(t)])
        ok = (frac >= 0) & (frac <= n - 1)
    else:
        i0 = np.clip(np.floor(frac), 1, max(n - 3, 1)).astype(np.int64)
        t = frac - i0
        idx = i0[:, None] + np.arange(-1, 3)
        w, dw = keys_weights(t)
        ok = (frac >= 1) & (frac <= n - 2)
    return idx, w, dw, ok


def _grid_operator(grid: NodeGrid, query: np.ndarray, method: str):
    """Sparse weights (q, nodes) of a grid interpolation and their X/Y derivatives."""
    fc = (query[:, 0] - grid.x0) / grid.dx
    fr = (query[:, 1] - grid.y0) / grid.dy
    ci, cw, cdw, cok = _axis_weights(fc, grid.cols, method)
    ri, rw, rdw, rok = _axis_weights(fr, grid.rows, method)
    k = ci.shape[1]
    node = (ri[:, :, None] * grid.cols + ci[:, None, :]).reshape(len(query), k * k)
    w = (rw[:, :, None] * cw[:, None, :]).reshape(len(query), -1)
    wx = (rw[:, :, None] * cdw[:, None, :]).reshape(len(query), -1) / grid.dx
    wy = (rdw[:, :, None] * cw[:, None, :]).reshape(len(query), -1) / grid.dy
    ok = cok & rok
    node = np.where(ok[:, None], np.clip(node, 0, grid.rows * grid.cols - 1), 0)
    rows = np.repeat(np.arange(len(query)), k * k)
    shape = (len(query), grid.rows * grid.cols)

    def mat(v):
        return sparse.csr_matrix((np.where(ok[:, None], v, 0.0).ravel(), (rows, node.ravel())),
                                 shape=shape)

    return mat(w), mat(wx), mat(wy), ok


def _tin_operator(model: HeightModel, query: np.ndarray) -> Interpolated:
    """Linear interpolation in the Delaunay triangles of the points."""
    tri = model.tin
    xyz = model.xyz
    # the directed walk of find_simplex can take seconds for points outside the hull
    # (scipy 1.17: 9 s for 2400 points on 600 triangles); brute force is linear in both
    s = tri.find_simplex(query, bruteforce=len(tri.simplices) < 20000)
    ok = s >= 0
    s0 = np.where(ok, s, 0)
    tr = tri.transform[s0]
    b2 = np.einsum("qij,qj->qi", tr[:, :2, :], query - tr[:, 2, :])
    w = np.column_stack([b2, 1 - b2.sum(axis=1)])
    verts = tri.simplices[s0]
    z = xyz[verts, 2]
    # plane gradient: grad h = sum_i z_i grad w_i, grad of (w0, w1) = rows of T
    gw = np.concatenate([tr[:, :2, :], -tr[:, :2, :].sum(axis=1, keepdims=True)], axis=1)
    g = np.einsum("qi,qij->qj", z, gw)
    h = np.where(ok, (w * z).sum(axis=1), np.nan)
    w = np.where(ok[:, None], w, 0.0)
    rows = np.repeat(np.arange(len(query)), 9)
    cols = (3 * verts[:, :, None] + np.arange(3)).reshape(-1)
    vals = np.stack([-w * g[:, 0:1], -w * g[:, 1:2], w], axis=-1).reshape(-1)
    jac = sparse.csr_matrix((vals, (rows, cols)), shape=(len(query), 3 * len(xyz)))
    return Interpolated(h, jac, np.where(ok[:, None], g, np.nan), ok)


def interpolation_operator(model: HeightModel, query, method: str = "tin",
                           nodes: Optional[NodeGrid] = None) -> Interpolated:
    """Heights at ``query`` and their Jacobian by the model's parameters.

    Parameters
    ----------
    model : HeightModel
    query : array_like, shape (q, 2)
    method : {"tin", "bilinear", "bicubic"}
        ``tin`` needs a points model. ``bilinear`` / ``bicubic`` interpolate in the
        DEM's nodes, or (points model) in ``nodes`` whose heights are the TIN's.
    nodes : NodeGrid, optional
        The node grid of a points model's bilinear / bicubic surface.

    Returns
    -------
    Interpolated
    """
    q = np.asarray(query, float).reshape(-1, 2)
    if method not in METHODS:
        raise ValueError(f"interpolation {method!r}: use one of {', '.join(METHODS)}")
    if method == "tin":
        if model.kind != "points":
            raise ValueError("TIN interpolation needs the adjusted points (a points model)")
        return _tin_operator(model, q)
    if model.kind == "points":
        if nodes is None:
            raise ValueError("bilinear / bicubic on points need the node grid (nodes=)")
        at = _tin_operator(model, nodes.xy())
        node_h = at.h
        node_jac = at.jacobian
    else:
        nodes = model.grid
        node_h = model.heights.ravel()
        node_jac = None
    w, wx, wy, ok = _grid_operator(nodes, q, method)
    bad_nodes = ~np.isfinite(node_h)
    if bad_nodes.any():
        ok &= np.asarray(abs(w)[:, bad_nodes].sum(axis=1)).ravel() == 0
        node_h = np.where(bad_nodes, 0.0, node_h)
    h = np.where(ok, w @ node_h, np.nan)
    g = np.column_stack([wx @ node_h, wy @ node_h])
    jac = w if node_jac is None else (w @ node_jac).tocsr()
    keep = sparse.diags(ok.astype(float))
    return Interpolated(h, (keep @ jac).tocsr(), np.where(ok[:, None], g, np.nan), ok)


def _covariance(model: HeightModel, ja: sparse.csr_matrix,
                jb: Optional[sparse.csr_matrix] = None, diagonal: bool = False) -> np.ndarray:
    """``J_a Sigma J_b'`` (or its diagonal) on the parameters the rows use."""
    jb = ja if jb is None else jb
    cols = np.union1d(ja.indices, jb.indices).astype(np.int64)
    if cols.size == 0:
        n = ja.shape[0]
        return np.zeros(n) if diagonal else np.zeros((n, jb.shape[0]))
    c = model.parameter_covariance(cols)
    a = ja[:, cols].toarray()
    b = jb[:, cols].toarray()
    if diagonal:
        return np.einsum("ij,ij->i", a @ c, b)
    return a @ c @ b.T


def _local_covariance(model: HeightModel, idx: np.ndarray) -> np.ndarray:
    """Covariance blocks ``(q, k, k)`` of the parameters ``idx`` (q, k) of each row."""
    if model.kind == "points":
        return model.covariance[idx[:, :, None], idx[:, None, :]]
    g = model.grid
    r, c = np.divmod(idx, g.cols)
    d = np.hypot((c[:, :, None] - c[:, None, :]) * g.dx, (r[:, :, None] - r[:, None, :]) * g.dy)
    if model.correlation_length > 0:
        return model.node_sigma ** 2 * np.exp(-d / model.correlation_length)
    return model.node_sigma ** 2 * (d == 0)


def _row_variance(model: HeightModel, jac: sparse.csr_matrix) -> np.ndarray:
    """``diag(J Sigma J')`` row by row from each row's own parameters."""
    jac = jac.tocsr()
    jac.sum_duplicates()
    nnz = np.diff(jac.indptr)
    out = np.zeros(jac.shape[0])
    k = int(nnz.max()) if nnz.size else 0
    if k == 0:
        return out
    chunk = max(1, 4_000_000 // (k * k))
    for i in range(0, jac.shape[0], chunk):
        sub = jac[i:i + chunk]
        n = np.diff(sub.indptr)
        pos = np.arange(k)[None, :] < n[:, None]
        idx = np.zeros((sub.shape[0], k), np.int64)
        w = np.zeros((sub.shape[0], k))
        idx[pos] = sub.indices
        w[pos] = sub.data
        out[i:i + chunk] = np.einsum("qi,qij,qj->q", w, _local_covariance(model, idx), w)
    return out


def interpolate(model: HeightModel, query, method: str = "tin",
                nodes: Optional[NodeGrid] = None, full: bool = False):
    """Heights at ``query`` with their propagated sigma (and full covariance).

    Parameters
    ----------
    model, query, method, nodes
        As :func:`interpolation_operator`.
    full : bool
        Also return the full covariance between the query heights.

    Returns
    -------
    (op, sigma) or (op, sigma, covariance)
        ``op`` the :class:`Interpolated`, ``sigma`` (q,) from ``F Sigma F'`` (NaN
        outside), and with ``full`` the (q, q) covariance.
    """
    op = interpolation_operator(model, query, method, nodes)
    if full:
        cov = _covariance(model, op.jacobian)
        var = np.diag(cov).copy()
    else:
        var = _row_variance(model, op.jacobian)
    sigma = np.where(op.valid, np.sqrt(np.clip(var, 0, None)), np.nan)
    return (op, sigma, cov) if full else (op, sigma)


# ------------------------------------------------------------------ added terms
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


# ------------------------------------------------------------------------- contours
@dataclass
class ContourSegments:
    """Contour segments of a DTM with their horizontal uncertainty.

    Attributes
    ----------
    level : numpy.ndarray, shape (m,)
    xy : numpy.ndarray, shape (m, 2, 2)
        Start and end point of each segment.
    sigma_z : numpy.ndarray, shape (m, 2)
        Height sigma at both ends (interpolated along the cell edges).
    tan_slope : numpy.ndarray, shape (m, 2)
    sigma_xy : numpy.ndarray, shape (m, 2)
        ``sigma_z / tan(slope)``, at most ``max_width`` (horizontal uncertainty).
    capped : numpy.ndarray of bool, shape (m, 2)
        Where the slope was too flat and ``max_width`` was used.
    """

    level: np.ndarray
    xy: np.ndarray
    sigma_z: np.ndarray
    tan_slope: np.ndarray
    sigma_xy: np.ndarray
    capped: np.ndarray

    def buffer_rings(self) -> np.ndarray:
        """Per segment the quadrilateral ``(m, 4, 2)`` reaching ``sigma_xy`` to each side.

        Its corners are the segment's ends moved by their own ``sigma_xy`` along the
        segment's normal, both ways; the union of a level's quadrilaterals is its
        contour's uncertainty buffer.
        """
        d = self.xy[:, 1] - self.xy[:, 0]
        n = np.column_stack([-d[:, 1], d[:, 0]])
        length = np.hypot(n[:, 0], n[:, 1])
        n = n / np.where(length > 0, length, 1.0)[:, None]
        w0, w1 = self.sigma_xy[:, 0:1], self.sigma_xy[:, 1:2]
        return np.stack([self.xy[:, 0] + w0 * n, self.xy[:, 1] + w1 * n,
                         self.xy[:, 1] - w1 * n, self.xy[:, 0] - w0 * n], axis=1)


# marching squares: corners 0 (r, c), 1 (r, c+1), 2 (r+1, c+1), 3 (r+1, c); edges
# 0 = 0-1, 1 = 1-2, 2 = 2-3, 3 = 3-0; case (bit k: corner k above) -> edge pairs
_EDGES = np.array([[0, 1], [1, 2], [3, 2], [0, 3]])
_CASES = {1: [(3, 0)], 2: [(0, 1)], 3: [(3, 1)], 4: [(1, 2)], 6: [(0, 2)], 7: [(3, 2)],
          8: [(2, 3)], 9: [(0, 2)], 11: [(1, 2)], 12: [(1, 3)], 13: [(0, 1)], 14: [(3, 0)]}
_SADDLES = {5: ([(0, 1), (2, 3)], [(3, 0), (1, 2)]), 10: ([(3, 0), (1, 2)], [(0, 1), (2, 3)])}


def _edge_points(fields: list, rr, cc, edge, level):
    """Crossing of ``level`` on an edge of each cell: values of every field there."""
    a, b = _EDGES[edge, 0], _EDGES[edge, 1]
    dr = np.array([0, 0, 1, 1])
    dc = np.array([0, 1, 1, 0])
    h = fields[0]
    ha = h[rr + dr[a], cc + dc[a]]
    hb = h[rr + dr[b], cc + dc[b]]
    t = np.clip((level - ha) / np.where(hb == ha, 1.0, hb - ha), 0.0, 1.0)
    return [f[rr + dr[a], cc + dc[a]] * (1 - t) + f[rr + dr[b], cc + dc[b]] * t
            for f in fields[1:]]


def _level_segments(fields: list, level: float) -> list:
    """Segments of one level: lists of per-field (k, 2) start and end values."""
    h = fields[0]
    q = [h[:-1, :-1], h[:-1, 1:], h[1:, 1:], h[1:, :-1]]
    ok = np.all([np.isfinite(v) for v in q], axis=0)
    case = sum(((v >= level) & ok).astype(int) << k for k, v in enumerate(q))
    case = np.where(ok, case, 0)
    centre = 0.25 * sum(np.where(ok, v, 0.0) for v in q)
    out = []
    for code in range(1, 15):
        rr, cc = np.nonzero(case == code)
        if rr.size == 0:
            continue
        if code in _SADDLES:
            hi = centre[rr, cc] >= level
            pairs_hi, pairs_lo = _SADDLES[code]
            groups = [(pairs_hi, hi), (pairs_lo, ~hi)]
        else:
            groups = [(_CASES[code], np.ones(rr.size, bool))]
        for pairs, sel in groups:
            for e0, e1 in pairs:
                p0 = _edge_points(fields, rr[sel], cc[sel], e0, level)
                p1 = _edge_points(fields, rr[sel], cc[sel], e1, level)
                out.append((p0, p1))
    return out


def contour_segments(product: DTMProduct, interval: float,
                     max_width: Optional[float] = None) -> ContourSegments:
    """Contours of a DTM product with the horizontal uncertainty ``sigma_z / tan a``.

    Marching squares on the cell-centre heights (saddles resolved by the cell's mean).
    Along a contour the height is fixed; a height error ``sigma_z`` moves it by
    ``sigma_z / tan a`` across the slope ``a`` (the gradient's magnitude; Filin &
    Doytsher's ``dh / (b + d (y - y0))`` along one axis).

    Parameters
    ----------
    product : DTMProduct
    interval : float
        Contour interval (m); levels are its multiples.
    max_width : float, optional
        Cap of ``sigma_xy`` where the terrain is flat; default 5 cells.

    Returns
    -------
    ContourSegments
    """
    if not interval > 0:
        raise ValueError("the contour interval must be positive")
    gt = product.transform
    rows, cols = product.height.shape
    cap = 5.0 * abs(gt[1]) if max_width is None else float(max_width)
    c, r = np.meshgrid(np.arange(cols), np.arange(rows))
    x = gt[0] + (c + 0.5) * gt[1]
    y = gt[3] + (r + 0.5) * gt[5]
    fields = [product.height, x, y, product.sigma, product.tan_slope]
    h = product.height[np.isfinite(product.height)]
    parts = []
    if h.size and rows > 1 and cols > 1:
        for level in np.arange(np.ceil(h.min() / interval), np.floor(h.max() / interval) + 1):
            for p0, p1 in _level_segments(fields, level * interval):
                parts.append((level * interval, p0, p1))
    if not parts:
        z = np.zeros((0, 2))
        return ContourSegments(np.zeros(0), np.zeros((0, 2, 2)), z, z, z, z.astype(bool))
    level = np.concatenate([np.full(len(p0[0]), lv) for lv, p0, _ in parts])

    def two(i):
        return np.concatenate([np.column_stack([p0[i], p1[i]]) for _, p0, p1 in parts])

    xy = np.stack([np.stack([two(0)[:, k], two(1)[:, k]], axis=-1) for k in range(2)], axis=1)
    sz, tan = two(2), two(3)
    with np.errstate(divide="ignore", invalid="ignore"):
        width = sz / tan
    capped = ~(width <= cap)
    return ContourSegments(level, xy, sz, tan, np.where(capped, cap, width), capped)


# ------------------------------------------------------------------ profile, volume
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


# ------------------------------------------------------------------- from a run
def run_points_model(run, kinds=("control", "tie", "shape")) -> HeightModel:
    """The adjusted points of a run with their FULL covariance (``joint_covariance``).

    Parameters
    ----------
    run : AdjustmentRun
        From :func:`vectoradjust.pipeline.run` (its factorisation not released).
    kinds : tuple of str
        Which bundle points define the surface.

    Returns
    -------
    HeightModel
    """
    idx = np.flatnonzero(np.isin(np.asarray(run.point_kind).astype(str), kinds)
                         & np.isfinite(run.result.xyz).all(axis=1))
    xyz = run.result.xyz[idx]
    _, first = np.unique(np.round(xyz[:, :2], 6), axis=0, return_index=True)
    idx = idx[np.sort(first)]  # one point per position (a TIN needs distinct XY)
    return points_model(run.result.xyz[idx], run.result.joint_covariance(idx))


def run_flying_height(run) -> Optional[float]:
    """Mean height of the frame images' stations above the median adjusted point (m).

    None with RPC images (no station): the sampling term is then left out.
    """
    prob = run.problem
    is_rpc = getattr(prob, "is_rpc", None)
    if is_rpc is not None and np.any(is_rpc):
        return None
    z = run.result.xyz[:, 2]
    return float(np.mean(run.result.eo[:, 2]) - np.median(z[np.isfinite(z)]))


def run_dem_model(run, node_sigma: Optional[float] = None,
                  correlation_length: float = 0.0) -> Optional[HeightModel]:
    """The first DEM of a run's road databases (held in the project CRS) as a model.

    Parameters
    ----------
    run : AdjustmentRun
    node_sigma : float, optional
        Sigma of a node (m); default the database's stated Z sigma.
    correlation_length : float
        ``L`` of the nodes' covariance (m).

    Returns
    -------
    HeightModel or None
        None when no database carries a DEM in the project CRS.
    """
    for spec, layer in getattr(run.data, "vectors", []) or []:
        d = getattr(layer, "dem", None)
        if d is not None:
            sigma = float(spec.sigma[2]) if node_sigma is None else float(node_sigma)
            return dem_model(d.grid, d.transform, sigma, correlation_length, d.nodata)
    return None
