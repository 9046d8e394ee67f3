"""Measured ids to control, check, shape and tie points, and the bundle problem they make.

The first stages of :func:`vectoradjust.pipeline.run`:

1. :func:`classify_measurements` - every measurement's image and point: a control or
   check point of the control file, a shape point (vertex) of a road database, or else a
   tie point; the checks that make an adjustment possible (known images, unambiguous ids,
   tie points on two images; whether the datum is fixed is decided later, by
   :mod:`vectoradjust.adjust.datum`).
2. :func:`build_problem` - the object points (control, the selected databases' shape
   points, tie points) with their priors, the images with their approximate exterior
   orientation, and the :class:`~vectoradjust.adjust.bundle.BundleProblem`.

Numpy only; every error names the file and line (or feature) to mend.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from vectoradjust.adjust.bundle import BundleProblem, ray_intersection
from vectoradjust.adjust.intersection import (
    approximate_points,
    check_bias_determined,
    check_rpc_domain,
    pts_have_prior,
)
from vectoradjust.adjust.shapepoints import ShapePoints, extract_shape_points, lookup, string_codes
from vectoradjust.errors import (
    DEMError,
    LayerError,
    MeasurementError,
    NothingAdjustedError,
)
from vectoradjust.model import ProjectData
from vectoradjust.results import DatabaseResult
from vectoradjust.sensor.models import SensorSet

__all__ = ["Classification", "BundleSetup", "classify_measurements", "build_problem"]


@dataclass
class Classification:
    """What each measurement (row of ``data.measurements``) is.

    Attributes
    ----------
    image_ids : numpy.ndarray of str
        Ids of all ``[[images]]``.
    img_of_obs, ctrl_of_obs : numpy.ndarray of int
        Image index and control-file row of each measurement (-1: not a control point).
    shapes : list of (VectorSpec, ShapePoints)
        Every database's shape points (selected or not).
    db_vertex_of_obs : list of numpy.ndarray of int
        Per database, the vertex each measurement names (-1: none).
    is_ctrl, is_check, is_tie : numpy.ndarray of bool
    tie_ids, tie_inv : numpy.ndarray
        Distinct tie point ids and each tie measurement's index into them.
    ctrl_used : numpy.ndarray of bool
        Control-file rows (role control) measured on an image.
    is_excluded : numpy.ndarray of bool, optional
        Measurements of features that a database's ``where`` filter left out of the run
        (left out, not made tie points).
    """

    image_ids: np.ndarray
    img_of_obs: np.ndarray
    ctrl_of_obs: np.ndarray
    shapes: list
    db_vertex_of_obs: list
    is_ctrl: np.ndarray
    is_check: np.ndarray
    is_tie: np.ndarray
    tie_ids: np.ndarray
    tie_inv: np.ndarray
    ctrl_used: np.ndarray
    is_excluded: Optional[np.ndarray] = None


@dataclass
class BundleSetup:
    """The bundle problem of a run and the bookkeeping to read its results.

    Attributes
    ----------
    problem : BundleProblem
    point_ids, point_kind, point_database : numpy.ndarray of str
        Per bundle point: its id, ``control``/``shape``/``tie`` and its database.
    databases : list of DatabaseResult
        One per selected database (vertex -> bundle point map filled in).
    obs_rows : numpy.ndarray of int
        Measurement row of each bundle observation.
    img_used : numpy.ndarray of int
        ``[[images]]`` index of each adjusted image.
    imap : numpy.ndarray of int
        Adjusted-image index of each ``[[images]]`` entry (-1: not adjusted).
    db_prior : numpy.ndarray, shape (m, 3)
        The points' priors before any database offset is applied.
    """

    problem: BundleProblem
    point_ids: np.ndarray
    point_kind: np.ndarray
    point_database: np.ndarray
    databases: list
    obs_rows: np.ndarray
    img_used: np.ndarray
    imap: np.ndarray
    db_prior: Optional[np.ndarray] = None


def _line(meas, i: int) -> str:
    return f"{meas.source}, line {int(meas.rows[i])}"


def _bare_ids(meas_ids: np.ndarray, name: str):
    """The measured ids without a ``NAME:`` qualifier of this database, and which ids are
    qualified with another database's name (they never match here)."""
    ids = np.asarray(meas_ids).astype(str)
    codes = string_codes(ids)  # (n, width) code points: no Python loop over the ids
    pre = string_codes(np.array([f"{name}:"]))[0]
    width, size = codes.shape[1], len(pre)
    qualified = np.zeros(len(ids), bool) if width < size else \
        (codes[:, :size] == pre).all(axis=1)
    bare = ids.copy()
    if qualified.any():  # the qualifier cut off
        rest = np.ascontiguousarray(codes[qualified, size:])
        bare[qualified] = rest.view(f"<U{width - size}").ravel() if width > size else ""
    other = (codes == ord(":")).any(axis=1) & ~qualified
    return bare, other


