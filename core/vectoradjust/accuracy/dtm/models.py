"""Height models: the node grid, :class:`HeightModel` from points or from a DEM, and the
height models of a finished run.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np
from scipy.spatial import Delaunay

__all__ = [
    "NodeGrid", "HeightModel", "points_model", "dem_model", "run_points_model",
    "run_flying_height", "run_dem_model",
]


METHODS = ("tin", "bilinear", "bicubic")



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
