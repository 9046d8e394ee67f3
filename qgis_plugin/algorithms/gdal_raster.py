"""Float32 rasters written through QGIS's own GDAL (the DTM accuracy and equal-error maps).

The plugin must not import rasterio (a second GDAL); this writes the core's grids with
``osgeo.gdal`` as QGIS ships it: the driver chosen by the file extension (GeoTIFF by
default, DEFLATE-compressed), one named band per grid, the non-finite cells as nodata.
"""

import os

import numpy as np
from qgis.core import QgsCoordinateReferenceSystem, QgsRasterFileWriter

__all__ = ["write_float_bands"]


def write_float_bands(path, bands, geotransform, crs, names, nodata, metadata, what):
    """Write ``bands`` (shape ``(n, rows, cols)``) as a Float32 raster of ``n`` bands.

    Parameters
    ----------
    path : str
        Output file; its extension chooses the GDAL driver (GeoTIFF without one).
    bands : numpy.ndarray, shape (n, rows, cols)
        The grids; NaN and infinite cells are written as ``nodata``.
    geotransform : sequence of 6 float
        GDAL geotransform (``x0, dx, 0, y0, 0, -dy``).
    crs : QgsCoordinateReferenceSystem
    names : sequence of str
        Band descriptions, one per band.
    nodata : float
    metadata : dict
        Dataset metadata (``units`` ...).
    what : str
        How messages name the raster (e.g. ``"the equal-error map"``).

    Returns
    -------
    str
        ``path``.

    Raises
    ------
    InputFileError
        No GDAL driver for the extension, or the file cannot be created.
    """
    from osgeo import gdal

    from vectoradjust.errors import InputFileError

    bands = np.asarray(bands).astype(np.float32)
    bands = np.where(np.isfinite(bands), bands, np.float32(nodata))
    ext = os.path.splitext(path)[1].lstrip(".").lower()
    driver = gdal.GetDriverByName((QgsRasterFileWriter.driverForExtension(ext) if ext else "")
                                  or "GTiff")
    if driver is None:
        raise InputFileError(f"Cannot write {path!r}: GDAL has no driver for .{ext} files",
                             f"Save {what} as a GeoTIFF (.tif)", path=path)
    options = ["COMPRESS=DEFLATE"] if driver.ShortName == "GTiff" else []
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    ds = driver.Create(path, int(bands.shape[2]), int(bands.shape[1]), len(names),
                       gdal.GDT_Float32, options=options)
    if ds is None:
        raise InputFileError(f"Cannot write {what} {path!r} ({gdal.GetLastErrorMsg()})",
                             "Choose a writable output path", path=path)
    ds.SetGeoTransform(tuple(float(v) for v in geotransform))
    ds.SetProjection(crs.toWkt(QgsCoordinateReferenceSystem.WKT_PREFERRED_GDAL))
    for i, name in enumerate(names, start=1):
        band = ds.GetRasterBand(i)
        band.SetNoDataValue(nodata)
        band.WriteArray(bands[i - 1])
        band.SetDescription(name)
    ds.SetMetadata(metadata)
    ds.FlushCache()
    ds = None
    return path