def _match_database(meas_ids: np.ndarray, name: str, sp: ShapePoints) -> np.ndarray:
    """Vertex index of each measured id in this database (-1 if none).

    Ids may be qualified ``NAME:<feature id>_<vertex>`` to disambiguate databases.
    """
    bare, other = _bare_ids(meas_ids, name)
    idx = lookup(sp.vertex_ids, bare)
    idx[other] = -1
    return idx


def _feature_part(ids) -> np.ndarray:
    """``<feature id>`` of ids shaped ``<feature id>_<vertex index>``; "" for other ids."""
    out = []
    for i in np.asarray(ids).astype(str):
        f, _, v = i.rpartition("_")
        out.append(f if f and v.isdigit() else "")
    return np.array(out, dtype=object).astype(str)


def reading_info(layer) -> dict:
    """What the reader says about a layer (``LineLayer.reading``; empty when not given).

    :func:`vectoradjust.files.readers.read_line_layer` sets it: ``where``,
    ``features_in_layer``, ``features_kept``, ``features_filtered``,
    ``excluded_feature_ids`` and the CRS transformation (``crs``, ``dem``).
    """
    info = getattr(layer, "reading", None)
    return info if isinstance(info, dict) else {}


def _excluded_by_filter(meas_ids: np.ndarray, name: str, layer) -> np.ndarray:
    """Measurements naming a vertex of a feature the database's ``where`` filter excluded."""
    excluded = reading_info(layer).get("excluded_feature_ids") or []
    if not len(excluded):
        return np.zeros(len(meas_ids), bool)
    bare, other = _bare_ids(meas_ids, name)
    feat = _feature_part(bare)
    return (feat != "") & np.isin(feat, np.asarray(list(excluded), dtype=object).astype(str)) \
        & ~other


# --------------------------------------------------------------------------- classify
def _image_of_measurements(data: ProjectData):
    """Ids of the images and the image index of every measurement (unknown image: error)."""
    meas = data.measurements
    image_ids = np.array([im.id for im in data.images], dtype=object).astype(str)
    img_of_obs = lookup(image_ids, meas.image_id)
    bad = np.flatnonzero(img_of_obs < 0)
    if bad.size:
        i = int(bad[0])
        raise MeasurementError(
            f"{_line(meas, i)}: image {str(meas.image_id[i])!r} is not defined in [[images]]",
            f"Add an [[images]] entry with id = {str(meas.image_id[i])!r} or correct the image id "
            f"(defined: {', '.join(image_ids)})",
            path=meas.source, details={"line": int(meas.rows[i])},
        )
    return image_ids, img_of_obs


def _match_points(data: ProjectData):
    """Control row and per-database vertex of each measurement (ambiguous ids: error), and
    per database the measurements of features its ``where`` filter excluded."""
    meas = data.measurements
    ctrl_of_obs = lookup(data.control.point_id, meas.point_id)
    shapes: list = []
    matches = (ctrl_of_obs >= 0).astype(int)
    db_vertex_of_obs = []
    excluded = []
    for spec, layer in data.vectors:
        sp = extract_shape_points(layer, data.settings.merge_tolerance)
        shapes.append((spec, sp))
        vi = _match_database(meas.point_id, spec.name, sp)
        db_vertex_of_obs.append(vi)
        excluded.append(_excluded_by_filter(meas.point_id, spec.name, layer) & (vi < 0))
        matches += (vi >= 0)
    amb = np.flatnonzero(matches > 1)
    if amb.size:
        i = int(amb[0])
        raise MeasurementError(
            f"{_line(meas, i)}: point id {str(meas.point_id[i])!r} is ambiguous (it is a control "
            "point id or a shape point id of more than one road database)",
            "Qualify shape point ids with the database name, e.g. 'OSM:123_4', or rename the "
            "control point",
            path=meas.source, details={"line": int(meas.rows[i])},
        )
    return ctrl_of_obs, shapes, db_vertex_of_obs, excluded


