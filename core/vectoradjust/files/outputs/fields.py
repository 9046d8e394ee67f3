"""The output layers' fields: their names, the input attributes' names and types.

The contract's field names (:data:`SHAPE_FIELDS`, :data:`FEATURE_FIELDS`,
:data:`CONTROL_FIELDS`), input attributes renamed where they would clash with them
(:func:`renamed_input_fields`), the input attributes as typed arrays
(:func:`attribute_array`, :func:`input_field_types`) and what a GeoPackage or a
shapefile cannot hold, written otherwise and said so (:func:`field_change`,
:func:`storable_frame`). Shared with the QGIS plugin's writer.
"""

from __future__ import annotations

import datetime as dt
import json
import math
import re
from typing import Optional

import numpy as np

from vectoradjust.results import AdjustmentRun

__all__ = [
    "renamed_input_fields",
    "run_input_fields",
    "input_field_types",
    "attribute_array",
    "storable_frame",
    "field_change",
    "text_value",
    "FIELD_KINDS",
    "SHAPE_FIELDS",
    "FEATURE_FIELDS",
    "CONTROL_FIELDS",
    "RESERVED_NAMES",
    "SHAPEFILE_NAME_LENGTH",
    "SHAPEFILE_INTEGER_DIGITS",
    "SHAPEFILE_INT32_DIGITS",
    "SHAPEFILE_REAL_DECIMALS",
]


SHAPE_FIELDS = ["point_id", "feature_id", "X", "Y", "Z", "Vx", "Vy", "Vz", "AdjX", "AdjY", "AdjZ",
                "SigmaX", "SigmaY", "SigmaZ", "CE90", "LE90", "CE90_meas", "LE90_meas",
                "NImages", "Adjusted", "Database", "Source", "Problem"]
FEATURE_FIELDS = ["NPts", "NAdj", "RMSE_X", "RMSE_Y", "RMSE_Z", "RMSE", "CE90", "LE90",
                  "Length", "LengthSD",
                  "LengthSDnc", "LengthSDOf", "FirstX",
                  "FirstY", "LastX", "LastY", "Images", "ImgDate", "Database", "Problem"]
CONTROL_FIELDS = ["point_id", "role", "X", "Y", "Z", "AdjX", "AdjY", "AdjZ", "Vx", "Vy", "Vz",
                  "SigmaX", "SigmaY", "SigmaZ", "CE90", "LE90", "NImages", "Used"]


#: names an input attribute may not keep besides ours (the geometry column and GeoPackage's fid)
RESERVED_NAMES = ("geometry", "fid")
#: longest field name a shapefile holds
SHAPEFILE_NAME_LENGTH = 10


def renamed_input_fields(names) -> dict:
    """The new names of input attributes that would clash with the product's fields.

    The product's field names (``FEATURE_FIELDS``, the file contract) are fixed. An input
    field whose name equals one of them case-insensitively (GeoPackage and shapefile
    names are case-insensitive), or ``geometry``/``fid``, or an earlier input field, is
    kept as ``in_<name>``: at most 10 characters (shapefile-safe) and unique,
    case-insensitively, among all fields of the ``features`` layer (a number is
    appended when needed).

    Parameters
    ----------
    names : iterable of str
        The input field names, in order.

    Returns
    -------
    dict
        ``{input name: output name}`` of the renamed fields only (empty when none clash).
    """
    names = [str(n) for n in names]
    reserved = {f.lower() for f in FEATURE_FIELDS} | set(RESERVED_NAMES)
    taken = reserved | {n.lower() for n in names}
    seen: set = set()
    out: dict = {}
    for n in names:
        low = n.lower()
        if low not in reserved and low not in seen:
            seen.add(low)
            continue
        new = ("in_" + n)[:SHAPEFILE_NAME_LENGTH]
        k = 1
        while new.lower() in taken:
            tail = str(k)
            new = ("in_" + n)[:SHAPEFILE_NAME_LENGTH - len(tail)] + tail
            k += 1
        taken.add(new.lower())
        out[n] = new
    return out


