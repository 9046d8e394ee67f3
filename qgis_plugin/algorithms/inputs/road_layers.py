"""Road databases: road layers read through QGIS and the project's ``[[vectors]]``.

A road layer that stands for a ``[[vectors]]`` entry (its file, its name or its ids:
:mod:`~qgis_plugin.algorithms.matching`) takes that entry's place and settings
(:func:`read_road_layer`, :func:`entry_settings_text`); every other entry is read as the
command line does (:func:`read_project_entry`), and :func:`project_data_with` assembles
the core's ProjectData.
"""

import os
from dataclasses import dataclass, field

from qgis.core import (
    QgsVectorLayer,
)

from ... import qgis_io
from .project_file import matching_vector_spec, raster_from_path

__all__ = [
    "RoadDatabase",
    "shape_point_sigma",
    "read_road_layer",
    "open_vector_entry",
    "filtered_entry_layer",
    "read_project_entry",
    "project_data_with",
    "entry_settings_text",
]


@dataclass
class RoadDatabase:
    """A road layer given as a parameter, read for the adjustment.

    ``spec`` and ``layer`` are the core's VectorSpec and LineLayer (vertices in the
    ground CRS, Z from the DEM or the geometry); ``fields`` and ``wkb`` describe the
    source for the features output; ``entry`` is the project's ``[[vectors]]`` entry
    for the layer's file (or None); ``truth`` the truth table, if any.
    """

    spec: object
    layer: object
    fields: object
    wkb: int
    entry: object = None
    truth: object = None
    where: str = ""
    renames: dict = field(default_factory=dict)


def shape_point_sigma(base, sigma_xy, sigma_z):
    """Prior sigma (x, y, z) of the shape points: parameters over ``base``; positive."""
    from vectoradjust.errors import ProjectError

    sigma = (sigma_xy if sigma_xy is not None else base[0],
             sigma_xy if sigma_xy is not None else base[1],
             sigma_z if sigma_z is not None else base[2])
    for s in sigma:
        if not s > 0:
            raise ProjectError(f"The prior sigma of the shape points must be positive, not {s}",
                               "Enter a sigma in metres (e.g. 10)")
    return tuple(float(s) for s in sigma)


def read_road_layer(prj, source, vlayer, context, feedback, *, name="", id_field="",
                    sigma_xy=None, sigma_z=None, dem=None, truth=None, error_model=None):
    """Read a road layer parameter (a feature source) for the adjustment.

    Parameters
    ----------
    prj : ProjectInputs
    source : QgsFeatureSource
        The layer's features (the selection when only selected features are used).
    vlayer : QgsVectorLayer or None
        The layer (matched to a ``[[vectors]]`` entry by :func:`matching_vector_spec`).
    name, id_field : str
        Database name and id field; empty = the entry's, else the layer name / the
        feature index.
    sigma_xy, sigma_z : float or None
        Prior sigma of the shape points (default the entry's, else 10 m).
    dem : QgsRasterLayer or None
        DEM for the heights (default the entry's DEM).
    truth : tuple or None
        Truth table (ids, xyz) (default the entry's).
    error_model : dict or None
        ``{"identification": (h, v) or None, "offset": str or None}`` from the dialog
        (None: the entry's identification_sigma and offset).

    Returns
    -------
    RoadDatabase
    """
    from vectoradjust.files.csv_tables import read_truth_points
    from vectoradjust.model import VectorSpec

    from ..matching import holds_whole_entry, vertex_renames

    entry = matching_vector_spec(prj, vlayer, source, (id_field or "").strip())
    if entry is not None:
        feedback.pushInfo(entry_settings_text(source.sourceName(), entry, name=name,
                                              id_field=id_field, sigma=(sigma_xy, sigma_z),
                                              dem=dem, truth=truth, error_model=error_model))
    name = (name or "").strip() or (entry.name if entry else source.sourceName())
    id_field = (id_field or "").strip() or (entry.id_field if entry else None)
    sigma = shape_point_sigma(entry.sigma if entry else (10.0, 10.0, 10.0), sigma_xy, sigma_z)
    where = f"road layer {source.sourceName()!r}"
    line_layer, fields = qgis_io.read_line_source(source, name, id_field, prj.crs, context,
                                                  where, feedback)
    if dem is None and entry is not None and entry.dem:
        dem = raster_from_path(entry.dem, prj.source)
    if dem is not None:
        feedback.setProgressText(f"{name}: sampling the DEM {dem.name()}")
        dem_report: dict = {}
        line_layer.coords[:, 2] = qgis_io.dem_heights(
            dem, line_layer.coords[:, :2], prj.crs, context, f"DEM {dem.name()!r}",
            report=dem_report)
        line_layer.dem = dem_report.get("grid")
    if truth is None and entry is not None and entry.truth:
        truth = read_truth_points(entry.truth)
    em = error_model or {}
    ident = em.get("identification") or (entry.identification_sigma if entry else None)
    offset = em.get("offset") or (entry.offset if entry else "shift")
    spec = VectorSpec(name=name, path=qgis_io.layer_path(vlayer) or where, id_field=id_field,
                      sigma=sigma, dem=dem.source() if dem is not None else None,
                      truth=entry.truth if entry else None, identification_sigma=ident,
                      offset=offset)
    # roads of the entry's file the layer does not hold (selection, filter, deletions)
    renames = (vertex_renames(prj, entry, id_field, line_layer, context)
               if entry is not None and id_field
               and not holds_whole_entry(entry, vlayer, len(line_layer.feature_ids)) else {})
    return RoadDatabase(spec, line_layer, fields, source.wkbType(), entry, truth, where,
                        renames)


