"""Smart conflation's files: the adjusted databases read from output folders or vector
files, the conflated layer, its table and summary written.

``read_sources`` reads each SOURCE (an output folder of ``vectoradjust adjust``:
``adjusted.gpkg`` layer ``features``; or a vector file of adjusted features with a
``CE90`` column) into one GeoDataFrame per database, :func:`feature_sets` turns them
into the arrays of :class:`vectoradjust.conflation.smart.FeatureSet`, and
:func:`conflated_frame` / :func:`write_smart` write ``conflated.gpkg`` (layer
``conflated``), ``conflated.csv`` and ``summary.json``. geopandas and pyogrio are
imported inside the functions only.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Optional

import numpy as np

from vectoradjust.errors import CRSError, InputFileError, LayerError, ProjectError

__all__ = ["NAME_FIELDS", "CLASS_FIELDS", "read_sources", "feature_set", "feature_sets",
           "join_parts", "line_arrays",
           "conflated_frame", "write_smart", "summary_table", "choice_rows"]

#: attributes holding a road's name, first found wins
NAME_FIELDS = ("name", "fullname", "FULLNAME", "NAME", "nimi")
#: attributes holding a road's class (compared only within the same attribute)
CLASS_FIELDS = ("highway", "mtfcc", "MTFCC", "fclass", "class")
#: columns the conflation writes (an input column of the same name is replaced)
OWN_COLUMNS = ("Source", "Loser", "LoserOffset", "LoserCE90", "LoserRMSE", "MatchScore",
               "NSources")


def _read_layer(path: Path, layer: Optional[str]):
    import geopandas as gpd
    import pyogrio

    try:
        layers = [str(x[0]) for x in pyogrio.list_layers(path)]
    except Exception as exc:  # noqa: BLE001 - GDAL's message is passed on
        raise InputFileError(f"{path}: cannot be read as a vector file ({exc})",
                             "Give an output folder of 'vectoradjust adjust' or a "
                             "GeoPackage/Shapefile of adjusted features", path=path) from None
    if layer is None:
        layer = "features" if "features" in layers else layers[0]
    if layer not in layers:
        raise LayerError(f"{path}: no layer {layer!r} (layers: {', '.join(layers)})",
                         "Give the output folder of 'vectoradjust adjust' or its "
                         "adjusted.gpkg", path=path)
    return gpd.read_file(path, layer=layer)


def _source_frames(source: Path) -> tuple:
    """``(frame, default name)`` of one SOURCE (a folder or a vector file)."""
    if source.is_dir():
        gpkg = source / "adjusted.gpkg"
        if not gpkg.is_file():
            raise InputFileError(f"{source}: no adjusted.gpkg in the folder",
                                 "Give the output folder of 'vectoradjust adjust'",
                                 path=source)
        return _read_layer(gpkg, "features"), source.name
    if not source.exists():
        raise InputFileError(f"{source}: not found", "Check the path of the SOURCE",
                             path=source)
    return _read_layer(source, None), source.stem


def _split(frame, default: str, path: Path) -> list:
    """``[(database, frame)]`` of one source: by its ``Database`` column, else one."""
    if "CE90" not in frame.columns:
        raise LayerError(f"{path}: no CE90 column (columns: {', '.join(map(str, frame.columns))})",
                         "Give adjusted features (the features layer of 'vectoradjust "
                         "adjust'), which have CE90 per feature", path=path)
    if frame.crs is None:
        raise CRSError(f"{path}: the layer has no coordinate reference system",
                       "Give a layer with a projected CRS (metres)", path=path)
    if frame.crs.is_geographic:
        raise CRSError(f"{path}: the CRS {frame.crs.to_string()} is geographic (degrees)",
                       "Give adjusted features in a projected CRS (metres)", path=path)
    if "Database" in frame.columns:
        return [(str(db), frame[frame["Database"] == db].reset_index(drop=True))
                for db in dict.fromkeys(frame["Database"].astype(str))]
    return [(default, frame.reset_index(drop=True))]


def read_sources(sources: Sequence, databases: Optional[Sequence[str]] = None) -> list:
    """The adjusted databases of the SOURCES: ``[(name, GeoDataFrame)]``.

    Parameters
    ----------
    sources : sequence of path-like
        Output folders of ``vectoradjust adjust`` or vector files of adjusted features.
    databases : sequence of str, optional
        Keep only these databases (by the ``Database`` column, or a file's stem).

    Returns
    -------
    list of tuple
        In the order of the sources; names made unique with the source's name where
        two sources hold a database of the same name. All in the first one's CRS.

    Raises
    ------
    InputFileError, LayerError, CRSError, ProjectError
    """
    out: list = []
    for src in sources:
        path = Path(src)
        frame, default = _source_frames(path)
        for name, f in _split(frame, default, path):
            if any(n == name for n, _ in out):
                name = f"{default}:{name}"
            out.append((name, f))
    if databases:
        known = [n.split(":")[-1] for n, _ in out]
        missing = [d for d in databases if d not in known and d not in [n for n, _ in out]]
        if missing:
            raise ProjectError(f"--databases {' '.join(missing)}: not in the sources "
                               f"(they hold {', '.join(n for n, _ in out)})",
                               "Name databases of the sources' Database column")
        rank = {d: k for k, d in enumerate(databases)}
        out = sorted([(n, f) for n, f in out if n in rank or n.split(":")[-1] in rank],
                     key=lambda nf: rank.get(nf[0], rank.get(nf[0].split(":")[-1])))
    if len(out) < 2:
        raise ProjectError(f"smart conflation needs two or more databases; the sources "
                           f"hold {len(out)} ({', '.join(n for n, _ in out) or 'none'})",
                           "Give a folder adjusted with two or more [[vectors]], or "
                           "more SOURCES")
    crs = out[0][1].crs
    return [(n, f if f.crs == crs else f.to_crs(crs)) for n, f in out]


def join_parts(parts) -> np.ndarray:
    """The XY of a line's parts (arrays of ``(n, >= 2)`` coordinates) as one ``(m, 2)``
    array with a NaN row between parts (empty: ``(0, 2)``)."""
    parts = [np.asarray(p, float)[:, :2] for p in parts if p is not None and len(p)]
    if not parts:
        return np.empty((0, 2))
    gap = np.full((1, 2), np.nan)
    return np.vstack([x for p in parts for x in (p, gap)][:-1])


def line_arrays(geoms) -> list:
    """Per geometry the ``(n, 2)`` XY of its lines (NaN rows between parts)."""
    import shapely

    return [np.empty((0, 2)) if g is None or g.is_empty else
            join_parts([shapely.get_coordinates(p) for p in shapely.get_parts(g)])
            for g in geoms]


def _first(columns: dict, fields, as_class: bool = False) -> Optional[np.ndarray]:
    from vectoradjust.conflation.smart import normalise_name

    for f in fields:
        if f in columns:
            vals = list(columns[f])
            if as_class:
                return np.array([None if v is None or v != v or str(v) == "" else f"{f}={v}"
                                 for v in vals], object)
            return np.array([normalise_name(v) for v in vals], object)
    return None


def _numbers(columns: dict, name: str, n: int) -> np.ndarray:
    if name not in columns:
        return np.full(n, np.nan)
    return np.array([np.nan if v is None else float(v) for v in columns[name]], float)


def feature_set(name: str, xy: list, columns: dict):
    """A :class:`vectoradjust.conflation.smart.FeatureSet` from the features' XY arrays
    and their attribute columns (``{field: values}``: ``CE90``, ``LE90``, ``RMSE``, a
    name field of :data:`NAME_FIELDS`, a class field of :data:`CLASS_FIELDS`). No
    geodata package: the QGIS algorithm calls it with what QGIS read."""
    from vectoradjust.conflation.smart import FeatureSet

    n = len(xy)
    return FeatureSet(name, xy, _numbers(columns, "CE90", n), _numbers(columns, "LE90", n),
                      _numbers(columns, "RMSE", n), _first(columns, NAME_FIELDS),
                      _first(columns, CLASS_FIELDS, as_class=True))


def feature_sets(sources: list) -> list:
    """The :class:`vectoradjust.conflation.smart.FeatureSet` of each ``(name, frame)``."""
    out = []
    for name, f in sources:
        columns = {c: f[c].to_numpy(object) for c in f.columns if c != f.geometry.name}
        out.append(feature_set(name, line_arrays(f.geometry), columns))
    return out


def _attribute_names(sources: list) -> dict:
    """Per database its attribute columns -> output column: the same name where every
    database holding it gives it one kind (number, text, ...), else ``<db>_<name>``."""
    kinds: dict = {}
    for _, f in sources:
        for c in f.columns:
            if c != f.geometry.name:
                kinds.setdefault(c, set()).add(f[c].dtype.kind if f[c].dtype.kind in "biuf"
                                               else "O")
    rename = {}
    for name, f in sources:
        rename[name] = {c: (c if len(kinds[c]) == 1 else f"{name}_{c}")
                        for c in f.columns if c != f.geometry.name and c not in OWN_COLUMNS
                        and c != "Database"}
    return rename


def conflated_frame(sources: list, result):
    """The conflated layer: per row the winner's attributes and line, ``Source``,
    ``CE90``/``LE90`` (the winner's), ``Loser``, ``LoserOffset``, ``LoserCE90`` /
    ``LoserRMSE`` (the smallest of the losers'), ``MatchScore`` and ``NSources``
    (databases in the match).

    Parameters
    ----------
    sources : list of tuple
        ``[(name, GeoDataFrame)]`` as given to :func:`feature_sets`.
    result : vectoradjust.conflation.smart.SmartResult

    Returns
    -------
    geopandas.GeoDataFrame
    """
    import geopandas as gpd
    import pandas as pd

    rename = _attribute_names(sources)
    parts = []
    for k, (name, f) in enumerate(sources):
        rows = np.flatnonzero(result.source == k)
        if not len(rows):
            continue
        sub = f.iloc[result.feature[rows]].rename(columns=rename[name])
        sub = sub[[*rename[name].values(), f.geometry.name]]
        if f.geometry.name != "geometry":
            sub = sub.rename_geometry("geometry")
        sub.index = rows
        parts.append(sub)
    frame = pd.concat(parts).sort_index()
    frame.insert(0, "Source", [result.sets[s].name for s in result.source])
    frame["Loser"] = result.loser_names()
    frame["LoserOffset"] = result.loser_offset
    frame["LoserCE90"] = result.loser_values("ce90")
    frame["LoserRMSE"] = result.loser_values("rmse")
    frame["MatchScore"] = result.score
    frame["NSources"] = [1 + len(ls) for ls in result.losers]
    return gpd.GeoDataFrame(frame.reset_index(drop=True), geometry="geometry",
                            crs=sources[0][1].crs)


def choice_rows(frame) -> list:
    """The per-feature choice as dictionaries (the CSV's columns, no geometry)."""
    cols = [c for c in frame.columns if c != "geometry"]
    return frame[cols].to_dict("records")


def summary_table(summary: dict) -> str:
    """The summary as a printed table: one row per database."""
    def num(v):
        return "-" if v is None else f"{v:.3f}"

    head = (f"{'database':12s} {'features':>8s} {'matched':>8s} {'unmatched':>9s} "
            f"{'wins':>6s} {'rows':>6s} {'CE90 in':>8s} {'CE90 out':>9s}")
    lines = [head, "-" * len(head)]
    for name, d in summary["databases"].items():
        lines.append(f"{name:12s} {d['features']:8d} {d['matched']:8d} {d['unmatched']:9d} "
                     f"{d['wins']:6d} {d['rows']:6d} {num(d['mean_ce90_input']):>8s} "
                     f"{num(d['mean_ce90']):>9s}")
    lines.append(f"{'conflated':12s} {summary['features']:8d} {summary['matched']:8d} "
                 f"{summary['unmatched']:9d} {'':6s} {summary['features']:6d} {'':8s} "
                 f"{num(summary['mean_ce90']):>9s}")
    lines.append("(matched/unmatched: the database's features; wins: matches it won; rows: "
                 "its features in the product; CE90 in/out: mean CE90 of its features / of "
                 "its rows in the product, m)")
    return "\n".join(lines)


def write_smart(frame, summary: dict, out_dir) -> dict:
    """Write ``conflated.gpkg`` (layer ``conflated``), ``conflated.csv`` (the layer
    without its geometry) and ``summary.json`` into ``out_dir``.

    Parameters
    ----------
    frame : geopandas.GeoDataFrame
        :func:`conflated_frame`.
    summary : dict
    out_dir : path-like

    Returns
    -------
    dict
        ``{"gpkg": path, "csv": path, "summary": path}``.
    """
    import json

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    gpkg, csv, js = out / "conflated.gpkg", out / "conflated.csv", out / "summary.json"
    if gpkg.exists():
        gpkg.unlink()
    frame.to_file(gpkg, layer="conflated", driver="GPKG")
    frame.drop(columns="geometry").to_csv(csv, index=False)
    js.write_text(json.dumps(summary, indent=2, default=_plain), encoding="utf-8")
    return {"gpkg": gpkg, "csv": csv, "summary": js}


def _plain(v):
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, Path):
        return str(v)
    raise TypeError(f"not JSON serialisable: {type(v).__name__}")
