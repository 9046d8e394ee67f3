"""Bilinear interpolation of heights in a north-up DEM grid (numpy only).

The grid follows GDAL's convention: ``transform = (x_origin, dx, 0, y_origin, 0, -dy)``
(the affine ``(a, b, c, d, e, f)`` of rasterio is ``(dx, 0, x_origin, 0, -dy, y_origin)``;
:func:`bilinear` takes the GDAL order). Values are cell-centred ("pixel is area"):
cell ``(row, col)`` holds the height at ``x_origin + (col + 0.5) dx``,
``y_origin - (row + 0.5) dy``.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

__all__ = ["bilinear", "covered", "cell_window"]


def _fractional_indices(transform, xy: np.ndarray):
    x0, dx, rx, y0, ry, dy = (float(v) for v in transform)
    if rx != 0.0 or ry != 0.0:
        raise ValueError("rotated DEM grids are not supported")
    col = (xy[..., 0] - x0) / dx - 0.5
    row = (xy[..., 1] - y0) / dy - 0.5
    return row, col


def covered(grid: np.ndarray, transform, xy, nodata: Optional[float] = None) -> np.ndarray:
    """Whether each point can be interpolated (inside the grid, four valid neighbours).

    Parameters
    ----------
    grid : numpy.ndarray, shape (rows, cols)
    transform : sequence of 6 floats
        GDAL geotransform.
    xy : array_like, shape (n, 2)
    nodata : float, optional
        Nodata value of the grid (NaN cells are always invalid).

    Returns
    -------
    numpy.ndarray of bool, shape (n,)
    """
    z = bilinear(grid, transform, xy, nodata=nodata)
    return np.isfinite(z)


def bilinear(grid: np.ndarray, transform, xy, nodata: Optional[float] = None) -> np.ndarray:
    """Heights at ``xy`` by bilinear interpolation between cell centres.

    Points in the outer half cell are interpolated with the edge cells (clamped), so
    the whole raster extent is covered. Points outside the raster, or next to a nodata
    cell, get NaN.

    Parameters
    ----------
    grid : numpy.ndarray, shape (rows, cols)
        Heights.
    transform : sequence of 6 floats
        GDAL geotransform ``(x_origin, dx, 0, y_origin, 0, -dy)``.
    xy : array_like, shape (n, 2)
        Ground coordinates in the grid's CRS.
    nodata : float, optional
        Cells equal to it are invalid.

    Returns
    -------
    numpy.ndarray, shape (n,)
    """
    grid = np.asarray(grid, float)
    if nodata is not None and np.isfinite(nodata):
        grid = np.where(grid == nodata, np.nan, grid)
    xy = np.asarray(xy, float).reshape(-1, 2)
    nrow, ncol = grid.shape
    row, col = _fractional_indices(transform, xy)
    inside = (row >= -0.5) & (row <= nrow - 0.5) & (col >= -0.5) & (col <= ncol - 0.5)
    inside &= np.isfinite(row) & np.isfinite(col)
    row = np.clip(np.where(inside, row, 0.0), 0.0, nrow - 1.0)
    col = np.clip(np.where(inside, col, 0.0), 0.0, ncol - 1.0)
    r0 = np.minimum(np.floor(row).astype(np.int64), max(nrow - 2, 0))
    c0 = np.minimum(np.floor(col).astype(np.int64), max(ncol - 2, 0))
    r1 = np.minimum(r0 + 1, nrow - 1)
    c1 = np.minimum(c0 + 1, ncol - 1)
    fr = row - r0
    fc = col - c0
    z = (
        grid[r0, c0] * (1 - fr) * (1 - fc)
        + grid[r0, c1] * (1 - fr) * fc
        + grid[r1, c0] * fr * (1 - fc)
        + grid[r1, c1] * fr * fc
    )
    return np.where(inside, z, np.nan)


def cell_window(transform, shape: tuple, xy, margin: int = 2) -> Optional[tuple]:
    """The cells of a grid that :func:`bilinear` needs for the points ``xy``, with a margin:
    ``(row_lo, row_hi, col_lo, col_hi)`` (inclusive), clipped to the grid; None when no
    point is finite. For reading a window of a large DEM instead of all of it.

    Parameters
    ----------
    transform : sequence of 6 floats
        GDAL geotransform of the whole grid.
    shape : (int, int)
        ``(rows, cols)`` of the whole grid.
    xy : array_like, shape (n, 2)
    margin : int
        Cells added on each side beyond the bilinear neighbours.

    Examples
    --------
    >>> cell_window((0.0, 10.0, 0.0, 100.0, 0.0, -10.0), (10, 10), [[42.0, 58.0]])
    (1, 6, 1, 6)
    >>> cell_window((0.0, 10.0, 0.0, 100.0, 0.0, -10.0), (10, 10), [[np.nan, 1.0]]) is None
    True
    """
    xy = np.asarray(xy, float).reshape(-1, 2)
    xy = xy[np.isfinite(xy).all(axis=1)]
    if not len(xy):
        return None
    row, col = _fractional_indices(transform, xy)
    nrow, ncol = shape

    def clip(v, n):
        return int(np.clip(v, 0, n - 1))

    return (clip(np.floor(row.min()) - margin, nrow), clip(np.floor(row.max()) + margin + 1, nrow),
            clip(np.floor(col.min()) - margin, ncol), clip(np.floor(col.max()) + margin + 1, ncol))

