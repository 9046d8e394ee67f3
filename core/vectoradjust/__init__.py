"""vectoradjust: photogrammetric adjustment of road vectors.

The subpackages follow the data through the program (``docs/architecture.md``):
:mod:`~vectoradjust.sensor` (image coordinates and the sensor model) ->
:mod:`~vectoradjust.adjust` (shape points and the bundle adjustment) ->
:mod:`~vectoradjust.accuracy` (statistics and derived quantities) ->
:mod:`~vectoradjust.qa` (production accuracy control); :mod:`vectoradjust.pipeline` runs
one adjustment on in-memory data by calling those stages; :mod:`~vectoradjust.files`
reads and writes, :mod:`~vectoradjust.cli` is the command line and
:mod:`~vectoradjust.simulate` makes projects with known truth.

Everything below :mod:`vectoradjust.pipeline` imports only numpy and scipy. File input
and output (geopandas, pyogrio, rasterio, pyproj) live in :mod:`vectoradjust.files` and
are imported lazily, so that QGIS can use the heart without loading a second GDAL.
"""

from vectoradjust import _compat
from vectoradjust.errors import VectorAdjustError

__version__ = "0.3.0"

__all__ = ["VectorAdjustError", "__version__"]

_compat.install()
