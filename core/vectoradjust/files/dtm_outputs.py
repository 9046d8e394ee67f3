"""Files of the DTM accuracy product (``vectoradjust dtm``).

* ``dtm_accuracy.tif``: float32 GeoTIFF, bands 1 height, 2 sigma Z (all terms),
  3 LE90, 4 sigma Z of the interpolation alone, 5 tan(slope); cells outside the DTM
  hold the nodata value.
* ``dtm_contours.gpkg``: layer ``contours`` (one LineString per contour segment, fields
  ``level``, ``sigma_z``, ``sigma_xy``, ``capped``) and ``contour_buffers`` (per level,
  the union of the segments' buffers of half-width ``sigma_xy`` at each end).

rasterio, geopandas and shapely are imported inside the functions.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vectoradjust.accuracy.dtm import ContourSegments, DTMProduct

__all__ = ["DTM_NODATA", "write_dtm_raster", "contour_frames", "write_contours"]

DTM_NODATA = -9999.0
_BANDS = ("height (m)", "sigma Z (m)", "LE90 (m)", "sigma Z interpolation (m)", "tan slope")


def write_dtm_raster(product: DTMProduct, path, crs, nodata: float = DTM_NODATA) -> str:
    """Write the product's cells as a 5-band float32 GeoTIFF (see the module notes).

    Parameters
    ----------
    product : DTMProduct
    path : str or os.PathLike
    crs : str or pyproj.CRS
        The project CRS.
    nodata : float

    Returns
    -------
    str
        The path written.
    """
    import rasterio
    from rasterio.transform import Affine

    gt = product.transform
    bands = np.stack([product.height, product.sigma, product.le90,
                      product.sigma_interpolation, product.tan_slope]).astype(np.float32)
    bands = np.where(np.isfinite(bands), bands, np.float32(nodata))
    if hasattr(crs, "to_wkt"):
        crs = crs.to_wkt()
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    with rasterio.open(p, "w", driver="GTiff", height=bands.shape[1], width=bands.shape[2],
                       count=len(_BANDS), dtype="float32", crs=crs,
                       transform=Affine(gt[1], gt[2], gt[0], gt[4], gt[5], gt[3]),
                       nodata=nodata, compress="deflate") as dst:
        dst.write(bands)
        for i, name in enumerate(_BANDS, start=1):
            dst.set_band_description(i, name)
        dst.update_tags(method=product.method, source=product.model.kind, units="m")
    return str(p)


def contour_frames(seg: ContourSegments, crs):
    """The ``contours`` and ``contour_buffers`` layers as GeoDataFrames.

    Parameters
    ----------
    seg : ContourSegments
    crs : str or pyproj.CRS

    Returns
    -------
    (geopandas.GeoDataFrame, geopandas.GeoDataFrame)
    """
    import geopandas as gpd
    import shapely

    lines = gpd.GeoDataFrame(
        {"level": seg.level, "sigma_z": seg.sigma_z.mean(axis=1),
         "sigma_xy": seg.sigma_xy.mean(axis=1), "capped": seg.capped.any(axis=1)},
        geometry=shapely.linestrings(seg.xy), crs=crs)
    polys = shapely.polygons(seg.buffer_rings()) if len(seg.level) else np.zeros(0, object)
    rows = []
    for level in np.unique(seg.level):
        k = seg.level == level
        rows.append({"level": float(level), "segments": int(k.sum()),
                     "mean_sigma_xy": float(seg.sigma_xy[k].mean()),
                     "max_sigma_xy": float(seg.sigma_xy[k].max()),
                     "geometry": shapely.union_all(shapely.buffer(polys[k], 0.0))})
    buffers = gpd.GeoDataFrame(rows, geometry="geometry", crs=crs) if rows else \
        gpd.GeoDataFrame({"level": []}, geometry=[], crs=crs)
    return lines, buffers


def write_contours(seg: ContourSegments, path, crs) -> str:
    """Write ``contours`` and ``contour_buffers`` into one GeoPackage (overwritten).

    Parameters
    ----------
    seg : ContourSegments
    path : str or os.PathLike
    crs : str or pyproj.CRS

    Returns
    -------
    str
    """
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    if p.exists():
        p.unlink()
    lines, buffers = contour_frames(seg, crs)
    lines.to_file(p, layer="contours", driver="GPKG")
    buffers.to_file(p, layer="contour_buffers", driver="GPKG")
    return str(p)
