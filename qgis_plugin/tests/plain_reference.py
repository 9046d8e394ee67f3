"""In-process reference inputs read WITHOUT the QGIS layer API.

Road layers and the DEM are read with GDAL's own Python bindings (``osgeo``: the same
GDAL library QGIS uses, so nothing second is loaded), the tables with the core's
plain-Python readers (:mod:`vectoradjust.files.csv_tables`), the project with
:func:`vectoradjust.files.project.load_project`. Feeding these arrays to
:func:`vectoradjust.pipeline.run` in the QGIS test process gives the numbers the plugin
must reproduce exactly: it checks the plugin's layer -> array conversion.
"""

import numpy as np

from vectoradjust.adjust.dem import bilinear
from vectoradjust.files.assemble import project_data as assemble_project_data
from vectoradjust.files.csv_tables import (
    read_control,
    read_fiducials,
    read_measurements,
    read_truth_points,
)
from vectoradjust.files.project import load_project
from vectoradjust.model import LineLayer


def _id_text(v):
    if isinstance(v, float) and float(v).is_integer():
        return str(int(v))
    return str(v)


def read_lines(path, name, id_field):
    """A LineLayer of a shapefile (vertex order, ids and problems as the headless reader)."""
    from osgeo import ogr

    ds = ogr.Open(str(path))
    lyr = ds.GetLayer(0)
    defn = lyr.GetLayerDefn()
    names = [defn.GetFieldDefn(i).GetName() for i in range(defn.GetFieldCount())]
    attributes = {n: [] for n in names}
    ids, problems = [], {}
    coords, vf, vi, vp = [], [], [], []
    for i, feat in enumerate(lyr):
        for n in names:
            attributes[n].append(feat.GetField(n))
        ids.append(_id_text(feat.GetField(id_field)) if id_field else str(i))
        g = feat.GetGeometryRef()
        if g is None:
            problems[i] = "null geometry"
            continue
        if g.IsEmpty():
            problems[i] = "empty geometry"
            continue
        parts = [g.GetGeometryRef(k) for k in range(g.GetGeometryCount())] if \
            g.GetGeometryCount() else [g]
        count = 0
        for pnum, part in enumerate(parts):
            pts = np.array([part.GetPoint(k) for k in range(part.GetPointCount())], float)
            if part.GetCoordinateDimension() == 2 or not len(pts):
                pts = pts.reshape(-1, 3) if len(pts) else np.zeros((0, 3))
                pts[:, 2] = np.nan
            if not len(pts):
                continue
            coords.append(pts)
            vf.append(np.full(len(pts), i))
            vi.append(count + np.arange(len(pts)))
            vp.append(np.full(len(pts), pnum))
            count += len(pts)
        if count == 0:
            problems[i] = "empty geometry"
    xyz = np.concatenate(coords) if coords else np.zeros((0, 3))

    def cat(a):
        return np.concatenate(a) if a else np.zeros(0, np.int64)

    return LineLayer(name, np.asarray(ids, dtype=object).astype(str), attributes, xyz, cat(vf),
                     cat(vi), cat(vp), problems, None, str(path))


def dem_grid(path):
    """The DEM (band 1) read with GDAL's reader, as a DemGrid."""
    from osgeo import gdal

    from vectoradjust.model import DemGrid

    ds = gdal.Open(str(path))
    band = ds.GetRasterBand(1)
    grid = band.ReadAsArray().astype(float)
    return DemGrid(grid, tuple(ds.GetGeoTransform()), band.GetNoDataValue())


def dem_heights(path, xy):
    """Bilinear DEM heights (band 1) with GDAL's reader."""
    dem = dem_grid(path)
    return bilinear(dem.grid, dem.transform, xy, nodata=dem.nodata)


def project_data(project_path, names=None):
    """ProjectData of the project's [[vectors]] entries (all, or ``names``), read without
    the QGIS layer API and assembled by the core (:mod:`vectoradjust.files.assemble`)."""
    spec = load_project(project_path)
    unit = spec.measurements.get("unit", "mm")
    raw = read_measurements(spec.measurements["path"], spec.measurements.get("sigma"), unit=unit)
    control = read_control(spec.control["path"]) if spec.control is not None else None
    fid = spec.measurements.get("fiducials")
    vectors, truth = [], {}
    for v in spec.vectors:
        if names is not None and v.name not in names:
            continue
        layer = read_lines(v.path, v.name, v.id_field)
        if v.dem:  # the DEM is in the project CRS: kept for heights at shifted positions
            layer.dem = dem_grid(v.dem)
            layer.coords[:, 2] = bilinear(layer.dem.grid, layer.dem.transform,
                                          layer.coords[:, :2], nodata=layer.dem.nodata)
        vectors.append((v, layer))
        if v.truth:
            truth[v.name] = read_truth_points(v.truth)
    return assemble_project_data(spec, raw, control, vectors, truth=truth,
                                 fiducials=read_fiducials(fid, unit) if fid else None,
                                 source=str(project_path))