def _text(v) -> str:
    """An attribute value as an id text (``123.0`` -> ``"123"``)."""
    if isinstance(v, float) and v.is_integer():
        return str(int(v))
    return str(v)


def _field_holding(layer, features: np.ndarray) -> Optional[str]:
    """The attribute field whose values are most of the measured ``features``, or None."""
    best, best_n = None, 0
    wanted = set(features.tolist())
    for fname, values in layer.attributes.items():
        n = len(wanted & {_text(v) for v in values if v is not None})
        if n > best_n:
            best, best_n = fname, n
    return best


def _why_unmeasured(data: ProjectData, spec, sp: ShapePoints, unmatched: np.ndarray,
                    n_excluded: int) -> str:
    """The likely reason why no measurement names a vertex of this database."""
    meas, layer = data.measurements, sp.layer
    info = reading_info(layer)
    if n_excluded:
        return (f"the {n_excluded} measurement(s) of its shape points name features that "
                f"where = {info.get('where')!r} excluded")
    if not len(sp.vertex_ids):
        filt = (f" (where = {info.get('where')!r} kept {info.get('features_kept')} of "
                f"{info.get('features_in_layer')} features)" if info.get("where") else "")
        return f"the layer has no vertices{filt}"
    ids = meas.point_id[unmatched].astype(str)
    names = {s.name for s, _ in data.vectors}
    prefixes = sorted({i.split(":", 1)[0] for i in ids if ":" in i} - names)
    feats = _feature_part(np.array([i.split(":", 1)[-1] for i in ids], dtype=object))
    shaped = ids[feats != ""]
    db_id = str(sp.vertex_ids[0])
    if not len(shaped):
        return (f"no measured id has the form of a shape point id '<feature id>_<vertex>' "
                f"(its first is {db_id!r})")
    field = _field_holding(layer, feats[feats != ""])
    hint = (f"; the field {field!r} holds the measured feature ids: "
            f"set id_field = \"{field}\"" if field and field != spec.id_field else "")
    qual = (f"; ids are qualified with {', '.join(p + ':' for p in prefixes)} but the "
            f"databases are named {', '.join(sorted(names))}" if prefixes else "")
    if spec.id_field is None:
        return ("no id_field is given, so its shape point ids are the 0-based feature index "
                f"and the vertex (e.g. {db_id!r}), while the measurements use ids such as "
                f"{str(shaped[0])!r}" + hint + qual)
    return (f"its shape point ids (id_field = {spec.id_field!r}, e.g. {db_id!r}) match none of "
            f"the measured ids (e.g. {str(shaped[0])!r})" + hint + qual)


def _check_measured(data: ProjectData, selected: set, shapes: list, db_vertex_of_obs: list,
                    excluded: list, unmatched: np.ndarray) -> None:
    """Every selected database has a measured shape point; else a clear error with the cause."""
    for (spec, sp), vi, ex in zip(shapes, db_vertex_of_obs, excluded):
        if spec.name not in selected or np.any(vi >= 0):
            continue
        meas = data.measurements
        raise NothingAdjustedError(
            f"{spec.name} ({sp.layer.source}): none of its shape points is measured in "
            f"{meas.source}, so nothing of it would be adjusted: "
            + _why_unmeasured(data, spec, sp, unmatched, int(ex.sum())),
            "Match the ids (id_field in its [[vectors]] entry, or the ids in the measurements: "
            "'<feature id>_<vertex index>'), or leave the database out of this run "
            "(--vectors)",
            path=sp.layer.source, details={"database": spec.name},
        )


def _tie_points(meas, is_tie: np.ndarray):
    """Distinct tie point ids and each tie measurement's index (one ray only: error)."""
    tie_ids, tie_inv, tie_counts = np.unique(meas.point_id[is_tie], return_inverse=True,
                                             return_counts=True)
    if np.any(tie_counts < 2):
        t = tie_ids[tie_counts < 2][0]
        i = int(np.flatnonzero(is_tie & (meas.point_id == t))[0])
        raise MeasurementError(
            f"{_line(meas, i)}: point {str(t)!r} is measured on only one image and is neither a "
            "control/check point nor a shape point of the road layers, so it cannot be intersected",
            "Measure it on a second image, add it to the control file, or correct its id "
            "(shape point ids are '<feature id>_<vertex index>')",
            path=meas.source, details={"line": int(meas.rows[i]), "point_id": str(t)},
        )
    return tie_ids, tie_inv


