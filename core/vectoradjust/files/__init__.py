"""Files: the project file, the input tables and layers, and every output.

- :mod:`~vectoradjust.files.project` - the project file (TOML).
- :mod:`~vectoradjust.files.tables` - the CSV tables (measurements, control, truth,
  fiducials), parsed with line numbers.
- :mod:`~vectoradjust.files.assemble` - tables and layers to
  :class:`~vectoradjust.model.ProjectData` (shared with the QGIS plugin).
- :mod:`~vectoradjust.files.readers` - line layers, DEMs and CRS transformations
  (geopandas, pyogrio, rasterio, pyproj; imported lazily).
- :mod:`~vectoradjust.files.truth` - ``[truth]`` centrelines and the buffer test against
  them.
- :mod:`~vectoradjust.files.outputs` - adjusted.gpkg / shapefiles and summary.json.
- :mod:`~vectoradjust.files.derived_outputs` - uncertainty bands and the equal-error
  GeoTIFF.
- :mod:`~vectoradjust.files.report` - report.html (matplotlib figures).
- :mod:`~vectoradjust.files.jsonfile` - strict JSON writing.

Only :mod:`project`, :mod:`tables`, :mod:`assemble` and :mod:`jsonfile` are free of
GDAL-based packages; the QGIS plugin uses those and never the others.
"""