def open_vector_entry(entry, where):
    """The QgsVectorLayer of a ``[[vectors]]`` entry's file (layer name as the headless
    reader picks it: ``layer``, or ``lines`` of an OSM PBF)."""
    from vectoradjust.errors import InputFileError, LayerError

    path = entry.path
    if not path or not os.path.exists(path):
        raise InputFileError(f"Road layer {path!r} does not exist ({where})",
                             "Check the path in the [[vectors]] entry", path=path)
    sub = entry.layer or ("lines" if str(path).lower().endswith(".pbf") else None)
    uri = qgis_io.shapefile_uri(path, sub)  # wide shapefile integers: exact, not reals
    layer = QgsVectorLayer(uri, entry.name, "ogr")
    if not layer.isValid():
        raise LayerError(f"{path}: cannot be read as a vector layer ({where})",
                         "Give a shapefile, GeoPackage, GeoJSON or OSM PBF with line features",
                         path=path)
    return layer


def filtered_entry_layer(layer, entry, where):
    """``layer`` with the entry's ``where`` attribute filter applied (a memory copy of the
    features it selects), or ``layer`` itself without a filter.

    Raises
    ------
    LayerError
        The filter is not a valid expression, names a field the layer does not have, or
        selects no feature.
    """
    from vectoradjust.errors import LayerError

    from ..matching import entry_request

    text = getattr(entry, "where", None)
    if not text:
        return layer
    request = entry_request(entry, where)
    unknown = sorted(c for c in request.filterExpression().referencedColumns()
                     if layer.fields().lookupField(c) < 0)
    if unknown:
        raise LayerError(f"{where}: where = {text!r} names {', '.join(map(repr, unknown))}, not a "
                         f"field of {entry.path} (fields: {', '.join(layer.fields().names())})",
                         "Correct the field name in the where filter of the [[vectors]] entry",
                         path=entry.path)
    out = layer.materialize(request)
    if out.featureCount() == 0:
        raise LayerError(f"{where}: where = {text!r} selects no feature of {entry.path}",
                         "Correct the where filter of the [[vectors]] entry", path=entry.path)
    out.setName(layer.name())
    return out


def read_project_entry(prj, entry, context, feedback, dems=None):
    """A ``[[vectors]]`` entry read from its file through QGIS, as the command line reads it.

    Returns
    -------
    (VectorSpec, LineLayer, truth or None)
    """
    from vectoradjust.files.csv_tables import read_truth_points

    where = f"[[vectors]] entry {entry.name!r} of {prj.source}"
    feedback.setProgressText(f"reading {entry.name} ({entry.path})")
    layer = filtered_entry_layer(open_vector_entry(entry, where), entry, where)
    line_layer, _ = qgis_io.read_line_source(layer, entry.name, entry.id_field, prj.crs,
                                             context, f"{where} ({entry.path})", feedback)
    if entry.dem:
        dems = {} if dems is None else dems
        if entry.dem not in dems:
            dems[entry.dem] = raster_from_path(entry.dem, where)
        dem = dems[entry.dem]
        dem_report: dict = {}
        line_layer.coords[:, 2] = qgis_io.dem_heights(
            dem, line_layer.coords[:, :2], prj.crs, context, f"DEM {dem.name()!r}",
            report=dem_report)
        line_layer.dem = dem_report.get("grid")
    truth = read_truth_points(entry.truth) if entry.truth else None
    return entry, line_layer, truth


