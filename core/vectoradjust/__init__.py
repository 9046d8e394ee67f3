"""vectoradjust: photogrammetric adjustment of road vectors.

The numerical heart (:mod:`vectoradjust.collinearity`, :mod:`vectoradjust.bundle`,
:mod:`vectoradjust.stats`, ...) imports only numpy and scipy. File input and output
(geopandas, pyogrio, rasterio, pyproj) live in :mod:`vectoradjust.io` and are
imported lazily, so that QGIS can use the heart without loading a second GDAL.
"""

from vectoradjust.errors import VectorAdjustError

__version__ = "0.1.0"

__all__ = ["VectorAdjustError", "__version__"]
