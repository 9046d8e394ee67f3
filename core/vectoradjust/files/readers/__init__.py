"""File input: vector layers (pyogrio/geopandas), DEMs (rasterio), CRSs (pyproj).

The geospatial libraries are imported inside the functions, never at module import,
so that importing :mod:`vectoradjust` does not load a second GDAL into QGIS.

The package's modules:

- :mod:`~vectoradjust.files.readers.loading` - :func:`load_project_data`: every file of
  a project into :class:`~vectoradjust.model.ProjectData`; :func:`read_rpc_images`.
- :mod:`~vectoradjust.files.readers.layers` - line layers: :func:`line_layers`,
  :func:`choose_layer`, :func:`read_line_layer`, :func:`layer_from_geometries`.
- :mod:`~vectoradjust.files.readers.crs` - CRSs: :func:`check_projected_crs`,
  :func:`same_crs`, :func:`transformation_info`, :func:`transform_points`,
  :func:`control_to_project_crs`.
- :mod:`~vectoradjust.files.readers.elevation` - DEMs: :func:`read_dem`,
  :func:`sample_dem`, :func:`dem_heights`.

The package re-exports every public name of its modules (and ``_parts``, which
``vectoradjust measure`` uses).
"""

from __future__ import annotations

from vectoradjust.files.readers.crs import (
    TRANSFORMATION_ACCURACY_LIMIT,
    check_projected_crs,
    control_to_project_crs,
    same_crs,
    transform_points,
    transformation_info,
)
from vectoradjust.files.readers.crs import _parts as _parts
from vectoradjust.files.readers.elevation import (
    dem_heights,
    read_dem,
    sample_dem,
)
from vectoradjust.files.readers.layers import (
    EXACT_REAL_INTEGER,
    choose_layer,
    layer_from_geometries,
    line_layers,
    read_line_layer,
)
from vectoradjust.files.readers.loading import (
    load_project_data,
    read_rpc_images,
)

__all__ = [
    "check_projected_crs",
    "choose_layer",
    "control_to_project_crs",
    "transform_points",
    "line_layers",
    "read_line_layer",
    "transformation_info",
    "same_crs",
    "read_dem",
    "sample_dem",
    "load_project_data",
    "layer_from_geometries",
    # public in the modules too
    "TRANSFORMATION_ACCURACY_LIMIT",
    "EXACT_REAL_INTEGER",
    "dem_heights",
    "read_rpc_images",
]