def project_data_with(prj, given, context, feedback):
    """The core's ProjectData: the given road layers and every other ``[[vectors]]`` entry.

    A given layer that matches an entry takes its place (project order is kept); the
    other given layers follow. Like ``vectoradjust adjust --vectors NAME`` /
    ``compare``, every database of the project is read so that the measurements of
    databases that are not adjusted are recognised as theirs (and left out).

    Parameters
    ----------
    prj : ProjectInputs
    given : list of RoadDatabase

    Returns
    -------
    ProjectData
    """
    from vectoradjust.errors import ProjectError

    from ..base import check_cancelled

    taken = {}
    extra = []
    for g in given:
        if g.entry is not None and id(g.entry) not in taken:
            taken[id(g.entry)] = g
        else:
            extra.append(g)
    items = []  # (spec, layer, truth, where)
    dems = {}
    for entry in prj.vectors:
        check_cancelled(feedback)
        g = taken.get(id(entry))
        if g is not None:
            items.append((g.spec, g.layer, g.truth, g.where))
        else:
            spec, layer, truth = read_project_entry(prj, entry, context, feedback, dems)
            items.append((spec, layer, truth, f"the project's [[vectors]] entry ({spec.path})"))
    items += [(g.spec, g.layer, g.truth, g.where) for g in extra]
    seen = {}
    for spec, _, _, where in items:
        if spec.name in seen:
            raise ProjectError(
                f"two road databases are both called {spec.name!r}: {seen[spec.name]} and "
                f"{where}",
                "Give the road layer another database name (parameter Database name / "
                "Names), or choose the file of the project's [[vectors]] entry")
        seen[spec.name] = where
    truth = {spec.name: t for spec, _, t, _ in items if t is not None}
    prj = _without_missing_roads(prj, given, feedback)
    return prj.project_data([(spec, layer) for spec, layer, _, _ in items], truth, context,
                            feedback)


def _without_missing_roads(prj, given, feedback):
    """``prj`` without the measurements of roads of a matched entry's file that its layer
    does not hold (they are not in the run: neither shape points nor tie points)."""
    import dataclasses

    from ..matching import apply_renames

    meas = prj.measurements
    for g in given:
        if g.entry is None or not g.renames:
            continue
        meas, n = apply_renames(meas, g.spec.name, g.renames)
        if n:
            feedback.pushInfo(f"{g.spec.name}: {n} image measurements of roads of "
                              f"{g.entry.path} that {g.where} does not hold (not selected, "
                              "filtered or deleted) are left out")
    return prj if meas is prj.measurements else dataclasses.replace(prj, measurements=meas)


def entry_settings_text(layer_name, entry, *, name="", id_field="", sigma=(None, None),
                        dem=None, truth=None, error_model=None):
    """The log line saying that the road layer ``layer_name`` stands for the project's
    ``[[vectors]]`` entry and which of its settings are taken from the entry (those not
    given as parameters)."""
    em = error_model or {}
    taken = []
    if not (name or "").strip():
        taken.append(f"name {entry.name!r}")
    if not (id_field or "").strip() and entry.id_field:
        taken.append(f"id field {entry.id_field!r}")
    if sigma[0] is None:
        taken.append(f"horizontal sigma {entry.sigma[0]:g} m")
    if sigma[1] is None:
        taken.append(f"vertical sigma {entry.sigma[2]:g} m")
    if dem is None and entry.dem:
        taken.append(f"DEM {entry.dem}")
    if truth is None and entry.truth:
        taken.append(f"truth {entry.truth}")
    if em.get("identification") is None and entry.identification_sigma is not None:
        taken.append("identification sigma "
                     f"{', '.join(f'{v:g}' for v in entry.identification_sigma)} m")
    if em.get("offset") is None and entry.offset:
        taken.append(f"offset {entry.offset!r}")
    return (f"road layer {layer_name!r} is the project's [[vectors]] entry {entry.name!r} "
            f"({entry.path}); from the entry: "
            + (", ".join(taken) if taken else "nothing (every setting given here)"))