def _control_used(ctrl, ctrl_of_obs: np.ndarray, is_ctrl: np.ndarray, warnings: list):
    """Control points measured on an image (a warning for each one measured on none).

    How many are needed depends on what else fixes the datum (camera priors, control
    databases, DEM heights): :func:`vectoradjust.adjust.datum.analyse_datum` decides
    before the solve, in :func:`vectoradjust.adjust.passes.solve`.
    """
    ctrl_used = np.zeros(len(ctrl.point_id), bool)
    ctrl_used[ctrl_of_obs[is_ctrl]] = True
    for j in np.flatnonzero((ctrl.role == "control") & ~ctrl_used):
        warnings.append(f"control point {str(ctrl.point_id[j])!r} ({ctrl.source}, line "
                        f"{int(ctrl.rows[j])}) is measured on no image and was not used")
    return ctrl_used


def _junctions(sp: ShapePoints) -> np.ndarray:
    """Object points where two or more vertices (features) meet: the intersections."""
    return np.bincount(sp.vertex_object, minlength=sp.n_objects) >= 2


def _reuse_source(shapes: list, db_vertex_of_obs: list, selected: set, k: int,
                  junctions_only: bool):
    """XY and object key of every measurement of a vertex of a database not in the run
    (of an intersection vertex only, with ``junctions_only``)."""
    src_xy = np.full((k, 2), np.nan)
    src_key = np.full(k, -1, np.int64)
    for a, ((spec, sp), vi) in enumerate(zip(shapes, db_vertex_of_obs)):
        if spec.name in selected:
            continue
        r = np.flatnonzero(vi >= 0)
        if junctions_only:
            r = r[_junctions(sp)[sp.vertex_object[vi[r]]]]
        src_xy[r] = sp.layer.coords[vi[r], :2]
        src_key[r] = a * (1 << 40) + sp.vertex_object[vi[r]]
    return src_xy, src_key


def _reuse_measurements(data: ProjectData, selected: set, shapes: list, db_vertex_of_obs: list,
                        has_c: np.ndarray, warnings: list) -> list:
    """Measurements of a vertex of a database NOT in the run reused for the coinciding
    vertex of a database in the run (``[adjustment] reuse_tolerance``, XY distance).

    A database object point that is measured itself keeps its own measurements; of
    several measured vertices near one object point the nearest is reused. With
    ``reuse_points = "intersections"`` (default) only intersections (object points where
    features meet) of both databases reuse: elsewhere two databases' vertices near each
    other are rarely the same point of the road. Returns the
    per-database vertex of each measurement with the reused ones filled in.
    """
    tol = data.settings.reuse_tolerance
    if not tol or len(selected) == len(shapes):
        return db_vertex_of_obs
    from scipy.spatial import cKDTree

    k = len(data.measurements.point_id)
    junctions_only = data.settings.reuse_points != "all"
    src_xy, src_key = _reuse_source(shapes, db_vertex_of_obs, selected, k, junctions_only)
    out = []
    for (spec, sp), vi in zip(shapes, db_vertex_of_obs):
        rows = np.flatnonzero((src_key >= 0) & (vi < 0) & ~has_c)
        if spec.name not in selected or not rows.size or not sp.n_objects:
            out.append(vi)
            continue
        cand = np.flatnonzero(_junctions(sp)) if junctions_only else np.arange(sp.n_objects)
        if not cand.size:
            out.append(vi)
            continue
        dist, j = cKDTree(sp.object_xyz[cand, :2]).query(src_xy[rows], distance_upper_bound=tol)
        obj = np.append(cand, sp.n_objects)[j]  # j == len(cand): nothing within tol
        own = np.zeros(sp.n_objects + 1, bool)  # + 1: the "nothing found" index
        own[sp.vertex_object[vi[vi >= 0]]] = True
        ok = np.isfinite(dist) & ~own[obj]
        rows, dist, obj = rows[ok], dist[ok], obj[ok]
        order = np.lexsort((dist, obj))
        uo, first = np.unique(obj[order], return_index=True)
        winner = np.full(sp.n_objects, -1, np.int64)
        winner[uo] = src_key[rows[order[first]]]
        keep = src_key[rows] == winner[obj]
        vi = vi.copy()
        vi[rows[keep]] = sp.object_vertex[obj[keep]]
        if keep.any():
            warnings.append(f"{spec.name}: {len(uo)} shape point(s) reuse the measurements of "
                            f"a vertex of another database within reuse_tolerance = {tol:g} m "
                            f"({int(keep.sum())} image measurements)")
        out.append(vi)
    return out


