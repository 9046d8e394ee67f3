"""File input: vector layers (pyogrio/geopandas), DEMs (rasterio), CRSs (pyproj).

The geospatial libraries are imported inside the functions, never at module import,
so that importing :mod:`vectoradjust` does not load a second GDAL into QGIS.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import numpy as np

from vectoradjust.errors import CRSError, DEMError, InputFileError, LayerError
from vectoradjust.files.project import ProjectSpec, load_project
from vectoradjust.files.tables import read_control, read_measurements, read_truth_points
from vectoradjust.model import LineLayer, ProjectData

__all__ = [
    "check_projected_crs",
    "read_line_layer",
    "read_dem",
    "sample_dem",
    "load_project_data",
    "layer_from_geometries",
]


def check_projected_crs(crs, where: str):
    """Parse ``crs`` with pyproj and require a projected CRS in metres.

    Returns
    -------
    pyproj.CRS
    """
    from pyproj import CRS
    from pyproj.exceptions import CRSError as _PCRSError

    try:
        c = CRS.from_user_input(crs)
    except _PCRSError as exc:
        raise CRSError(f"{where}: the CRS {str(crs)[:80]!r} is not understood ({exc})",
                       'Give an EPSG code such as "EPSG:32616"') from exc
    if c.is_geographic:
        raise CRSError(
            f"{where}: the CRS {c.name!r} is geographic (degrees); the adjustment needs a "
            "projected CRS in metres",
            'Set crs to the local projected CRS, e.g. the UTM zone ("EPSG:326xx")',
        )
    if not c.is_projected:
        raise CRSError(f"{where}: the CRS {c.name!r} is not a projected CRS",
                       'Use a projected CRS in metres (e.g. "EPSG:32616")')
    unit = c.axis_info[0].unit_name if c.axis_info else "metre"
    if unit not in ("metre", "meter", "m"):
        raise CRSError(f"{where}: the CRS {c.name!r} has units of {unit!r}, not metres",
                       "Use a projected CRS in metres")
    return c


def layer_from_geometries(name, geoms, attributes: dict, feature_ids, crs, source,
                          geometry_type="LineString") -> LineLayer:
    """Flatten shapely (Multi)LineStrings to a :class:`LineLayer`.

    Empty, null or non-line geometries are kept as features without vertices and
    listed in ``LineLayer.problems``.
    """
    import shapely

    geoms = np.asarray(geoms, dtype=object)
    nf = len(geoms)
    problems: dict = {}
    parts_coords = []
    vf, vi, vp = [], [], []
    types = shapely.get_type_id(geoms)
    # 1 = LineString, 2 = LinearRing, 5 = MultiLineString
    for i in range(nf):
        g = geoms[i]
        if g is None:
            problems[i] = "null geometry"
            continue
        if types[i] not in (1, 2, 5):
            problems[i] = f"geometry type {g.geom_type} is not a line"
            continue
        if g.is_empty:
            problems[i] = "empty geometry"
            continue
        parts = list(g.geoms) if types[i] == 5 else [g]
        count = 0
        for pnum, part in enumerate(parts):
            c = shapely.get_coordinates(part, include_z=True)
            if len(c) == 0:
                continue
            parts_coords.append(c)
            vf.append(np.full(len(c), i))
            vi.append(count + np.arange(len(c)))
            vp.append(np.full(len(c), pnum))
            count += len(c)
        if count == 0:
            problems[i] = "empty geometry"
    return LineLayer.from_parts(name, feature_ids, attributes, parts_coords, vf, vi, vp,
                                problems, crs, source, geometry_type)


def read_line_layer(path: str, name: str, id_field: Optional[str], target_crs,
                    layer: Optional[str] = None) -> LineLayer:
    """Read a line layer (any OGR format) and transform it to the project CRS.

    Parameters
    ----------
    path : str
        Shapefile, GeoPackage, GeoJSON, OSM PBF ...
    name : str
        Database name.
    id_field : str or None
        Field whose values are the feature ids; None for the 0-based feature index.
    target_crs : pyproj.CRS
        Project CRS.
    layer : str, optional
        Layer name inside a multi-layer source (e.g. ``"lines"`` of an OSM PBF).

    Raises
    ------
    LayerError
        Missing file, unreadable layer, no line geometries, missing id field,
        duplicate ids.
    CRSError
        Layer without CRS.
    """
    import geopandas as gpd

    p = Path(path)
    if not p.exists():
        raise InputFileError(f"Road layer {str(p)!r} does not exist",
                             "Check the path in the [[vectors]] entry", path=str(p))
    try:
        kwargs = {"layer": layer} if layer else {}
        if p.suffix.lower() == ".pbf" and not layer:
            kwargs["layer"] = "lines"
        gdf = gpd.read_file(p, **kwargs)
    except Exception as exc:  # pyogrio/fiona raise many types
        raise LayerError(f"{p}: cannot be read as a vector layer ({exc})",
                         "Give a shapefile, GeoPackage, GeoJSON or OSM PBF with line features",
                         path=str(p)) from exc
    if gdf.crs is None:
        raise CRSError(f"{p}: the layer has no coordinate reference system",
                       "Add a .prj file (or define the CRS in your GIS and save again)",
                       path=str(p))
    geom = gdf.geometry
    types = set(t for t in geom.geom_type.dropna().unique())
    if types and not types & {"LineString", "MultiLineString", "LinearRing"}:
        raise LayerError(
            f"{p}: the layer holds {', '.join(sorted(types))} geometries, not lines",
            "Give the road centrelines as a LineString layer", path=str(p))
    attr_cols = [c for c in gdf.columns if c != gdf.geometry.name]
    if id_field is not None:
        if id_field not in gdf.columns:
            raise LayerError(f"{p}: id_field {id_field!r} is not a field of the layer "
                             f"(fields: {', '.join(attr_cols)})",
                             "Correct id_field in the [[vectors]] entry or omit it", path=str(p))
        vals = gdf[id_field]
        if vals.isna().any():
            i = int(np.flatnonzero(vals.isna().to_numpy())[0])
            raise LayerError(f"{p}: feature {i} has no value in id field {id_field!r}",
                             "Give every feature an id, or omit id_field to use the index",
                             path=str(p))
        ids = np.array([_id_text(v) for v in vals], dtype=object).astype(str)
        u, c = np.unique(ids, return_counts=True)
        if np.any(c > 1):
            raise LayerError(f"{p}: the id {u[c > 1][0]!r} of field {id_field!r} is used by "
                             f"{int(c[c > 1][0])} features",
                             "Use a field with unique values as id_field", path=str(p))
    else:
        ids = np.arange(len(gdf)).astype(str)
    if geom.notna().any():
        gdf_t = gdf.to_crs(target_crs) if not gdf.crs.equals(target_crs) else gdf
    else:
        gdf_t = gdf
    attributes = {c: gdf[c].tolist() for c in attr_cols}
    gtype = ",".join(sorted(types)) or "none"
    return layer_from_geometries(name, gdf_t.geometry.to_numpy(), attributes, ids,
                                 target_crs.to_wkt(), str(p), gtype)


def _id_text(v) -> str:
    if isinstance(v, float) and float(v).is_integer():
        return str(int(v))
    return str(v)


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


def sample_dem(path: str, xy: np.ndarray, project_crs) -> np.ndarray:
    """Heights at ``xy`` (project CRS) by bilinear interpolation; NaN where uncovered."""
    from pyproj import Transformer

    from vectoradjust.adjust.dem import bilinear

    grid, gt, nodata, crs = read_dem(path)
    pts = np.asarray(xy, float)
    if crs is not None and not crs.equals(project_crs):
        t = Transformer.from_crs(project_crs, crs, always_xy=True)
        x, y = t.transform(pts[:, 0], pts[:, 1])
        pts = np.column_stack([x, y])
    elif crs is None:
        raise CRSError(f"{path}: the DEM has no coordinate reference system",
                       "Assign the CRS to the GeoTIFF (gdal_edit.py -a_srs)", path=str(path))
    return bilinear(grid, gt, pts, nodata=nodata)


def load_project_data(project, vectors: Optional[list] = None) -> ProjectData:
    """Read every file a project refers to.

    Parameters
    ----------
    project : str, os.PathLike or ProjectSpec
    vectors : list of str, optional
        Only these ``[[vectors]]`` entries are read (default: all).

    Returns
    -------
    ProjectData
        The image measurements are already refined
        (:func:`vectoradjust.sensor.interior.refine_measurements`: fiducial affine or pixel
        size, principal point, lens distortion, refraction, earth curvature as switched
        in ``[corrections]``): ``measurements`` are photo mm with sigmas in mm,
        ``camera.principal_point`` is the one the collinearity equations must use with
        them (``(0, 0)`` once reduced), ``camera.calibration`` the
        :class:`~vectoradjust.sensor.camera.CameraCalibration` and ``interior`` the report.
    """
    from vectoradjust.files.assemble import project_data
    from vectoradjust.files.tables import read_fiducials

    spec = project if isinstance(project, ProjectSpec) else load_project(project)
    where = str(spec.path) if spec.path else "<project>"
    crs = check_projected_crs(spec.crs, f"{where}: crs")
    unit = spec.measurements.get("unit", "mm")
    raw_meas = read_measurements(spec.measurements["path"], spec.measurements.get("sigma"),
                                 unit=unit)
    control = read_control(spec.control["path"]) if spec.control is not None else None
    fid_path = spec.measurements.get("fiducials")
    fiducials = read_fiducials(fid_path, unit) if fid_path else None
    layers = []
    truth = {}
    names = vectors or [v.name for v in spec.vectors]
    for v in spec.vectors:
        if v.name not in names:
            continue
        layer = read_line_layer(v.path, v.name, v.id_field, crs, v.layer)
        if v.dem:
            z = sample_dem(v.dem, layer.coords[:, :2], crs)
            layer.coords[:, 2] = z
        layers.append((v, layer))
        if v.truth:
            truth[v.name] = read_truth_points(v.truth)
    for n in names:
        spec.vector(n)  # raises a clear error for an unknown name
    # refinement (DESIGN 5), camera, [qa], truth: vectoradjust.files.assemble, shared with QGIS;
    # the project CRS is projected (checked above): earth curvature applies when asked
    return project_data(spec, raw_meas, control, layers, crs=crs.to_string(), truth=truth,
                        fiducials=fiducials, map_projection=bool(crs.is_projected),
                        source=where)