def run_input_fields(run: AdjustmentRun) -> list:
    """The input attribute names of all databases of a run (first appearance order)."""
    names: list = []
    for d in run.databases:
        names += [n for n in d.shape.layer.attributes if n not in names]
    return names


def _arrow_type(name: Optional[str]):
    """The Arrow type of a type name (:func:`vectoradjust.files.readers.read_line_layer`'s
    ``reading["fields"]``), or None when the name gives none (then the values tell)."""
    import pyarrow as pa

    if not name or name in ("null", "mixed"):
        return None
    try:
        return pa.type_for_alias(name)
    except (ValueError, KeyError):
        pass
    m = re.fullmatch(r"timestamp\[(s|ms|us|ns), tz=(.+)\]", name)
    return pa.timestamp(m.group(1), m.group(2)) if m else None


_ARROW_ERRORS = ("ArrowInvalid", "ArrowTypeError", "ArrowNotImplementedError")


def attribute_array(values, type_name: Optional[str] = None):
    """An input attribute column as an Arrow array of its type, values exact.

    Parameters
    ----------
    values : sequence
        Plain Python values (``int`` exact beyond 2^53, ``datetime.date`` ...), None or
        NaN for NULL.
    type_name : str, optional
        Arrow type name (``"int32"``, ``"date32[day]"``, ``"timestamp[ms, tz=UTC]"`` ...):
        kept even when every value is NULL. Without it, or when the values do not fit it,
        the type is inferred from the values; values of no common type are written as
        text.

    Returns
    -------
    pyarrow.Array
    """
    import pyarrow as pa

    errors = tuple(getattr(pa, e) for e in _ARROW_ERRORS) + (TypeError, ValueError,
                                                             OverflowError)
    wanted = _arrow_type(type_name)
    vals = values.tolist() if isinstance(values, np.ndarray) else list(values)
    for t in ([wanted] if wanted is not None else []) + [None]:
        try:
            arr = pa.array(vals, type=t, from_pandas=True)
        except errors:
            continue
        if not pa.types.is_null(arr.type):
            return arr
    return pa.array([None if _missing(v) else (v.isoformat() if hasattr(v, "isoformat")
                                                else str(v)) for v in vals], type=pa.string())


def _pandas_column(arr):
    """An Arrow array as a pandas column of the same type (pandas' Arrow types); the plain
    Python values where pandas has none (before 1.5)."""
    import pandas as pd

    make = getattr(pd.arrays, "ArrowExtensionArray", None)
    return make(arr) if make is not None else arr.to_pylist()


def _missing(v) -> bool:
    """None, NaN, NaT or pandas' NA."""
    if v is None:
        return True
    try:
        return bool(v != v)
    except (TypeError, ValueError):  # pandas' NA has no truth value
        return True


def _common_type(names: list) -> Optional[str]:
    """One type for a field that several databases hold: their own when they agree,
    the widest integer or a real when all are numbers, else text."""
    import pyarrow as pa

    given = list(dict.fromkeys(n for n in names if n and n not in ("null", "mixed")))
    if len(given) <= 1:
        return given[0] if given else None
    types = [_arrow_type(n) for n in given]
    if all(t is not None and pa.types.is_integer(t) for t in types):
        return "int64"
    if all(t is not None and (pa.types.is_integer(t) or pa.types.is_floating(t))
           for t in types):
        return "double"
    return "string"


def input_field_types(run: AdjustmentRun) -> dict:
    """``{input field: Arrow type name or None}`` over all databases of a run.

    A database's type of a field is the one its reader states (``LineLayer.reading
    ["fields"]``), else the one its values give; several databases holding a field with
    different types get one common type (:func:`_common_type`).
    """
    seen: dict = {}
    for d in run.databases:
        layer = d.shape.layer
        stated = (getattr(layer, "reading", None) or {}).get("fields") or {}
        for name, values in layer.attributes.items():
            t = stated.get(name) or str(attribute_array(values).type)
            seen.setdefault(name, []).append(t)
    return {name: _common_type(ts) for name, ts in seen.items()}


