"""File input: vector layers (pyogrio/geopandas), DEMs (rasterio), CRSs (pyproj).

The geospatial libraries are imported inside the functions, never at module import,
so that importing :mod:`vectoradjust` does not load a second GDAL into QGIS.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Optional

import numpy as np

from vectoradjust.errors import CRSError, DEMError, InputFileError, LayerError
from vectoradjust.files.project import ProjectSpec, load_project
from vectoradjust.files.tables import read_control, read_measurements, read_truth_points
from vectoradjust.model import LineLayer, ProjectData

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
    types = shapely.get_type_id(geoms)  # -1 = None, 1 = LineString, 2 = LinearRing, 5 = Multi
    is_line = np.isin(types, (1, 2, 5))
    for i in np.flatnonzero(~is_line).tolist():
        problems[i] = ("null geometry" if geoms[i] is None else
                       f"geometry type {geoms[i].geom_type} is not a line")
    # every part of every line feature, then every coordinate of every part (no loop)
    parts, part_feature = shapely.get_parts(geoms[is_line], return_index=True)
    part_feature = np.flatnonzero(is_line)[part_feature]
    xyz, vpart = shapely.get_coordinates(parts, include_z=True, return_index=True)
    # part number within its feature: position among the feature's parts
    first_part = np.searchsorted(part_feature, part_feature, side="left")
    part_no = np.arange(len(parts)) - first_part
    vf = part_feature[vpart]
    vp = part_no[vpart]
    # vertex number within its feature: running count over the feature's parts
    feat_count = np.bincount(vf, minlength=nf)
    feat_start = np.concatenate([[0], np.cumsum(feat_count)[:-1]])
    vi = np.arange(len(vf)) - feat_start[vf]
    for i in np.flatnonzero(is_line & (feat_count == 0)).tolist():
        problems[i] = "empty geometry"
    return LineLayer.from_parts(name, feature_ids, attributes, [xyz] if len(xyz) else [],
                                [vf], [vi], [vp], problems, crs, source, geometry_type)


#: a transformation less accurate than this (m), or of unknown accuracy, is a warning
TRANSFORMATION_ACCURACY_LIMIT = 1.0


def line_layers(path) -> list:
    """``(name, geometry type)`` of every layer of a source (GeoPackage, FileGDB, OSM PBF ...).

    Raises
    ------
    LayerError
        The source cannot be opened.
    """
    import pyogrio

    try:
        return [(str(n), str(t) if t is not None else "Unknown")
                for n, t in pyogrio.list_layers(str(path))]
    except Exception as exc:  # pyogrio raises DataSourceError and others
        raise LayerError(f"{path}: cannot be read as a vector source ({exc})",
                         "Give a shapefile, GeoPackage, GeoJSON, FileGDB or OSM PBF with line "
                         "features", path=str(path)) from exc


def _holds_lines(gtype: str) -> bool:
    return "linestring" in gtype.lower() or "linearring" in gtype.lower()


def choose_layer(path, layer: Optional[str], entry: str) -> Optional[str]:
    """The layer of ``path`` to read: ``layer`` if given, else the source's only line layer.

    Parameters
    ----------
    path : str or os.PathLike
    layer : str or None
        ``[[vectors]] layer``.
    entry : str
        The ``[[vectors]]`` entry, for messages (``"[[vectors]] 'OSM'"``).

    Returns
    -------
    str or None
        None for a single-layer source (shapefile, GeoJSON).

    Raises
    ------
    LayerError
        ``layer`` is not in the source; or no ``layer`` is given and the source holds
        several layers with lines (the message lists them) or several layers none of which
        holds lines.
    """
    layers = line_layers(path)
    listing = ", ".join(f"{n} ({t})" for n, t in layers)
    if layer is not None:
        if layer not in [n for n, _ in layers]:
            raise LayerError(f"{path} ({entry}): there is no layer {layer!r} (layers: {listing})",
                             "Correct layer in the [[vectors]] entry", path=str(path))
        return layer
    if len(layers) <= 1:
        return None
    lines = [(n, t) for n, t in layers if _holds_lines(t)]
    if len(lines) == 1:
        return lines[0][0]
    if lines:
        raise LayerError(
            f"{path} ({entry}) holds {len(lines)} layers with lines: "
            + ", ".join(f"{n} ({t})" for n, t in lines),
            f'Add layer = "{lines[0][0]}" (or another of them) to its [[vectors]] entry',
            path=str(path), details={"layers": [n for n, _ in lines]})
    raise LayerError(f"{path} ({entry}) holds {len(layers)} layers and none holds lines: "
                     f"{listing}",
                     'Give the road centrelines (a line layer), or name the layer with '
                     'layer = "..." in the [[vectors]] entry',
                     path=str(path), details={"layers": [n for n, _ in layers]})


def _read_frame(p: Path, layer: Optional[str], where: Optional[str], entry: str):
    """The layer as a GeoDataFrame (indexed by FID when filtered), with its fields checked."""
    import pyogrio

    kwargs = {"layer": layer} if layer else {}
    typed = _typed_reading(p, layer)  # every attribute with its type and exact value
    try:
        if where is None:
            return _typed_or_plain(p, typed, **kwargs)
        return _typed_or_plain(p, typed, where=where, fid_as_index=True, **kwargs)
    except Exception as exc:  # pyogrio raises many types
        if where is None:
            raise LayerError(f"{p}: cannot be read as a vector layer ({exc})",
                             "Give a shapefile, GeoPackage, GeoJSON or OSM PBF with line "
                             "features", path=str(p)) from exc
        try:
            fields = ", ".join(map(str, pyogrio.read_info(p, **kwargs)["fields"]))
        except Exception:  # the expression is what we report
            fields = "?"
        raise LayerError(
            f"{p} ({entry}): where = {where!r} is not a valid attribute filter ({exc})",
            "Write an OGR SQL WHERE clause over the layer's fields "
            f"({fields}), e.g. where = \"highway IS NOT NULL\" or "
            "where = \"highway IN ('primary', 'residential')\"",
            path=str(p), details={"where": where}) from exc


def _typed_or_plain(p: Path, typed: dict, **kwargs):
    """``read_dataframe`` through Arrow (``typed``), or through NumPy where pyogrio's Arrow
    path fails on the file (e.g. a GeoJSON field named like its FID column, ``id``, with
    ``fid_as_index``): the file is read as before the typed reading, not refused."""
    import pyogrio

    if typed:
        try:
            df = pyogrio.read_dataframe(p, **kwargs, **typed)
        except (ValueError, KeyError, TypeError):
            df = None
        # the FID index as integers, not (fid, id) pairs; every column asked for
        if (df is not None and (not kwargs.get("fid_as_index") or df.index.dtype.kind in "iu")
                and all(c in df.columns for c in kwargs.get("columns") or [])):
            return df
    return pyogrio.read_dataframe(p, **kwargs)


def _filtered_ids(p: Path, layer: Optional[str], gdf, id_field: Optional[str]):
    """Feature ids of a filtered read: ``(kept ids or None, excluded ids, features in layer)``.

    Without ``id_field`` the ids are the 0-based positions in the *unfiltered* layer, so
    a feature keeps its id (and its shape point ids) whatever the filter.
    """
    import pyogrio

    kwargs = {"layer": layer} if layer else {}
    # the FIDs through NumPy (exact integers; pyogrio's Arrow path can mix them up with a
    # field of the FID column's name), the id values typed, in the same feature order
    fids = pyogrio.read_dataframe(p, read_geometry=False, fid_as_index=True, columns=[],
                                  **kwargs).index
    full = (_typed_or_plain(p, _typed_reading(p, layer), read_geometry=False,
                            columns=[id_field], **kwargs) if id_field else None)
    if full is not None:
        full.index = fids
    else:
        import pandas as pd

        full = pd.DataFrame(index=fids)
    kept = np.isin(full.index.to_numpy(), np.asarray(gdf.index.to_numpy()))
    if id_field is None:
        pos = {fid: i for i, fid in enumerate(full.index.to_numpy())}
        ids = np.array([str(pos[f]) for f in gdf.index.to_numpy()], dtype=object).astype(str)
        excluded = [str(i) for i in np.flatnonzero(~kept)]
    else:
        ids = None
        if id_field not in full.columns:  # a field GDAL reads as the FID (GeoJSON "id")
            raise LayerError(f"{p}: id_field {id_field!r} cannot be read with the where "
                             "filter (GDAL takes it for the feature id)",
                             f"Use another id field, or no where filter, for {p.name}",
                             path=str(p))
        values = _column_values(full[id_field])[0]
        excluded = [_id_text(v) for v, k in zip(values, kept) if not k and v is not None]
    return ids, excluded, len(full)


def read_line_layer(path: str, name: str, id_field: Optional[str], target_crs,
                    layer: Optional[str] = None, where: Optional[str] = None) -> LineLayer:
    """Read a line layer (any OGR format) and transform it to the project CRS.

    Parameters
    ----------
    path : str
        Shapefile, GeoPackage, GeoJSON, FileGDB, OSM PBF ...
    name : str
        Database name.
    id_field : str or None
        Field whose values are the feature ids; None for the 0-based feature index (in
        the layer as stored, before any ``where`` filter).
    target_crs : pyproj.CRS
        Project CRS.
    layer : str, optional
        Layer name inside a multi-layer source (e.g. ``"lines"`` of an OSM PBF); needed
        when the source holds more than one layer with lines (:func:`choose_layer`).
    where : str, optional
        Attribute filter (OGR SQL WHERE clause, ``[[vectors]] where``): the features it
        rejects are not read.

    Returns
    -------
    LineLayer
        With an extra attribute ``reading`` (dict): ``source``, ``layer``, ``where``,
        ``features_in_layer``, ``features_kept``, ``features_filtered``,
        ``excluded_feature_ids`` (ids of the filtered features, so that their measurements
        are left out, not made tie points), ``crs`` (:func:`transformation_info`) and
        ``fields``: ``{field: Arrow type name}`` of the attributes (``"int64"``,
        ``"date32[day]"`` ...). The attributes are plain Python values with their type and
        exact value (an int64 beyond 2^53, a date, None for NULL), and so are the ids'
        texts.

    Raises
    ------
    LayerError
        Missing file, unreadable layer, several line layers and no ``layer``, a bad
        ``where``, no line geometries, missing id field, duplicate ids.
    CRSError
        Layer without CRS.
    """
    p = Path(path)
    entry = f"[[vectors]] {name!r}"
    if not p.exists():
        raise InputFileError(f"Road layer {str(p)!r} does not exist",
                             "Check the path in the [[vectors]] entry", path=str(p))
    chosen = choose_layer(p, layer, entry)
    gdf = _read_frame(p, chosen, where, entry)
    if not hasattr(type(gdf), "geometry"):  # pyogrio gives a DataFrame: no geometry column
        raise LayerError(f"{p} ({entry}): the layer has no geometries (a table: "
                         f"{', '.join(map(str, gdf.columns)) or 'no fields'})",
                         "Give the road centrelines as a line layer (shapefile, GeoPackage, "
                         "GeoJSON ...)", path=str(p))
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
    if id_field is not None and id_field not in attr_cols:  # said before the filter's ids
        _feature_ids(p, gdf, id_field, attr_cols)
    index_ids, excluded, n_layer = (None, [], len(gdf)) if where is None else _filtered_ids(
        p, chosen, gdf, id_field)
    ids = _feature_ids(p, gdf, id_field, attr_cols) if id_field is not None else (
        index_ids if index_ids is not None else np.arange(len(gdf)).astype(str))
    geoms, crs_info = _to_project_crs(gdf, target_crs)
    attributes, field_types = _attribute_columns(gdf, attr_cols, _shapefile_types(p, chosen))
    gtype = ",".join(sorted(types)) or "none"
    out = layer_from_geometries(name, geoms, attributes, ids, target_crs.to_wkt(), str(p), gtype)
    out.reading = {
        "source": str(p), "layer": chosen, "where": where, "features_in_layer": int(n_layer),
        "features_kept": int(len(gdf)), "features_filtered": int(n_layer - len(gdf)),
        "excluded_feature_ids": excluded, "crs": crs_info,
    }
    out.reading["fields"] = field_types
    return out


def _feature_ids(p: Path, gdf, id_field: str, attr_cols: list) -> np.ndarray:
    """The values of ``id_field`` as text (missing field, missing or duplicate ids: error)."""
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
    values = _column_values(vals)[0]
    _check_exact_ids(p, id_field, values)
    ids = np.array([_id_text(v) for v in values], dtype=object).astype(str)
    u, c = np.unique(ids, return_counts=True)
    if np.any(c > 1):
        raise LayerError(f"{p}: the id {str(u[c > 1][0])!r} of field {id_field!r} is used by "
                         f"{int(c[c > 1][0])} features",
                         "Use a field with unique values as id_field", path=str(p))
    return ids


#: reals at or beyond this magnitude are not every integer: an id read as a real there
#: may not be the id in the file
EXACT_REAL_INTEGER = 2 ** 53


def _check_exact_ids(p: Path, id_field: str, values: list) -> None:
    """Ids that GDAL gives as reals beyond 2^53 (a GeoJSON's or an unusual shapefile
    field read as real numbers) may have changed: a clear error, not wrong ids."""
    big = [v for v in values if isinstance(v, float) and abs(v) >= EXACT_REAL_INTEGER]
    if big:
        raise LayerError(
            f"{p}: the ids of field {id_field!r} are read as real numbers, and {len(big)} of "
            f"them lie beyond 2^53 (e.g. {big[0]:.17g}), where a real cannot hold every "
            "integer: the ids read may not be those in the file",
            "Store the ids as text (in a GeoJSON \"id\": \"-1152921504648188749\": GDAL "
            "reads negative integers of 19 digits there as reals) or as integers in a "
            "GeoPackage; or choose another id_field", path=str(p),
            details={"id_field": id_field, "example": big[0]})


def same_crs(a, b) -> bool:
    """Whether two CRSs place coordinates identically, judged by the CRSs, not their names.

    The same when pyproj finds them equivalent (names and other metadata aside, the axis
    order ignored: every reader here takes X = easting or longitude), or when both stand
    for the same authority code (an explicit ``ID``/``AUTHORITY`` of the CRS, else PROJ's
    identification as equivalent) and each agrees with that code's definition except in
    names: e.g. EPSG:3067 as "ETRS89 / TM35FIN(E,N)" and as "EUREF-FIN / TM35FIN(E,N)"
    with its datum called "EUREF-FIN". A real datum change (another ellipsoid, a datum
    with a shift, another projection) is never the same.

    Parameters
    ----------
    a, b : pyproj.CRS or anything :meth:`pyproj.CRS.from_user_input` takes

    Returns
    -------
    bool
    """
    from pyproj import CRS

    a, b = CRS.from_user_input(a), CRS.from_user_input(b)
    if a.equals(b, ignore_axis_order=True):
        return True
    code = _authority_code(a)
    if code is None or code != _authority_code(b):
        return False
    try:
        ref = CRS.from_authority(*code)
    except Exception:  # noqa: BLE001 - an authority PROJ does not know: not the same
        return False
    return _alike(a, ref) and _alike(b, ref)


def _authority_code(crs) -> Optional[tuple]:
    """``(authority, code)`` the CRS stands for: its explicit identifier, else the one
    PROJ identifies as equivalent (confidence >= 90); None when neither."""
    ident = (crs.to_json_dict() or {}).get("id")
    if isinstance(ident, dict) and ident.get("authority") and ident.get("code") is not None:
        return str(ident["authority"]).upper(), str(ident["code"])
    found = crs.to_authority(min_confidence=90)
    return (found[0].upper(), str(found[1])) if found else None


def _alike(crs, ref) -> bool:
    """``crs`` is ``ref`` except in names: the same kind, ellipsoid, prime meridian,
    map projection (method and parameters) and axis units (compound: part by part)."""
    if crs.is_compound or ref.is_compound:
        subs, refs = crs.sub_crs_list, ref.sub_crs_list
        return (crs.is_compound and ref.is_compound and len(subs) == len(refs)
                and all(_alike(x, y) for x, y in zip(subs, refs)))
    if (crs.type_name != ref.type_name
            or [ax.unit_conversion_factor for ax in crs.axis_info]
            != [ax.unit_conversion_factor for ax in ref.axis_info]):
        return False
    if crs.is_vertical:
        return True  # a vertical datum's name is all there is: the code vouches for it
    e, f = crs.ellipsoid, ref.ellipsoid
    if e is None or f is None or not np.isclose(e.semi_major_metre, f.semi_major_metre,
                                                rtol=1e-12, atol=0.0) \
            or not np.isclose(e.inverse_flattening, f.inverse_flattening, rtol=1e-12,
                              atol=0.0):
        return False
    pa, pb = crs.prime_meridian, ref.prime_meridian
    if pa is not None and pb is not None and pa.longitude != pb.longitude:
        return False
    if crs.is_projected:
        return _same_conversion(crs.coordinate_operation, ref.coordinate_operation)
    return True


def _same_conversion(a, b) -> bool:
    """Two map projections (pyproj CoordinateOperation) with the same method and the
    same parameter values (by EPSG code, else by name)."""
    if a is None or b is None:
        return a is b
    if a.method_code != b.method_code or (not a.method_code and a.method_name != b.method_name):
        return False

    def values(op):
        return {(p.code or p.name): (p.value, p.unit_conversion_factor) for p in op.params}

    va, vb = values(a), values(b)
    return va.keys() == vb.keys() and all(
        np.isclose(va[k][0] * va[k][1], vb[k][0] * vb[k][1], rtol=1e-12, atol=1e-12)
        for k in va)


def transformation_info(source_crs, target_crs, bounds=None):
    """The transformation from ``source_crs`` to ``target_crs`` PROJ chooses, and a verdict.

    Parameters
    ----------
    source_crs, target_crs : pyproj.CRS
    bounds : sequence of 4 floats, optional
        ``xmin, ymin, xmax, ymax`` of the data in ``source_crs``: the transformation is
        chosen for that area (as PROJ would per point), so that it can be named.

    Returns
    -------
    transformer : pyproj.Transformer
        The one to use (``always_xy``).
    info : dict
        ``source_crs``, ``target_crs`` (names), ``transformation`` (PROJ's description),
        ``accuracy_m`` (None when unknown), ``ballpark`` and ``warning`` (text or None:
        a ballpark transformation, or an accuracy unknown or worse than
        :data:`TRANSFORMATION_ACCURACY_LIMIT`).
    """
    from pyproj import Transformer

    aoi = _area_of_interest(source_crs, bounds)
    with warnings.catch_warnings(record=True) as caught:  # pyproj: "missing Grid(...)"
        warnings.simplefilter("always")
        t = Transformer.from_crs(source_crs, target_crs, always_xy=True, area_of_interest=aoi)
    desc = str(t.description)
    acc = float(t.accuracy) if t.accuracy is not None else -1.0
    ballpark = "ballpark" in desc.lower()
    info = {"source_crs": source_crs.name, "target_crs": target_crs.name,
            "transformation": desc, "accuracy_m": acc if acc >= 0 else None,
            "ballpark": ballpark, "warning": None,
            "proj_notes": [str(w.message) for w in caught]}
    if ballpark or acc < 0 or acc > TRANSFORMATION_ACCURACY_LIMIT:
        why = ("a ballpark transformation (datum shift ignored; errors of metres possible)"
               if ballpark else "of unknown accuracy" if acc < 0 else
               f"accurate to about {acc:g} m only")
        info["warning"] = (f"from {source_crs.name} to {target_crs.name} is {why}: {desc}; "
                           "positions may be off by that much (an offset of the database "
                           "absorbs a constant shift): give the data in the project CRS's "
                           "datum, or install PROJ's transformation grids (projsync) if one "
                           "applies")
    return t, info


def _user_crs(value, where: str):
    """``value`` (an EPSG code, WKT ...) as a pyproj CRS; a :class:`CRSError` if unknown."""
    from vectoradjust.files.rpc import _parse_crs

    return _parse_crs(value, f"{where}: the CRS", 'EPSG:4326" or "EPSG:5703')


def _parts(crs):
    """(horizontal CRS, vertical CRS or None) of ``crs`` (compound or not)."""
    if crs.is_compound:
        subs = crs.sub_crs_list
        return subs[0], (subs[1] if len(subs) > 1 else None)
    return crs, None


def _with_vertical(crs, vertical, where: str):
    """The horizontal part of ``crs`` with the heights in ``vertical`` (None: ``crs``)."""
    if vertical is None:
        return crs
    from pyproj.crs import CompoundCRS

    if not vertical.is_vertical or vertical.is_compound:
        raise CRSError(f"{where}: {vertical.name!r} is not a vertical CRS",
                       'Give a vertical CRS, e.g. vertical_crs = "EPSG:5703" (NAVD88 height)')
    horizontal = _parts(crs)[0]
    if len(horizontal.axis_info) == 3:
        raise CRSError(f"{where}: {horizontal.name!r} already has ellipsoidal heights; a "
                       f"vertical_crs ({vertical.name!r}) cannot be added to it",
                       "Give its 2D CRS (e.g. EPSG:4326 instead of EPSG:4979) with "
                       "vertical_crs, or leave vertical_crs out")
    return CompoundCRS(f"{horizontal.name} + {vertical.name}", [horizontal, vertical])


def _is_3d(crs) -> bool:
    return len(crs.axis_info) == 3


def transform_points(xyz: np.ndarray, source, target, what: str):
    """Points from ``source`` to ``target`` (pyproj CRSs; X = easting or longitude).

    3D (the heights too) when both CRSs are 3D (compound or ellipsoidal); else XY only
    and the heights pass unchanged (a warning when ``source`` states their datum).

    Returns
    -------
    xyz : numpy.ndarray (n, 3)
    info : dict
        :func:`transformation_info` plus ``vertical``: ``source``, ``target`` (datum
        names; None when a side has none) and ``transformed`` (whether the heights
        changed datum).

    Raises
    ------
    CRSError
        The heights change datum but PROJ has only a ballpark vertical transformation
        (a 0 m geoid: the grid it needs is not installed) or gives no height.
    """
    pts = np.array(xyz, float).reshape(-1, 3)
    ok = np.isfinite(pts[:, :2]).all(axis=1)
    bounds = np.r_[pts[ok, :2].min(axis=0), pts[ok, :2].max(axis=0)] if ok.any() else None
    t, info = transformation_info(source, target, bounds)
    three_d = _is_3d(source) and _is_3d(target)
    out = pts.copy()
    if three_d:
        out[:, 0], out[:, 1], out[:, 2] = t.transform(pts[:, 0], pts[:, 1], pts[:, 2])
    else:
        out[:, 0], out[:, 1] = t.transform(pts[:, 0], pts[:, 1])
    sv, tv = _parts(source)[1], _parts(target)[1]
    changed = three_d and not (sv is not None and tv is not None and sv.equals(tv))
    info["vertical"] = {
        "source": sv.name if sv is not None else ("ellipsoidal height" if three_d else None),
        "target": tv.name if tv is not None else None, "transformed": bool(changed)}
    if _is_3d(source) and not _is_3d(target):
        kept = (f"the heights stay in {sv.name if sv is not None else 'ellipsoidal height'} "
                f"(untransformed): {target.name} states no vertical datum (give a compound "
                "crs or vertical_crs to transform them)")
        info["warning"] = f"{info['warning']}; {kept}" if info["warning"] else kept
    bad = not np.isfinite(out[ok & np.isfinite(pts[:, 2]), 2]).all()
    if changed and ("ballpark vertical" in info["transformation"].lower() or bad):
        raise CRSError(*_no_geoid_message(source, target, what, info["vertical"], bounds))
    return out, info


def _no_geoid_message(source, target, what: str, vertical: dict, bounds=None) -> tuple:
    """(message, mend) when PROJ cannot change the heights' datum (no geoid grid)."""
    from pyproj.transformer import TransformerGroup

    try:
        with warnings.catch_warnings():  # the message below names the missing grids
            warnings.simplefilter("ignore")
            group = TransformerGroup(source, target, always_xy=True, area_of_interest=(
                _area_of_interest(_parts(source)[0], bounds)))
        grids = sorted({g.short_name for op in group.unavailable_operations for g in op.grids
                        if not g.available})
    except Exception:  # only for the message
        grids = []
    need = f" (missing grids: {', '.join(grids[:4])})" if grids else ""
    return (f"{what}: the heights cannot be transformed from {vertical['source']} to "
            f"{vertical['target']}: PROJ has no grid-based transformation here{need}, only a "
            "ballpark one that would take the geoid as 0 m",
            "Install the grid (the proj-data package, or projsync --file <grid>; PROJ_NETWORK "
            f"is off), or give the heights in {vertical['target']}, the project's vertical datum")


def control_to_project_crs(control, spec: ProjectSpec, project_crs, where: str):
    """The control points in the project CRS (``[control] crs`` / ``vertical_crs``).

    The source CRS is ``[control] crs`` (default: the project ``crs``), its heights in
    ``[control] vertical_crs``, else the top-level ``vertical_crs``, else the CRS's own
    vertical datum. The target is the project ``crs`` (its vertical datum, else the
    top-level ``vertical_crs``). The sigmas stay as given.

    Returns
    -------
    ControlPoints
        ``xyz`` transformed; ``reading`` the source CRS and :func:`transform_points`'s
        info (``crs``; None when nothing was transformed).
    """
    table = spec.control or {}
    w = f"{where} [control]"
    source = _user_crs(table["crs"], f"{w} crs") if table.get("crs") else project_crs
    if source.is_vertical and not source.is_compound:
        raise CRSError(f"{w} crs: {source.name!r} is a vertical CRS",
                       'Give the horizontal CRS as crs and the heights\' as vertical_crs')
    vname = table.get("vertical_crs") or spec.vertical_crs
    if vname:
        source = _with_vertical(source, _user_crs(vname, f"{w} vertical_crs"), w)
    target = _project_target(project_crs, spec, where)
    reading = {"source": control.source, "source_crs": source.name, "crs": None}
    if not same_crs(source, target):
        control.xyz, info = transform_points(control.xyz, source, target,
                                             f"{w} ({control.source})")
        if info["warning"]:
            info["warning"] = info["warning"].replace(
                " (an offset of the database absorbs a constant shift)", "")
        reading["crs"] = info
    control.reading = reading
    return control


def _project_target(project_crs, spec: ProjectSpec, where: str):
    """The project CRS with its vertical datum: its own, else the top-level vertical_crs."""
    if _parts(project_crs)[1] is not None or not spec.vertical_crs:
        return project_crs
    return _with_vertical(project_crs, _user_crs(spec.vertical_crs, f"{where} vertical_crs"),
                          where)


def dem_heights(z: np.ndarray, xy: np.ndarray, spec: ProjectSpec, project_crs, where: str):
    """DEM heights (top-level ``vertical_crs``) in the project's vertical datum.

    Returns ``(z, info)``; info is None when no datum change is asked for (no top-level
    ``vertical_crs``, or the project CRS states no other vertical datum).
    """
    target = _project_target(project_crs, spec, where)
    if not spec.vertical_crs or target is not project_crs:
        return z, None
    source = _with_vertical(project_crs, _user_crs(spec.vertical_crs, f"{where} vertical_crs"),
                            where)
    if same_crs(source, target):
        return z, None
    pts = np.column_stack([np.asarray(xy, float)[:, :2], z])
    out, info = transform_points(pts, source, target, where)
    return out[:, 2], info


def _area_of_interest(crs, bounds):
    """The data's extent in degrees (pyproj AreaOfInterest), or None when unknown."""
    if bounds is None or not np.all(np.isfinite(bounds)):
        return None
    from pyproj import Transformer
    from pyproj.aoi import AreaOfInterest

    try:
        to_deg = Transformer.from_crs(crs, "EPSG:4326", always_xy=True)
        w, s, e, n = to_deg.transform_bounds(*bounds)
        return AreaOfInterest(max(w, -180.0), max(s, -90.0), min(e, 180.0), min(n, 90.0))
    except Exception:  # no extent: PROJ chooses without it
        return None


def _transform_geometries(geoms: np.ndarray, transformer) -> np.ndarray:
    """The geometries through ``transformer`` (Z passed on where the geometry has one)."""
    import shapely

    def xy(c):
        return np.column_stack(transformer.transform(c[:, 0], c[:, 1]))

    def xyz(c):
        return np.column_stack(transformer.transform(c[:, 0], c[:, 1], c[:, 2]))

    out = np.array(geoms, dtype=object)
    has_z = shapely.has_z(out)
    for mask, fn, z in ((~has_z, xy, False), (has_z, xyz, True)):
        if mask.any():
            out[mask] = shapely.transform(out[mask], fn, include_z=z)
    return out


def _to_project_crs(gdf, target_crs):
    """The layer's geometries in the project CRS and the transformation used (dict or None)."""
    geoms = gdf.geometry.to_numpy()
    if not gdf.geometry.notna().any() or same_crs(gdf.crs, target_crs):
        return geoms, None
    transformer, info = transformation_info(gdf.crs, target_crs, gdf.total_bounds)
    return _transform_geometries(geoms, transformer), info


def _id_text(v) -> str:
    """A feature id as text: integers exactly (an int64 beyond 2^53 too), ``12.0`` as
    ``"12"``, dates in ISO 8601."""
    if isinstance(v, float) and float(v).is_integer():
        return str(int(v))
    return v.isoformat() if hasattr(v, "isoformat") else str(v)


#: OGR field types whose values pyogrio's Arrow reading gives as 64-bit integers when a
#: shapefile is opened with ADJUST_TYPE (the type the file states, or wider)
_WIDE_INTEGER_TYPES = ("OFTInteger64", "OFTReal")


def _typed_reading(p: Path, layer: Optional[str]) -> dict:
    """``read_dataframe`` keywords that keep every attribute's type and exact value.

    Through Arrow with pandas' Arrow types: an integer field with NULLs stays integer
    (the NumPy path makes it float, changing int64 values beyond 2^53), a date stays a
    date, a boolean a boolean. A shapefile whose integers are written wider than 18
    digits (DBF ``N(19+, 0)``, which GDAL reads as real numbers) is opened with
    ``ADJUST_TYPE=YES``: GDAL scans the values and reads such a field as exact 64-bit
    integers. Empty (the NumPy path) where pyogrio or GDAL cannot read through Arrow
    (pyogrio < 0.7, GDAL < 3.6, pandas < 1.5).
    """
    import pyogrio

    try:
        import pandas as pd
        import pyarrow  # noqa: F401
    except ImportError:
        return {}
    if (_version(pyogrio.__version__) < (0, 7) or not hasattr(pd, "ArrowDtype")
            or tuple(pyogrio.__gdal_version__[:2]) < (3, 6)):
        return {}
    out = {"use_arrow": True, "arrow_to_pandas_kwargs": {"types_mapper": pd.ArrowDtype}}
    if "OFTReal" in _shapefile_types(p, layer).values():
        out["ADJUST_TYPE"] = "YES"
    return out


def _shapefile_types(p: Path, layer: Optional[str]) -> dict:
    """``{field: OGR type}`` as GDAL reads a shapefile by default (from the DBF field
    widths); empty for another format or an unreadable source."""
    import pyogrio

    try:
        info = pyogrio.read_info(p, **({"layer": layer} if layer else {}))
    except Exception:  # not readable: the read itself reports it
        return {}
    if info.get("driver") != "ESRI Shapefile":
        return {}
    return dict(zip(map(str, info["fields"]), map(str, info["ogr_types"])))


def _version(text: str) -> tuple:
    """``"0.13.0"`` -> ``(0, 13)`` (non-numeric parts as 0)."""
    parts = (str(text).split(".") + ["0"])[:2]
    return tuple(int("".join(ch for ch in x if ch.isdigit()) or 0) for x in parts)


def _column_values(series) -> tuple:
    """A column's values as plain Python and its type.

    Returns
    -------
    values : list
        ``int`` (exact, also beyond 2^53), ``float``, ``str``, ``bool``,
        ``datetime.date``, ``datetime.datetime`` (with its time zone when it has one),
        ``datetime.time``, ``bytes``, lists; None for NULL (and NaN, NaT).
    type : str
        The Arrow type's name (``"int64"``, ``"int32"``, ``"double"``, ``"string"``,
        ``"bool"``, ``"date32[day]"``, ``"timestamp[ms]"``, ``"timestamp[ms, tz=UTC]"``
        ...); ``"null"`` for a column without any value and no declared type.
    """
    import pyarrow as pa

    try:
        arr = pa.array(series.array, from_pandas=True)
    except (pa.ArrowInvalid, pa.ArrowTypeError, pa.ArrowNotImplementedError, TypeError):
        vals = [None if _is_missing(v) else v for v in series.tolist()]
        return vals, "string" if all(isinstance(v, str) for v in vals if v is not None) else (
            "mixed")
    if pa.types.is_timestamp(arr.type) and arr.type.unit == "ns":  # whole microseconds
        arr = arr.cast(pa.timestamp("us", arr.type.tz), safe=False)
    return arr.to_pylist(), str(arr.type)


def _is_missing(v) -> bool:
    """None, NaN, NaT or pandas' NA."""
    if v is None:
        return True
    try:
        return bool(v != v)
    except (TypeError, ValueError):  # pandas' NA has no truth value: it is missing
        return True


def _attribute_columns(gdf, columns: list, declared: Optional[dict] = None) -> tuple:
    """``({field: values}, {field: type})`` of the attribute columns (:func:`_column_values`).

    ``declared``: a shapefile's field types as GDAL reads them by default
    (:func:`_shapefile_types`). Read with ``ADJUST_TYPE`` (:func:`_typed_reading`), a
    field of 64-bit integers whose values fit 32 bits comes as 32-bit: its type is
    widened back to the 64-bit one the file states.
    """
    values, types = {}, {}
    for c in columns:
        values[c], types[c] = _column_values(gdf[c])
    for c, t in (declared or {}).items():
        if types.get(c) in ("int8", "int16", "int32") and t in _WIDE_INTEGER_TYPES:
            types[c] = "int64"
    return values, types


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


def sample_dem(path: str, xy: np.ndarray, project_crs, report: Optional[dict] = None
               ) -> np.ndarray:
    """Heights at ``xy`` (project CRS) by bilinear interpolation; NaN where uncovered.

    ``report``, when given, receives ``"crs"``: the transformation from the project CRS to
    the DEM's (:func:`transformation_info`; None when the DEM is in the project CRS), and
    then ``"grid"``: the DEM as a :class:`~vectoradjust.model.DemGrid`.
    """
    from pyproj import CRS

    from vectoradjust.adjust.dem import bilinear

    grid, gt, nodata, crs = read_dem(path)
    pts = np.asarray(xy, float)
    info = None
    if crs is None:
        raise CRSError(f"{path}: the DEM has no coordinate reference system",
                       "Assign the CRS to the GeoTIFF (gdal_edit.py -a_srs)", path=str(path))
    if not same_crs(crs, project_crs):
        pcrs = CRS.from_user_input(project_crs)
        finite = pts[np.isfinite(pts).all(axis=1)]
        bounds = (np.r_[finite.min(axis=0), finite.max(axis=0)] if len(finite) else None)
        t, info = transformation_info(pcrs, crs, bounds)
        x, y = t.transform(pts[:, 0], pts[:, 1])
        pts = np.column_stack([x, y])
    if report is not None:
        report["crs"] = info
        if info is None:  # in the project CRS: kept for heights at shifted positions
            from vectoradjust.model import DemGrid

            report["grid"] = DemGrid(grid, tuple(gt), nodata)
    return bilinear(grid, gt, pts, nodata=nodata)


def load_project_data(project, vectors: Optional[list] = None,
                      progress=None) -> ProjectData:
    """Read every file a project refers to.

    Parameters
    ----------
    project : str, os.PathLike or ProjectSpec
    vectors : list of str, optional
        Only these ``[[vectors]]`` entries are read (default: all).
    progress : callable, optional
        ``progress(fraction, message)`` before each file is read.

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
        The control points are in the project CRS (:func:`control_to_project_crs`), the
        DEM heights in its vertical datum (:func:`dem_heights`).
    """
    from vectoradjust.files.assemble import project_data
    from vectoradjust.files.tables import read_fiducials

    spec = project if isinstance(project, ProjectSpec) else load_project(project)
    where = str(spec.path) if spec.path else "<project>"
    crs = check_projected_crs(spec.crs, f"{where}: crs")
    unit = spec.measurements.get("unit", "mm")
    steps = 3 + 3 * len(spec.vectors)
    done = [0]

    def say(message: str) -> None:
        if progress is not None:
            progress(min(done[0] / steps, 1.0), message)
        done[0] += 1

    say("reading the image measurements")
    raw_meas = read_measurements(spec.measurements["path"], spec.measurements.get("sigma"),
                                 unit=unit)
    say("reading the control points")
    control = read_control(spec.control["path"]) if spec.control is not None else None
    if control is not None:
        control = control_to_project_crs(control, spec, crs, where)
    fid_path = spec.measurements.get("fiducials")
    fiducials = read_fiducials(fid_path, unit) if fid_path else None
    trajectory_warnings = _trajectory(spec, crs, where)
    layers = []
    truth = {}
    names = vectors or [v.name for v in spec.vectors]
    for v in spec.vectors:
        if v.name not in names:
            continue
        say(f"reading the road layer {v.name}")
        layer = read_line_layer(v.path, v.name, v.id_field, _parts(crs)[0], v.layer, v.where)
        say(f"heights of {v.name} from the DEM")
        if v.dem:
            dem_report: dict = {}
            z = sample_dem(v.dem, layer.coords[:, :2], _parts(crs)[0], dem_report)
            layer.coords[:, 2], heights = dem_heights(z, layer.coords[:, :2], spec, crs,
                                                      f"{where} [[vectors]] {v.name!r} dem")
            layer.reading["dem"] = {"source": v.dem, "crs": dem_report.get("crs"),
                                    "heights": heights}
            layer.dem = dem_report.get("grid")
        layers.append((v, layer))
        say(f"reading the truth of {v.name}")
        if v.truth:
            truth[v.name] = read_truth_points(v.truth)
    for n in names:
        spec.vector(n)  # raises a clear error for an unknown name
    say("refining the image coordinates")
    # refinement (DESIGN 5), camera, [qa], truth: vectoradjust.files.assemble, shared with QGIS;
    # the project CRS is projected (checked above): earth curvature applies when asked
    data = project_data(spec, raw_meas, control, layers, crs=crs.to_string(), truth=truth,
                        fiducials=fiducials, map_projection=bool(crs.is_projected),
                        source=where)
    if spec.has_rpc:
        say("reading the RPCs of the satellite images")
        read_rpc_images(data, spec, crs.to_string())
    data.reading_warnings.extend(trajectory_warnings)
    return data


def _trajectory(spec: ProjectSpec, project_crs, where: str) -> list:
    """``[trajectory]``: GNSS/INS positions (and attitudes, sigmas) into the
    ``[[images]]`` entries, transformed to the project CRS like the control points;
    returns the warnings (images without a row, the transformation's)."""
    if not spec.trajectory:
        return []
    from vectoradjust.files.trajectory import apply_trajectory, read_trajectory

    table = spec.trajectory
    w = f"{where} [trajectory]"
    cols = read_trajectory(table["path"])
    xyz = np.column_stack([cols["X"], cols["Y"], cols["Z"]])
    source = _user_crs(table["crs"], f"{w} crs") if table.get("crs") else project_crs
    vname = table.get("vertical_crs") or spec.vertical_crs
    if vname:
        source = _with_vertical(source, _user_crs(vname, f"{w} vertical_crs"), w)
    target = _project_target(project_crs, spec, where)
    warnings: list = []
    if not same_crs(source, target):
        xyz, info = transform_points(xyz, source, target, f"{w} ({table['path']})")
        if info.get("warning"):
            warnings.append(info["warning"])
    apply_trajectory(spec.images, cols, xyz, str(table["path"]), warnings)
    return warnings


def read_rpc_images(data: ProjectData, spec: ProjectSpec, crs: str) -> None:
    """Read the RPCs of the project's RPC images into their ``ImageSpec.rpc`` and give
    ``data`` the ground frame (project CRS and heights to WGS84 longitude, latitude and
    ellipsoidal height, :func:`vectoradjust.files.rpc.crs_frame`)."""
    from vectoradjust.files.assemble import read_image_rpcs
    from vectoradjust.files.rpc import crs_frame, read_rpc

    near = read_image_rpcs(data.images, read_rpc)
    data.ground_frame = crs_frame(crs, heights=spec.heights or "ellipsoidal",
                                  geoid=spec.vertical_crs if spec.heights == "orthometric"
                                  else None, near=near)