def classify_measurements(data: ProjectData, selected: set, warnings: list) -> Classification:
    """Classify every measurement of ``data`` as control, check, shape or tie point.

    Parameters
    ----------
    data : ProjectData
    selected : set of str
        Names of the databases in this run; measurements of the others' shape points, and
        of features a database's ``where`` filter excluded, are left out (a warning), not
        made tie points.
    warnings : list of str
        Appended to.

    Returns
    -------
    Classification

    Raises
    ------
    NothingAdjustedError
        A selected database has no measured shape point (the message names the likely
        cause: no or another ``id_field``, ids that match no measurement, a ``where`` filter).
    MeasurementError
        Unknown image, ambiguous id, tie point on one image.
    """
    meas, ctrl = data.measurements, data.control
    image_ids, img_of_obs = _image_of_measurements(data)
    ctrl_of_obs, shapes, db_vertex_of_obs, excluded_db = _match_points(data)
    k = len(meas.point_id)
    is_check = np.zeros(k, bool)
    is_ctrl = np.zeros(k, bool)
    has_c = ctrl_of_obs >= 0
    is_check[has_c] = ctrl.role[ctrl_of_obs[has_c]] == "check"
    is_ctrl[has_c] = ~is_check[has_c]
    db_vertex_of_obs = _reuse_measurements(data, selected, shapes, db_vertex_of_obs, has_c,
                                           warnings)
    is_shape = np.zeros(k, bool)
    use_shape = np.zeros(k, bool)
    for (spec, _), vi in zip(shapes, db_vertex_of_obs):
        is_shape |= vi >= 0
        if spec.name in selected:
            use_shape |= vi >= 0
    excluded_db = [ex & ~(has_c | is_shape) for ex in excluded_db]
    is_excluded = np.logical_or.reduce(excluded_db) if excluded_db else np.zeros(k, bool)
    is_tie = ~(has_c | is_shape | is_excluded)
    _check_measured(data, selected, shapes, db_vertex_of_obs, excluded_db, is_tie)
    dropped = int((is_shape & ~use_shape).sum())
    if dropped:
        warnings.append(f"{dropped} measurement(s) of shape points of road databases not in this "
                        "run were left out")
    for (spec, sp), ex in zip(shapes, excluded_db):
        if ex.any():
            warnings.append(f"{spec.name}: {int(ex.sum())} measurement(s) of features that "
                            f"where = {reading_info(sp.layer).get('where')!r} excluded were "
                            "left out")
    tie_ids, tie_inv = _tie_points(meas, is_tie)
    ctrl_used = _control_used(ctrl, ctrl_of_obs, is_ctrl, warnings)
    return Classification(image_ids, img_of_obs, ctrl_of_obs, shapes, db_vertex_of_obs,
                          is_ctrl, is_check, is_tie, tie_ids, tie_inv, ctrl_used, is_excluded)


# --------------------------------------------------------------------------- bundle points
class _Points:
    """The object points of the bundle, assembled block by block."""

    def __init__(self, k: int) -> None:
        self.ids: list = []
        self.kind: list = []
        self.db: list = []
        self.xyz: list = []
        self.weights: list = []
        self.obs_point = np.full(k, -1, np.int64)
        self.offset = 0

    def add(self, ids, kind: str, db: str, xyz: np.ndarray, weight: np.ndarray) -> None:
        """Append a block of points with their priors and prior weights."""
        n = len(ids)
        self.ids.extend(list(ids))
        self.kind.extend([kind] * n)
        self.db.extend([db] * n)
        self.xyz.append(xyz)
        self.weights.append(weight)
        self.offset += n