#: the longest integer text (sign included) GDAL reads back from a shapefile as an
#: integer: a wider DBF numeric field is read as real numbers
SHAPEFILE_INTEGER_DIGITS = 18
#: the longest 32-bit integer text a shapefile's integer field is read back as 32-bit
SHAPEFILE_INT32_DIGITS = 9
#: decimals of a real in a shapefile (GDAL writes a real field as DBF ``N(24, 15)``)
SHAPEFILE_REAL_DECIMALS = 15
_FORMAT_NAMES = {"gpkg": "a GeoPackage", "shp": "a shapefile"}
#: the kinds of attribute :func:`field_change` knows
FIELD_KINDS = ("int8", "int16", "int32", "int64", "uint8", "uint16", "uint32", "uint64",
               "float16", "float32", "float64", "string", "bool", "date", "datetime", "time",
               "binary", "list", "struct", "other")


def text_value(v, kind: str = "other") -> Optional[str]:
    """An attribute value as the text a format without its type gets: ISO 8601 for dates
    and times, JSON for lists and structures, hexadecimal for binary, the digits of a
    number; None stays None."""
    if v is None:
        return None
    if kind in ("list", "struct"):
        return json.dumps(v, ensure_ascii=False, default=lambda o: (
            o.isoformat() if hasattr(o, "isoformat") else
            bytes(o).hex() if isinstance(o, (bytes, bytearray)) else str(o)))
    if isinstance(v, (bytes, bytearray, memoryview)):
        return bytes(v).hex()
    if isinstance(v, (dt.datetime, dt.time)) and v.microsecond % 1000 == 0 and v.microsecond:
        return v.isoformat(timespec="milliseconds")  # as GDAL writes them
    return v.isoformat() if hasattr(v, "isoformat") else str(v)


def field_change(kind: str, values, fmt: str,
                 hint: str = "use --format gpkg") -> Optional[tuple]:
    """What ``fmt`` cannot hold of an attribute field, and what is written instead.

    Parameters
    ----------
    kind : str
        One of :data:`FIELD_KINDS` (``"int64"``, ``"datetime"`` ...).
    values : sequence
        The field's values, plain Python (None for NULL).
    fmt : {"gpkg", "shp"}
    hint : str
        How the user keeps the type (the command line: ``use --format gpkg``).

    Returns
    -------
    tuple or None
        None when the format holds the field as it is; else ``(as_text, what)``:
        ``as_text`` true when the field is to be written as text (:func:`text_value`),
        false when the values are written as they are but come back otherwise; ``what``
        the warning's text after the field's name. A time of day is text in both
        formats; for a shapefile, a date and time is text (ISO 8601), so are integers
        wider than :data:`SHAPEFILE_INTEGER_DIGITS` characters (GDAL would read them back
        as reals), binary (hexadecimal) and lists (JSON); integers read back with another
        width and reals with more than :data:`SHAPEFILE_REAL_DECIMALS` decimals are
        reported.
    """
    fmt_name = _FORMAT_NAMES.get(fmt, fmt)
    keep = f"; {hint} to keep it" if fmt == "shp" else ""
    if kind == "time":
        return True, f"(time of day) is written as text (HH:MM:SS): {fmt_name} has no time type"
    if kind == "struct" or (fmt == "shp" and kind == "list"):
        return True, f"(a list or structure) is written as JSON text{keep}"
    if fmt != "shp":
        return None
    if kind == "datetime":
        return True, ("(date and time) is written as text (ISO 8601, e.g. 2021-03-04T05:06:07): "
                      f"a shapefile has no date-time type{keep}")
    if kind == "binary":
        return True, f"(binary) is written as hexadecimal text{keep}"
    if kind.startswith(("int", "uint")):
        return _shapefile_integers(kind, values, hint)
    if kind.startswith("float"):
        return _shapefile_reals(kind, values, hint)
    return None


