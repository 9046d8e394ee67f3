"""Coordinate reference systems: checking, comparing and transforming (pyproj).

A projected CRS in metres required (:func:`check_projected_crs`), CRSs compared by what
they do, not their names (:func:`same_crs`), the transformation chosen for the data's
extent and its accuracy (:func:`transformation_info`), points and control tables
transformed to the project CRS with their vertical datum (:func:`transform_points`,
:func:`control_to_project_crs`), geometries transformed. pyproj and shapely are imported
inside the functions.
"""

from __future__ import annotations

import warnings
from typing import Optional

import numpy as np

from vectoradjust.errors import CRSError
from vectoradjust.files.project import ProjectSpec

__all__ = [
    "check_projected_crs",
    "control_to_project_crs",
    "transform_points",
    "transformation_info",
    "same_crs",
    "TRANSFORMATION_ACCURACY_LIMIT",
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


#: a transformation less accurate than this (m), or of unknown accuracy, is a warning
TRANSFORMATION_ACCURACY_LIMIT = 1.0


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