def _add_control(pts: _Points, ctrl, cls: Classification) -> None:
    """The measured control points (role control) with their surveyed priors."""
    cu = np.flatnonzero(cls.ctrl_used)
    cmap = np.full(len(ctrl.point_id), -1, np.int64)
    cmap[cu] = np.arange(len(cu))
    pts.obs_point[cls.is_ctrl] = cmap[cls.ctrl_of_obs[cls.is_ctrl]]
    if ctrl.cov is not None:
        w = np.linalg.inv(ctrl.cov[cu])
    else:
        w = np.zeros((len(cu), 3, 3))
        w[:, [0, 1, 2], [0, 1, 2]] = 1.0 / ctrl.sigma[cu] ** 2
    pts.add(ctrl.point_id[cu].tolist(), "control", "", ctrl.xyz[cu], w)


def _check_heights(spec, sp: ShapePoints, used_obj: np.ndarray, xyz: np.ndarray) -> None:
    """A measured shape point without a height (outside the DEM, no Z): error."""
    badz = np.flatnonzero(~np.isfinite(xyz).all(axis=1))
    if not badz.size:
        return
    v = int(sp.object_vertex[used_obj[badz[0]]])
    fid = sp.layer.feature_ids[sp.layer.vertex_feature[v]]
    err = DEMError if spec.dem else LayerError
    raise err(
        f"{spec.dem or sp.layer.source}: measured shape point {str(sp.vertex_ids[v])!r} "
        f"(feature {str(fid)!r} of {sp.layer.source}) has no height: "
        + ("the DEM does not cover it" if spec.dem else "the layer has no Z"),
        "Use a DEM that covers every measured vertex" if spec.dem else
        "Give a DEM in the [[vectors]] entry (dem = \"dem.tif\") or a layer with Z",
        path=spec.dem or sp.layer.source,
        details={"point_id": str(sp.vertex_ids[v]), "feature_id": str(fid)},
    )


def _add_shape_points(pts: _Points, cls: Classification, selected: set) -> list:
    """The measured shape points of each selected database; their DatabaseResults."""
    db_results: list = []
    for (spec, sp), vi in zip(cls.shapes, cls.db_vertex_of_obs):
        if spec.name not in selected:
            continue
        sel = np.flatnonzero(vi >= 0)
        obj = sp.vertex_object[vi[sel]]
        used_obj = np.unique(obj)
        omap = np.full(sp.n_objects, -1, np.int64)
        omap[used_obj] = pts.offset + np.arange(len(used_obj))
        pts.obs_point[sel] = omap[obj]
        vertex_point = omap[sp.vertex_object]
        xyz = sp.object_xyz[used_obj]
        _check_heights(spec, sp, used_obj, xyz)
        # the prior X_db = X_id + (e_db - e_id): database and identification error; the
        # systematic part of a control database is carried by its offset's prior instead
        var = (np.asarray(spec.sigma, float) ** 2 - _systematic(spec)
               + spec.identification_variance)
        w = np.zeros((len(used_obj), 3, 3))
        w[:, [0, 1, 2], [0, 1, 2]] = 1.0 / var
        pts.add(sp.object_ids[used_obj].tolist(), "shape", spec.name, xyz, w)
        db_results.append(DatabaseResult(spec, sp, vertex_point, sigma_used=tuple(spec.sigma)))
    return db_results


def _systematic(spec) -> np.ndarray:
    """Per-axis variance of a control database's systematic part (0 for the others)."""
    if getattr(spec, "role", "adjust") != "control":
        return np.zeros(3)
    return spec.systematic_variance


def _add_tie_points(pts: _Points, cls: Classification) -> int:
    """The tie points (no prior); returns their number."""
    n_tie = len(cls.tie_ids)
    pts.obs_point[cls.is_tie] = pts.offset + np.asarray(cls.tie_inv).reshape(-1)
    pts.add(cls.tie_ids.tolist(), "tie", "", np.full((n_tie, 3), np.nan),
            np.zeros((n_tie, 3, 3)))
    return n_tie


