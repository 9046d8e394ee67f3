"""Line layers: found in a source, read with their attributes, flattened to arrays.

:func:`line_layers` and :func:`choose_layer` find the line layers of a source
(GeoPackage, shapefile, FileGDB, OSM PBF ...); :func:`read_line_layer` reads one (pyogrio,
geopandas), keeps the attributes with their types, checks the feature ids and
transforms it to the project CRS; :func:`layer_from_geometries` flattens shapely
geometries to a :class:`~vectoradjust.model.LineLayer`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import numpy as np

from vectoradjust.errors import CRSError, InputFileError, LayerError
from vectoradjust.files.readers.crs import _to_project_crs
from vectoradjust.model import LineLayer

__all__ = [
    "choose_layer",
    "line_layers",
    "read_line_layer",
    "layer_from_geometries",
    "EXACT_REAL_INTEGER",
]


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
    types = _line_geometry_types(p, gdf, entry)
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


def _line_geometry_types(p: Path, gdf, entry: str) -> set:
    """The geometry types of the frame read from ``p``; a table without geometries, a
    layer without CRS (:class:`CRSError`) or one without lines is an error."""
    if not hasattr(type(gdf), "geometry"):  # pyogrio gives a DataFrame: no geometry column
        raise LayerError(f"{p} ({entry}): the layer has no geometries (a table: "
                         f"{', '.join(map(str, gdf.columns)) or 'no fields'})",
                         "Give the road centrelines as a line layer (shapefile, GeoPackage, "
                         "GeoJSON ...)", path=str(p))
    if gdf.crs is None:
        raise CRSError(f"{p}: the layer has no coordinate reference system",
                       "Add a .prj file (or define the CRS in your GIS and save again)",
                       path=str(p))
    types = set(t for t in gdf.geometry.geom_type.dropna().unique())
    if types and not types & {"LineString", "MultiLineString", "LinearRing"}:
        raise LayerError(
            f"{p}: the layer holds {', '.join(sorted(types))} geometries, not lines",
            "Give the road centrelines as a LineString layer", path=str(p))
    return types


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