def _shapefile_reals(kind: str, values, hint: str) -> Optional[tuple]:
    """:func:`field_change` of reals in a shapefile: the DBF holds them as text with
    :data:`SHAPEFILE_REAL_DECIMALS` decimals (GDAL's ``N(24, 15)``)."""
    vals = [float(v) for v in values if v is not None and math.isfinite(float(v))]
    changed = [v for v in vals if float(f"{v:.{SHAPEFILE_REAL_DECIMALS}f}") != v]
    what = []
    if kind != "float64":
        what.append(f"({kind[5:]}-bit reals) is read back as 64-bit reals")
    if changed:
        v = changed[0]
        what.append(f"{'and has' if what else 'has'} {len(changed)} of its {len(vals)} values "
                    f"with more than {SHAPEFILE_REAL_DECIMALS} decimals (e.g. {v!r} is written "
                    f"as {float(f'{v:.{SHAPEFILE_REAL_DECIMALS}f}')!r}): a shapefile holds "
                    f"reals as text with {SHAPEFILE_REAL_DECIMALS} decimals; {hint} to keep "
                    "them exact")
    return (False, " ".join(what)) if what else None


def _shapefile_integers(kind: str, values, hint: str) -> Optional[tuple]:
    """:func:`field_change` of integers in a shapefile."""
    vals = [int(v) for v in values if v is not None]
    widest = max(vals, key=lambda v: len(str(v)), default=0)
    width = len(str(widest))
    if width > SHAPEFILE_INTEGER_DIGITS:
        return True, (
            f"holds integers wider than {SHAPEFILE_INTEGER_DIGITS} characters (e.g. {widest}), "
            "which a shapefile cannot give back exactly (GDAL reads so wide a field as real "
            "numbers): the field is written as text, every digit kept; "
            f"{hint} to keep it an integer field")
    unsigned = kind.startswith("u")
    bits = int(kind[4:] if unsigned else kind[3:])
    back = 64 if bits > 32 or width > SHAPEFILE_INT32_DIGITS or (unsigned and bits == 32) else 32
    if back == bits and not unsigned:
        return None
    return False, (f"({'unsigned ' if unsigned else ''}{bits}-bit integers) is read back as "
                   f"{back}-bit integers, the values unchanged: a shapefile's integer type "
                   "follows the field's width")


def _arrow_kind(t) -> str:
    """The :data:`FIELD_KINDS` name of an Arrow type."""
    import pyarrow as pa

    if pa.types.is_integer(t):
        return str(t)  # int8 ... uint64
    if pa.types.is_floating(t):
        return f"float{t.bit_width}"
    for test, kind in ((pa.types.is_boolean, "bool"), (pa.types.is_date, "date"),
                       (pa.types.is_timestamp, "datetime"), (pa.types.is_time, "time"),
                       (pa.types.is_string, "string"), (pa.types.is_large_string, "string"),
                       (pa.types.is_binary, "binary"), (pa.types.is_large_binary, "binary"),
                       (pa.types.is_list, "list"), (pa.types.is_large_list, "list"),
                       (pa.types.is_struct, "struct"), (pa.types.is_map, "struct")):
        if test(t):
            return kind
    return "other"


def storable_frame(gdf, fmt: str, where: str) -> tuple:
    """The frame as ``fmt`` can hold it, and a run warning per field it changes.

    The input attribute columns (pandas Arrow types, :func:`features_frame`) go through
    :func:`field_change`: a field the format cannot hold is written as text
    (:func:`text_value`), or as it is when only its reading back differs; each is a
    warning naming the field. What the driver itself changes (names cut to 10
    characters, texts to 254) is reported from GDAL's warnings (:func:`_writer_warning`).

    Returns
    -------
    frame : GeoDataFrame
        ``gdf`` itself when nothing changes, else a changed copy.
    notes : list of str
        ``"<where>: field 'stamp' (date and time) is written as text ..."``.
    """
    import pandas as pd
    import pyarrow as pa

    out, notes = gdf, []
    geometry = getattr(gdf, "_geometry_column_name", "geometry")
    for name in gdf.columns:
        if name == geometry or not isinstance(gdf[name].dtype, getattr(pd, "ArrowDtype", ())):
            continue
        arr = pa.array(gdf[name].array)
        kind = _arrow_kind(arr.type)
        values = arr.to_pylist()
        change = field_change(kind, values, fmt)
        if change is None:
            continue
        as_text, what = change
        notes.append(f"{where}: field {name!r} {what}")
        if as_text:
            out = out.copy() if out is gdf else out
            out[name] = _pandas_column(
                pa.array([text_value(v, kind) for v in values], type=pa.string()))
    return out, notes
