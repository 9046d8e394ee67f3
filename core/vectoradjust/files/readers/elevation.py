"""DEMs: read (rasterio), sampled at points, their heights in the project's datum.

:func:`read_dem` reads band 1 of a DEM GeoTIFF, :func:`sample_dem` interpolates it
bilinearly at points given in the project CRS, :func:`dem_heights` puts DEM heights in
the project's vertical datum.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import numpy as np

from vectoradjust.errors import CRSError, DEMError
from vectoradjust.files.project import ProjectSpec
from vectoradjust.files.readers.crs import (
    _project_target,
    _user_crs,
    _with_vertical,
    same_crs,
    transform_points,
    transformation_info,
)

__all__ = [
    "read_dem",
    "sample_dem",
    "dem_heights",
]


def dem_heights(z: np.ndarray, xy: np.ndarray, spec: ProjectSpec, project_crs, where: str):
    """DEM heights (top-level ``vertical_crs``) in the project's vertical datum.

    Returns ``(z, info)``; info is None when no datum change is asked for (no top-level
    ``vertical_crs``, or the project CRS states no other vertical datum).
    """
    target = _project_target(project_crs, spec, where)
    if not spec.vertical_crs or target is not project_crs:
        return z, None
    source = _with_vertical(project_crs, _user_crs(spec.vertical_crs, f"{where} vertical_crs"),
                            where)
    if same_crs(source, target):
        return z, None
    pts = np.column_stack([np.asarray(xy, float)[:, :2], z])
    out, info = transform_points(pts, source, target, where)
    return out[:, 2], info


def read_dem(path: str, target_crs=None):
    """Read band 1 of a DEM GeoTIFF.

    Returns
    -------
    grid : numpy.ndarray (rows, cols)
    transform : tuple
        GDAL geotransform.
    nodata : float or None
    crs : pyproj.CRS or None
    """
    import rasterio
    from pyproj import CRS

    p = Path(path)
    if not p.is_file():
        raise DEMError(f"DEM {str(p)!r} does not exist", "Check dem = in the [[vectors]] entry",
                       path=str(p))
    try:
        with rasterio.open(p) as ds:
            grid = ds.read(1).astype(float)
            gt = ds.transform.to_gdal()
            nodata = ds.nodata
            crs = CRS.from_wkt(ds.crs.to_wkt()) if ds.crs else None
    except rasterio.errors.RasterioIOError as exc:
        raise DEMError(f"{p}: cannot be read as a raster ({exc})", "Give a GeoTIFF DEM",
                       path=str(p)) from exc
    if gt[2] != 0 or gt[4] != 0:
        raise DEMError(f"{p}: the DEM grid is rotated", "Warp it to a north-up grid (gdalwarp)",
                       path=str(p))
    return grid, gt, nodata, crs


def sample_dem(path: str, xy: np.ndarray, project_crs, report: Optional[dict] = None
               ) -> np.ndarray:
    """Heights at ``xy`` (project CRS) by bilinear interpolation; NaN where uncovered.

    ``report``, when given, receives ``"crs"``: the transformation from the project CRS to
    the DEM's (:func:`transformation_info`; None when the DEM is in the project CRS), and
    then ``"grid"``: the DEM as a :class:`~vectoradjust.model.DemGrid`.
    """
    from pyproj import CRS

    from vectoradjust.adjust.dem import bilinear

    grid, gt, nodata, crs = read_dem(path)
    pts = np.asarray(xy, float)
    info = None
    if crs is None:
        raise CRSError(f"{path}: the DEM has no coordinate reference system",
                       "Assign the CRS to the GeoTIFF (gdal_edit.py -a_srs)", path=str(path))
    if not same_crs(crs, project_crs):
        pcrs = CRS.from_user_input(project_crs)
        finite = pts[np.isfinite(pts).all(axis=1)]
        bounds = (np.r_[finite.min(axis=0), finite.max(axis=0)] if len(finite) else None)
        t, info = transformation_info(pcrs, crs, bounds)
        x, y = t.transform(pts[:, 0], pts[:, 1])
        pts = np.column_stack([x, y])
    if report is not None:
        report["crs"] = info
        if info is None:  # in the project CRS: kept for heights at shifted positions
            from vectoradjust.model import DemGrid

            report["grid"] = DemGrid(grid, tuple(gt), nodata)
    return bilinear(grid, gt, pts, nodata=nodata)
