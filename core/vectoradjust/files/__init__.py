"""Files: the project file, the input tables and layers, and every output.

- :mod:`~vectoradjust.files.project` - the project file (TOML).
- :mod:`~vectoradjust.files.csv_tables` - the CSV tables (measurements, control, truth,
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
- :mod:`~vectoradjust.files.dtm_outputs` - the files of ``vectoradjust dtm``.
- :mod:`~vectoradjust.files.smart_outputs` - smart conflation's files.
- :mod:`~vectoradjust.files.images`, :mod:`~vectoradjust.files.measuring` - image windows,
  chips and measurement tables; measuring on the images of a project.
- :mod:`~vectoradjust.files.measure_rows` - the measurement layer's rows, the transfer's
  terrain height and the RPC bias line (the command line and the QGIS plugin share them).
- :mod:`~vectoradjust.files.rpc`, :mod:`~vectoradjust.files.rpc_ties` - RPC files and the
  ground frame; automatic tie points between satellite images.
- :mod:`~vectoradjust.files.drone`, :mod:`~vectoradjust.files.trajectory` - drone images
  into a project; GNSS/INS camera positions from a trajectory CSV.
- :mod:`~vectoradjust.files.study`, :mod:`~vectoradjust.files.study_report` - the
  dissertation's experiments and their report.
- :mod:`~vectoradjust.files.many` - many independent projects at once, on Dask;
  :mod:`~vectoradjust.files.many_merge` - their merged output, one GeoPackage per database.

Only :mod:`project`, :mod:`csv_tables`, :mod:`assemble` and :mod:`jsonfile` are free of
GDAL-based packages; the QGIS plugin uses those and never the others.
"""
