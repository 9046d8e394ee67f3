"""True centrelines (``[truth]``) and the buffer test of a run against them.

With a ``[truth]`` table (true centrelines) in the project, ``adjust`` and ``compare`` add
the share of each database's lines inside 1 m and 2 m (or ``widths``) of the truth
before and after the adjustment to ``summary.json`` (``databases[].truth.buffer``).
Reading uses geopandas/pyproj, imported inside the functions.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import numpy as np

from vectoradjust.errors import LayerError, ProjectError

__all__ = ["parse_widths", "read_lines", "truth_buffer", "project_truth"]


def parse_widths(text) -> list:
    """``"1,2,5"`` or a list of numbers -> sorted positive widths (m)."""
    if isinstance(text, str):
        parts = [p for p in text.replace(";", ",").split(",") if p.strip()]
    else:
        parts = list(text)
    try:
        widths = sorted({float(p) for p in parts})
    except (TypeError, ValueError) as exc:
        raise ProjectError(f"buffer widths {text!r} are not numbers",
                           "Give widths in metres, e.g. --widths 1,2,5") from exc
    if not widths or widths[0] < 0:
        raise ProjectError(f"buffer widths {text!r} must be >= 0 and not empty",
                           "Give widths in metres, e.g. --widths 1,2,5")
    return widths


def read_lines(path, crs=None, layer=None):
    """The line geometries of a layer (shapely), transformed to ``crs`` if given.

    Returns
    -------
    geometries : numpy.ndarray of shapely geometries
    crs : pyproj.CRS
    """
    import geopandas as gpd

    from vectoradjust.files.readers import check_projected_crs

    p = Path(path)
    if not p.exists():
        raise LayerError(f"Line layer {str(p)!r} does not exist", "Check the path", path=str(p))
    try:
        gdf = gpd.read_file(p, **({"layer": layer} if layer else {}))
    except Exception as exc:  # pyogrio raises several types
        raise LayerError(f"{p}: cannot be read as a vector layer ({exc})",
                         "Give a shapefile, GeoPackage or GeoJSON of lines", path=str(p)) from exc
    if not isinstance(gdf, gpd.GeoDataFrame):
        raise LayerError(f"{p}: has no geometries", "Give a line layer to the buffer test",
                         path=str(p))
    if gdf.crs is None:
        raise LayerError(f"{p}: the layer has no coordinate reference system",
                         "Add a .prj file or define the CRS", path=str(p))
    types = set(gdf.geometry.geom_type.dropna())
    if types - {"LineString", "MultiLineString", "LinearRing"}:
        raise LayerError(f"{p}: holds {', '.join(sorted(types))} geometries, not lines",
                         "Give line layers to the buffer test", path=str(p))
    target = crs if crs is not None else gdf.crs
    check_projected_crs(target, f"{p}")
    if not gdf.crs.equals(target):
        gdf = gdf.to_crs(target)
    return gdf.geometry.to_numpy(), gdf.crs


def _lines(xy: np.ndarray, feature: np.ndarray, part: np.ndarray) -> list:
    """LineStrings from vertex arrays (one per feature part with >= 2 vertices)."""
    import shapely

    key = feature * 100000 + part
    if len(key) == 0:
        return []
    brk = np.flatnonzero(np.diff(key)) + 1
    return [shapely.linestrings(xy[s:e]) for s, e in zip(np.r_[0, brk], np.r_[brk, len(key)])
            if e - s >= 2]


def truth_buffer(run, truth_path, widths=(1.0, 2.0)) -> dict:
    """Share of each database's lines inside buffers of the true lines, before and after.

    Only features with at least one adjusted vertex are compared (the others did not
    move). Returns ``{database: {"widths", "before", "after"}}`` and writes the same into
    ``run.summary["databases"][i]["truth"]["buffer"]``.
    """
    from pyproj import CRS

    from vectoradjust.accuracy.buffer import buffer_test

    truth, _ = read_lines(truth_path, CRS.from_user_input(run.data.crs))
    out = {}
    for d, entry in zip(run.databases, run.summary.get("databases", [])):
        layer = d.shape.layer
        measured = np.unique(layer.vertex_feature[d.vertices["Adjusted"] == 1])
        keep = np.isin(layer.vertex_feature, measured)
        if not keep.any():
            continue
        fp = (layer.vertex_feature[keep], layer.vertex_part[keep])
        before = buffer_test(_lines(layer.coords[keep, :2], *fp), truth, widths)
        after = buffer_test(_lines(d.adjusted_coords[keep, :2], *fp), truth, widths)
        res = {"widths": list(widths), "before": [r["share"] for r in before],
               "after": [r["share"] for r in after], "truth_lines": str(truth_path)}
        out[d.name] = res
        entry.setdefault("truth", {})["buffer"] = res
    return out


def project_truth(spec) -> Optional[tuple]:
    """``(path, widths)`` of the project's ``[truth]`` table, or None."""
    t = spec.raw.get("truth")
    if not t:
        return None
    if not isinstance(t, dict) or "path" not in t:
        raise ProjectError(f"{spec.path}: [truth] needs path = \"truth_roads.shp\"",
                           "Give the true centrelines as a line layer")
    p = Path(t["path"])
    p = p if p.is_absolute() else spec.base_dir / p
    return str(p), parse_widths(t.get("widths", [1.0, 2.0]))