def _images_in_run(data: ProjectData, cls: Classification, use: np.ndarray, warnings: list):
    """Adjusted images, their index map and approximate EO with prior sigmas."""
    image_ids = cls.image_ids
    img_used = np.unique(cls.img_of_obs[use])
    for j in np.setdiff1d(np.arange(len(image_ids)), img_used):
        warnings.append(f"image {str(image_ids[j])!r} has no measurements in this run and was not "
                        "adjusted")
    imap = np.full(len(image_ids), -1, np.int64)
    imap[img_used] = np.arange(len(img_used))
    eo0 = np.array([np.r_[im.position, np.radians(im.attitude)] for im in data.images])[img_used]
    eo_sigma = np.full((len(img_used), 6), np.inf)
    for r, j in enumerate(img_used):
        im = data.images[j]
        if im.model == "rpc":  # six bias parameters (px), starting at zero
            eo0[r] = 0.0
            eo_sigma[r] = im.rpc.bias_sigma
            continue
        if im.sigma_position is not None:
            eo_sigma[r, :3] = im.sigma_position
        if im.sigma_attitude is not None:
            eo_sigma[r, 3:] = np.radians(im.sigma_attitude)
    return img_used, imap, eo0, eo_sigma


def build_problem(data: ProjectData, cls: Classification, selected: set,
                  warnings: list) -> BundleSetup:
    """Object points, images and observations of the bundle adjustment.

    Parameters
    ----------
    data : ProjectData
    cls : Classification
        From :func:`classify_measurements`.
    selected : set of str
        Databases in this run.
    warnings : list of str
        Appended to (images without measurements).

    Returns
    -------
    BundleSetup

    Raises
    ------
    DEMError, LayerError
        A measured shape point has no height.
    MeasurementError
        Tie points cannot be intersected from the approximate orientation.
    """
    meas = data.measurements
    pts = _Points(len(meas.point_id))
    _add_control(pts, data.control, cls)
    db_results = _add_shape_points(pts, cls, selected)
    n_tie = _add_tie_points(pts, cls)
    use = pts.obs_point >= 0
    obs_rows = np.flatnonzero(use)
    img_used, imap, eo0, eo_sigma = _images_in_run(data, cls, use, warnings)
    prior = np.concatenate(pts.xyz)
    weight = np.concatenate(pts.weights)
    o_pt = pts.obs_point[use]
    o_img = imap[cls.img_of_obs[use]]
    o_xy = meas.xy[use]
    o_sig = meas.sigma[use]
    xyz0 = prior.copy()
    sensors = None
    if data.has_rpc:
        sensors = SensorSet([data.images[j].rpc if data.images[j].model == "rpc" else None
                             for j in img_used], data.ground_frame)
    if n_tie:
        if sensors is None:
            approx = ray_intersection(eo0, o_pt, o_img, o_xy, len(prior),
                                      data.camera.focal_length, data.camera.principal_point)
        else:
            approx = approximate_points(sensors, eo0, o_pt, o_img, o_xy, len(prior),
                                        data.camera.focal_length, data.camera.principal_point)
        tie_sl = slice(len(prior) - n_tie, len(prior))
        xyz0[tie_sl] = approx[tie_sl]
        if not np.isfinite(xyz0[tie_sl]).all():
            raise MeasurementError("Tie points could not be intersected from the approximate "
                                   "exterior orientation",
                                   "Check the approximate positions and attitudes in [[images]]")
    if sensors is not None:
        check_bias_determined(sensors, eo_sigma, o_pt, o_img, o_xy, pts_have_prior(weight),
                              [str(data.images[j].id) for j in img_used])
    if sensors is not None:
        check_rpc_domain(sensors, xyz0, o_pt, o_img, [str(data.images[j].id) for j in img_used],
                         pts.ids, warnings)
    prior_filled = np.where(np.isfinite(prior), prior, 0.0)
    problem = BundleProblem(data.camera.focal_length, data.camera.principal_point, eo0, eo_sigma,
                            xyz0, prior_filled, weight, o_pt, o_img, o_xy, o_sig,
                            sensors=sensors)
    return BundleSetup(
        problem=problem,
        point_ids=np.array(pts.ids, dtype=object).astype(str),
        point_kind=np.array(pts.kind, dtype=object).astype(str),
        point_database=np.array(pts.db, dtype=object).astype(str),
        databases=db_results, obs_rows=obs_rows, img_used=img_used, imap=imap,
        db_prior=problem.prior_xyz.copy(),
    )
