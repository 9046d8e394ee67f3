"""From project data (arrays) to adjusted shape points, features and a summary.

:func:`run` is the whole vector adjustment on in-memory data
(:class:`~vectoradjust.model.ProjectData`): it classifies the measured points
(control, check, shape, tie), validates them, sets up and solves the bundle
adjustment (optionally twice, ``reweight = "two-pass"``), intersects the check
points, and tabulates the results in the contract's fields. It does no file I/O
and imports only numpy and scipy, so the QGIS plugin calls it directly.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Optional

import numpy as np

from vectoradjust.accuracy import stats
from vectoradjust.adjust.bundle import (
    BundleProblem,
    BundleResult,
    adjust,
    intersect,
    ray_intersection,
)
from vectoradjust.adjust.shapepoints import ShapePoints, extract_shape_points, lookup
from vectoradjust.errors import (
    ControlError,
    DEMError,
    LayerError,
    MeasurementError,
    ProjectError,
)
from vectoradjust.model import ProjectData, VectorSpec

__all__ = ["AdjustmentRun", "DatabaseResult", "run", "LE90_FACTOR"]

LE90_FACTOR = 1.6448536269514722  # Phi^-1(0.95)

Progress = Callable[[float, str], None]


@dataclass
class DatabaseResult:
    """Results for one road database (one ``[[vectors]]`` entry).

    Attributes
    ----------
    spec : VectorSpec
    shape : ShapePoints
    vertex_point : numpy.ndarray of int, shape (nv,)
        Bundle point index of each vertex, -1 where not measured.
    vertices : dict of str to numpy.ndarray
        The ``shape_points`` columns of this database, one row per vertex.
    features : dict of str to numpy.ndarray
        The computed ``features`` columns (one row per input feature).
    adjusted_coords : numpy.ndarray, shape (nv, 3)
        Vertex coordinates of the adjusted geometry.
    sigma_used : tuple of float
        Prior sigma of the shape points in the final pass.
    truth : dict or None
        Truth comparison (simulations).
    """

    spec: VectorSpec
    shape: ShapePoints
    vertex_point: np.ndarray
    vertices: dict = field(default_factory=dict)
    features: dict = field(default_factory=dict)
    adjusted_coords: Optional[np.ndarray] = None
    sigma_used: tuple = (10.0, 10.0, 10.0)
    truth: Optional[dict] = None

    @property
    def name(self) -> str:
        """Database name."""
        return self.spec.name


@dataclass
class AdjustmentRun:
    """Everything one adjustment produced.

    Attributes
    ----------
    data : ProjectData
    problem : BundleProblem
    result : BundleResult
    point_ids : numpy.ndarray of str
        Id of every bundle point (control id, canonical shape point id, tie id).
    point_kind : numpy.ndarray of str
        ``"control"``, ``"shape"`` or ``"tie"`` per bundle point.
    point_database : numpy.ndarray of str
        Database name for shape points, ``""`` otherwise.
    image_ids : list of str
        Images in the adjustment (those with measurements).
    obs_rows : numpy.ndarray of int
        Row of ``data.measurements`` for each bundle observation.
    databases : list of DatabaseResult
    control_points : dict of str to numpy.ndarray
        The ``control_points`` columns.
    summary : dict
        JSON-ready run summary (contract fields and more).
    warnings : list of str
    passes : list of dict
        One entry per adjustment pass (two-pass reweighting).
    """

    data: ProjectData
    problem: BundleProblem
    result: BundleResult
    point_ids: np.ndarray
    point_kind: np.ndarray
    point_database: np.ndarray
    image_ids: list
    obs_rows: np.ndarray
    databases: list
    control_points: dict
    summary: dict
    warnings: list = field(default_factory=list)
    passes: list = field(default_factory=list)
    reliability: object = None
    flagged: list = field(default_factory=list)


# --------------------------------------------------------------------------- helpers
def _line(meas, i: int) -> str:
    return f"{meas.source}, line {int(meas.rows[i])}"


def _match_database(meas_ids: np.ndarray, name: str, sp: ShapePoints) -> np.ndarray:
    """Vertex index of each measured id in this database (-1 if none).

    Ids may be qualified ``NAME:<feature id>_<vertex>`` to disambiguate databases.
    """
    prefix = f"{name}:"
    qualified = np.char.startswith(meas_ids.astype(str), prefix)
    bare = np.where(qualified, np.char.replace(meas_ids.astype(str), prefix, "", count=1),
                    meas_ids)
    idx = lookup(sp.vertex_ids, bare)
    # a qualified id naming another database never matches here
    other = np.char.find(meas_ids.astype(str), ":") >= 0
    idx[other & ~qualified] = -1
    return idx


def _collinear(xyz: np.ndarray) -> bool:
    """Whether points lie (nearly) on one line in plan."""
    xy = xyz[:, :2] - xyz[:, :2].mean(axis=0)
    s = np.linalg.svd(xy, compute_uv=False)
    extent = max(float(s[0]), 1e-9)
    return len(xyz) < 3 or float(s[1]) / extent < 1e-3


def _degrees_att(eo: np.ndarray) -> np.ndarray:
    return np.degrees(eo[..., 3:])


def _float_or_none(x) -> Optional[float]:
    if x is None:
        return None
    x = float(x)
    return x if np.isfinite(x) else None


def _rmse_dict(d: np.ndarray) -> dict:
    """RMSE summary of an (n, 3) array of differences (NaN rows ignored)."""
    ok = np.isfinite(d).all(axis=1) if len(d) else np.zeros(0, bool)
    s = stats.rmse_summary(d[ok, 0], d[ok, 1], d[ok, 2])
    return {k: (_float_or_none(v) if k != "count" else int(v)) for k, v in s.items()}


# --------------------------------------------------------------------------- main entry
def run(
    data: ProjectData,
    *,
    vectors: Optional[list] = None,
    progress: Optional[Progress] = None,
    is_cancelled: Optional[Callable[[], bool]] = None,
) -> AdjustmentRun:
    """Adjust the road vectors of a project.

    Parameters
    ----------
    data : ProjectData
        Inputs as arrays (from :func:`vectoradjust.files.readers.load_project_data`, the
        simulator or QGIS).
    vectors : list of str, optional
        Names of the ``[[vectors]]`` entries to adjust (default: all). Measurements of
        the other databases' shape points are left out (not turned into tie points).
    progress : callable, optional
        ``progress(fraction, message)``.
    is_cancelled : callable, optional
        Polled between iterations.

    Returns
    -------
    AdjustmentRun

    Raises
    ------
    VectorAdjustError
        For every inconsistency of the input (named file, line, feature or point).
    """
    def report(frac, msg):
        if progress is not None:
            progress(frac, msg)

    settings = data.settings
    warnings: list = []
    meas = data.measurements
    ctrl = data.control
    all_names = [spec.name for spec, _ in data.vectors]
    if vectors:
        unknown = [v for v in vectors if v not in all_names]
        if unknown:
            raise ProjectError(
                f"{data.source}: no [[vectors]] entry named {', '.join(map(repr, unknown))}",
                f"Use one of: {', '.join(all_names) or '(none defined)'}",
            )
    selected = set(vectors) if vectors else set(all_names)
    report(0.02, "classifying measurements")

    # ---- images
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

    # ---- classify measured ids
    k = len(meas.point_id)
    ctrl_of_obs = lookup(ctrl.point_id, meas.point_id)
    shapes: list = []
    matches = (ctrl_of_obs >= 0).astype(int)
    db_vertex_of_obs = []
    for spec, layer in data.vectors:
        sp = extract_shape_points(layer, settings.merge_tolerance)
        shapes.append((spec, sp))
        vi = _match_database(meas.point_id, spec.name, sp)
        db_vertex_of_obs.append(vi)
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
    is_check = np.zeros(k, bool)
    is_ctrl = np.zeros(k, bool)
    has_c = ctrl_of_obs >= 0
    is_check[has_c] = ctrl.role[ctrl_of_obs[has_c]] == "check"
    is_ctrl[has_c] = ~is_check[has_c]
    is_shape = np.zeros(k, bool)
    use_shape = np.zeros(k, bool)
    for (spec, _), vi in zip(shapes, db_vertex_of_obs):
        is_shape |= vi >= 0
        if spec.name in selected:
            use_shape |= vi >= 0
    is_tie = ~(has_c | is_shape)
    dropped = int((is_shape & ~use_shape).sum())
    if dropped:
        warnings.append(f"{dropped} measurement(s) of shape points of road databases not in this "
                        "run were left out")

    # ---- tie points need two rays
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

    # ---- control
    ctrl_used = np.zeros(len(ctrl.point_id), bool)
    ctrl_used[ctrl_of_obs[is_ctrl]] = True
    for j in np.flatnonzero((ctrl.role == "control") & ~ctrl_used):
        warnings.append(f"control point {str(ctrl.point_id[j])!r} ({ctrl.source}, line "
                        f"{int(ctrl.rows[j])}) is measured on no image and was not used")
    n_ctrl = int(ctrl_used.sum())
    if n_ctrl < 3:
        raise ControlError(
            f"Only {n_ctrl} control point(s) are measured on the images ({ctrl.source}); at least "
            "3 are needed to fix the datum",
            "Measure at least 3 well-spread control points (role = control) on the images",
            path=ctrl.source,
        )
    if _collinear(ctrl.xyz[ctrl_used]):
        raise ControlError(
            f"The {n_ctrl} measured control points of {ctrl.source} lie on one line; the rotation "
            "about that line is not determined",
            "Add control points away from that line (spread them over the stereo model)",
            path=ctrl.source,
        )

    # ---- object points of the bundle
    point_ids: list = []
    point_kind: list = []
    point_db: list = []
    xyz_prior: list = []
    weights: list = []
    obs_point = np.full(k, -1, np.int64)

    cu = np.flatnonzero(ctrl_used)
    cmap = np.full(len(ctrl.point_id), -1, np.int64)
    cmap[cu] = np.arange(len(cu))
    obs_point[is_ctrl] = cmap[ctrl_of_obs[is_ctrl]]
    point_ids.extend(ctrl.point_id[cu].tolist())
    point_kind.extend(["control"] * len(cu))
    point_db.extend([""] * len(cu))
    xyz_prior.append(ctrl.xyz[cu])
    if ctrl.cov is not None:
        weights.append(np.linalg.inv(ctrl.cov[cu]))
    else:
        w = np.zeros((len(cu), 3, 3))
        w[:, [0, 1, 2], [0, 1, 2]] = 1.0 / ctrl.sigma[cu] ** 2
        weights.append(w)
    offset = len(cu)

    db_results: list = []
    for (spec, sp), vi in zip(shapes, db_vertex_of_obs):
        vertex_point = np.full(len(sp.vertex_ids), -1, np.int64)
        if spec.name not in selected:
            continue
        sel = np.flatnonzero(vi >= 0)
        obj = sp.vertex_object[vi[sel]]
        used_obj = np.unique(obj)
        omap = np.full(sp.n_objects, -1, np.int64)
        omap[used_obj] = offset + np.arange(len(used_obj))
        obs_point[sel] = omap[obj]
        vertex_point = omap[sp.vertex_object]
        xyz = sp.object_xyz[used_obj]
        badz = np.flatnonzero(~np.isfinite(xyz).all(axis=1))
        if badz.size:
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
        point_ids.extend(sp.object_ids[used_obj].tolist())
        point_kind.extend(["shape"] * len(used_obj))
        point_db.extend([spec.name] * len(used_obj))
        xyz_prior.append(xyz)
        w = np.zeros((len(used_obj), 3, 3))
        w[:, [0, 1, 2], [0, 1, 2]] = 1.0 / np.asarray(spec.sigma, float) ** 2
        weights.append(w)
        offset += len(used_obj)
        db_results.append(DatabaseResult(spec, sp, vertex_point, sigma_used=tuple(spec.sigma)))

    n_tie = len(tie_ids)
    obs_point[is_tie] = offset + np.asarray(tie_inv).reshape(-1)
    point_ids.extend(tie_ids.tolist())
    point_kind.extend(["tie"] * n_tie)
    point_db.extend([""] * n_tie)
    xyz_prior.append(np.full((n_tie, 3), np.nan))
    weights.append(np.zeros((n_tie, 3, 3)))

    use = obs_point >= 0
    obs_rows = np.flatnonzero(use)
    img_used = np.unique(img_of_obs[use])
    for j in np.setdiff1d(np.arange(len(image_ids)), img_used):
        warnings.append(f"image {str(image_ids[j])!r} has no measurements in this run and was not "
                        "adjusted")
    imap = np.full(len(image_ids), -1, np.int64)
    imap[img_used] = np.arange(len(img_used))

    eo0 = np.array([np.r_[im.position, np.radians(im.attitude)] for im in data.images])[img_used]
    eo_sigma = np.full((len(img_used), 6), np.inf)
    for r, j in enumerate(img_used):
        im = data.images[j]
        if im.sigma_position is not None:
            eo_sigma[r, :3] = im.sigma_position
        if im.sigma_attitude is not None:
            eo_sigma[r, 3:] = np.radians(im.sigma_attitude)

    prior = np.concatenate(xyz_prior)
    weight = np.concatenate(weights)
    o_pt = obs_point[use]
    o_img = imap[img_of_obs[use]]
    o_xy = meas.xy[use]
    o_sig = meas.sigma[use]
    xyz0 = prior.copy()
    if n_tie:
        approx = ray_intersection(eo0, o_pt, o_img, o_xy, len(prior),
                                  data.camera.focal_length, data.camera.principal_point)
        tie_sl = slice(len(prior) - n_tie, len(prior))
        xyz0[tie_sl] = approx[tie_sl]
        if not np.isfinite(xyz0[tie_sl]).all():
            raise MeasurementError("Tie points could not be intersected from the approximate "
                                   "exterior orientation",
                                   "Check the approximate positions and attitudes in [[images]]")
    prior_filled = np.where(np.isfinite(prior), prior, 0.0)
    problem = BundleProblem(data.camera.focal_length, data.camera.principal_point, eo0, eo_sigma,
                            xyz0, prior_filled, weight, o_pt, o_img, o_xy, o_sig)

    point_kind_a = np.array(point_kind, dtype=object).astype(str)
    point_db_a = np.array(point_db, dtype=object).astype(str)
    passes: list = []
    n_pass = 2 if settings.reweight == "two-pass" and db_results else 1
    adjust_kwargs = {"max_iterations": settings.max_iterations,
                     "tolerance_position": settings.tolerance_position,
                     "tolerance_angle": settings.tolerance_angle,
                     "is_cancelled": is_cancelled}
    result: Optional[BundleResult] = None
    for p in range(n_pass):
        report(0.1 + 0.6 * p / n_pass, f"adjustment pass {p + 1} of {n_pass}")

        def sub(frac, msg, p=p):
            report(0.1 + 0.6 * (p + frac) / n_pass, msg)

        result = adjust(problem, max_iterations=settings.max_iterations,
                        tolerance_position=settings.tolerance_position,
                        tolerance_angle=settings.tolerance_angle,
                        progress=sub, is_cancelled=is_cancelled)
        passes.append({"pass": p + 1, "sigma0_squared": _float_or_none(result.sigma0_squared),
                       "iterations": result.iterations,
                       "sigma": {d.name: list(d.sigma_used) for d in db_results}})
        if p + 1 < n_pass:
            # two-pass: each axis' sigma <- RMS of that database's residuals along it
            for d in db_results:
                m = point_db_a == d.name
                v = result.v_point[m]
                new = np.sqrt(np.mean(v**2, axis=0)) if len(v) else np.asarray(d.sigma_used)
                new = np.maximum(new, 1e-3)
                d.sigma_used = tuple(float(s) for s in new)
                idx = np.flatnonzero(m)
                weight[idx[:, None], [0, 1, 2], [0, 1, 2]] = 1.0 / new**2
            problem = BundleProblem(problem.focal_length, problem.principal_point, eo0, eo_sigma,
                                    xyz0, prior_filled, weight, o_pt, o_img, o_xy, o_sig)
    assert result is not None
    point_ids_a = np.array(point_ids, dtype=object).astype(str)
    vce_info = None
    if settings.reweight == "vce":
        report(0.55, "variance component estimation")
        problem, result, vce_info = _vce(problem, point_kind_a, point_db_a, db_results,
                                         adjust_kwargs, warnings)
        passes.append({"pass": "vce", "sigma0_squared": _float_or_none(result.sigma0_squared),
                       "iterations": vce_info["iterations"],
                       "sigma": {d.name: list(d.sigma_used) for d in db_results}})
    snooping_info = None
    if settings.snooping:
        from vectoradjust.adjust.reliability import data_snooping

        report(0.65, "data snooping")
        sn = data_snooping(problem, alpha0=settings.alpha0, beta0=settings.beta0,
                           max_removals=settings.max_removals, adjust_kwargs=adjust_kwargs)
        snooping_info = _snooping_record(sn, point_ids_a, image_ids[img_used], meas, obs_rows)
        kept = np.asarray(sn.point_index, np.int64)
        remap = np.full(len(point_ids_a), -1, np.int64)
        remap[kept] = np.arange(len(kept))
        point_ids_a, point_kind_a, point_db_a = (a[kept] for a in
                                                 (point_ids_a, point_kind_a, point_db_a))
        for d in db_results:
            d.vertex_point = np.where(d.vertex_point >= 0, remap[np.maximum(d.vertex_point, 0)],
                                      -1)
        obs_rows = obs_rows[np.asarray(sn.observation_index, np.int64)]
        problem, result = sn.problem, sn.result
        for rec in snooping_info["removed"]:
            warnings.append(f"data snooping removed the measurement of point {rec['point']!r} on "
                            f"image {rec['image']!r} (w = {rec['w']:.2f})")
    report(0.75, "intersecting check points and computing statistics")

    out = AdjustmentRun(
        data=data, problem=problem, result=result, point_ids=point_ids_a,
        point_kind=point_kind_a, point_database=point_db_a,
        image_ids=image_ids[img_used].tolist(), obs_rows=obs_rows, databases=db_results,
        control_points={}, summary={}, warnings=warnings, passes=passes,
    )
    _tabulate_control(out, ctrl_of_obs, is_check, img_of_obs, imap)
    for d in db_results:
        _tabulate_database(out, d)
    if data.qa:
        # production accuracy control: pass/fail of every control/check point
        from vectoradjust.qa.verdict import control_qa_field, spec_from_table

        spec = spec_from_table(data.qa, source=data.source)
        out.control_points["QA"] = np.asarray(control_qa_field(out, spec), dtype=object)
    out.summary = _summary(out)
    out.summary["reliability"] = _reliability_summary(out, settings)
    if vce_info is not None:
        out.summary["variance_components"] = vce_info
    if snooping_info is not None:
        out.summary["data_snooping"] = snooping_info
    from vectoradjust.accuracy.statements import accuracy_statements

    out.summary["accuracy"] = accuracy_statements(out)
    report(1.0, "done")
    return out


# --------------------------------------------------------------------------- statistics
MAX_FLAGGED_IN_SUMMARY = 1000


def _reliability_summary(out: AdjustmentRun, settings) -> dict:
    """Redundancy numbers, w-tests and flagged observations (Baarda, a-priori sigma0)."""
    from vectoradjust.adjust.reliability import flagged_observations, reliability

    rel = reliability(out.result, alpha0=settings.alpha0, beta0=settings.beta0)
    out.reliability = rel
    flagged = flagged_observations(rel, out.result, out.point_ids, out.image_ids,
                                   out.point_kind)
    meas = out.data.measurements
    for f in flagged:
        k = f.get("observation")
        if f.get("kind") == "image" and k is not None:
            f["line"] = int(meas.rows[out.obs_rows[int(k)]])
    out.flagged = flagged
    r_img = rel.r_image[np.isfinite(rel.r_image)]
    return {
        "test": "Baarda w-test with the a-priori sigma0 = 1",
        "alpha0": settings.alpha0, "beta0": settings.beta0,
        "critical_value": float(rel.critical), "delta0": float(rel.delta0),
        "sum_of_redundancy_numbers": float(rel.sum_r), "degrees_of_freedom": int(rel.dof),
        "mean_redundancy_image": _float_or_none(r_img.mean()) if r_img.size else None,
        "n_flagged": len(flagged),
        "flagged": flagged[:MAX_FLAGGED_IN_SUMMARY],
        "flagged_truncated": len(flagged) > MAX_FLAGGED_IN_SUMMARY,
    }


def _vce(problem, point_kind, point_db, db_results, adjust_kwargs, warnings):
    """Variance component estimation: image coordinates, GCPs, each database h / v."""
    from vectoradjust.adjust.vce import variance_components

    m = problem.n_points
    labels = np.full((m, 3), "", dtype=object)
    labels[point_kind == "control"] = "control"
    for d in db_results:
        sel = (point_kind == "shape") & (point_db == d.name)
        labels[sel, :2] = f"{d.name}:h"
        labels[sel, 2] = f"{d.name}:v"
    v = variance_components(problem, "image", labels.astype(str), adjust_kwargs=adjust_kwargs)
    for note in v.notes:
        warnings.append(f"variance components: {note}")
    if not v.converged:
        warnings.append("variance component estimation did not converge; the last estimates are "
                        "used")
    for d in db_results:
        h = v.sigma.get(f"{d.name}:h")
        z = v.sigma.get(f"{d.name}:v")
        d.sigma_used = (float(h if h is not None else d.sigma_used[0]),
                        float(h if h is not None else d.sigma_used[1]),
                        float(z if z is not None else d.sigma_used[2]))
    info = {
        "iterations": int(v.iterations), "converged": bool(v.converged),
        "groups": {g: {"sigma": _float_or_none(v.sigma.get(g)),
                       "sigma_initial": _float_or_none(v.sigma_initial.get(g)),
                       "redundancy": _float_or_none(v.redundancy.get(g)),
                       "count": int(v.count.get(g, 0)),
                       "estimable": bool(v.estimable.get(g, False)),
                       "unit": "mm" if g == "image" else "m"}
                   for g in v.groups},
        "notes": list(v.notes),
    }
    return v.problem, v.result, info


def _snooping_record(sn, point_ids, image_ids, meas, obs_rows) -> dict:
    removed = []
    for rec in sn.removed:
        r = dict(rec)
        k = r.get("observation")
        if k is not None:
            r["line"] = int(meas.rows[obs_rows[int(k)]])
        r["point"] = str(point_ids[int(r["point"])])
        r["image"] = str(image_ids[int(r["image"])])
        r["dropped_points"] = [str(point_ids[int(j)]) for j in r.get("dropped_points", [])]
        removed.append({key: (val.tolist() if isinstance(val, np.ndarray) else val)
                        for key, val in r.items()})
    return {"removed": removed, "clean": bool(sn.clean), "iterations": int(sn.iterations)}


# --------------------------------------------------------------------------- tables
def _cov_stats(cov: np.ndarray):
    sig = np.sqrt(np.maximum(np.einsum("...ii->...i", cov), 0.0))
    ce = stats.ce90(cov[..., :2, :2])
    le = LE90_FACTOR * sig[..., 2]
    return sig, ce, le


def _n_images_per_point(out: AdjustmentRun) -> np.ndarray:
    return np.bincount(out.problem.obs_point, minlength=out.problem.n_points)


def _tabulate_control(out: AdjustmentRun, ctrl_of_obs, is_check, img_of_obs, imap) -> None:
    data, res = out.data, out.result
    ctrl = data.control
    n = len(ctrl.point_id)
    adj = np.full((n, 3), np.nan)
    cov = np.full((n, 3, 3), np.nan)
    nimg = np.zeros(n, np.int64)
    # control points: from the bundle
    pidx = lookup(out.point_ids[out.point_kind == "control"], ctrl.point_id)
    has = pidx >= 0
    adj[has] = res.xyz[pidx[has]]
    cov[has] = res.point_cov[pidx[has]]
    nimg[has] = _n_images_per_point(out)[pidx[has]]
    # check points: intersected from the adjusted EO (not in the adjustment)
    meas = data.measurements
    chk = np.flatnonzero(is_check & (imap[img_of_obs] >= 0))
    if chk.size:
        cids, cinv = np.unique(ctrl_of_obs[chk], return_inverse=True)
        cinv = np.asarray(cinv).reshape(-1)
        cnt = np.bincount(cinv, minlength=len(cids))
        n_img = res.eo.shape[0]
        eo_cov_full = res.variance_factor * res.s_inv
        assert eo_cov_full.shape == (6 * n_img, 6 * n_img)
        xyz_c, cov_c = intersect(res.eo, cinv, imap[img_of_obs[chk]], meas.xy[chk],
                                 meas.sigma[chk], len(cids), data.camera.focal_length,
                                 data.camera.principal_point, eo_cov_full=eo_cov_full,
                                 variance_factor=res.variance_factor)
        ok = cnt >= 2
        adj[cids[ok]] = xyz_c[ok]
        cov[cids[ok]] = cov_c[ok]
        nimg[cids] = cnt
        for j in cids[~ok]:
            out.warnings.append(f"check point {str(ctrl.point_id[j])!r} is measured on one "
                                "image only "
                                "and cannot be intersected; it was not used")
    for j in np.flatnonzero((ctrl.role == "check") & (nimg == 0)):
        out.warnings.append(f"check point {str(ctrl.point_id[j])!r} is measured on no image "
                            "and was "
                            "not used")
    sig, ce, le = _cov_stats(cov)
    v = adj - ctrl.xyz
    out.control_points = {
        "point_id": ctrl.point_id, "role": ctrl.role,
        "X": ctrl.xyz[:, 0], "Y": ctrl.xyz[:, 1], "Z": ctrl.xyz[:, 2],
        "AdjX": adj[:, 0], "AdjY": adj[:, 1], "AdjZ": adj[:, 2],
        "Vx": v[:, 0], "Vy": v[:, 1], "Vz": v[:, 2],
        "SigmaX": sig[:, 0], "SigmaY": sig[:, 1], "SigmaZ": sig[:, 2],
        "CE90": ce, "LE90": le, "NImages": nimg,
        "Used": np.isfinite(adj).all(axis=1).astype(np.int64),
    }


def _tabulate_database(out: AdjustmentRun, d: DatabaseResult) -> None:
    res = out.result
    sp = d.shape
    layer = sp.layer
    nv = len(sp.vertex_ids)
    vp = d.vertex_point
    meas_v = vp >= 0
    db_xyz = layer.coords
    adj = db_xyz.copy()
    adj[meas_v] = res.xyz[vp[meas_v]]
    cov = np.full((nv, 3, 3), np.nan)
    cov[meas_v] = res.point_cov[vp[meas_v]]
    sig, ce, le = _cov_stats(cov)
    v = np.full((nv, 3), np.nan)
    v[meas_v] = adj[meas_v] - db_xyz[meas_v]
    nimg_pt = _n_images_per_point(out)
    nimg = np.zeros(nv, np.int64)
    nimg[meas_v] = nimg_pt[vp[meas_v]]
    d.adjusted_coords = adj
    d.vertices = {
        "point_id": sp.vertex_ids, "feature_id": layer.feature_ids[layer.vertex_feature],
        "X": db_xyz[:, 0], "Y": db_xyz[:, 1], "Z": db_xyz[:, 2],
        "Vx": v[:, 0], "Vy": v[:, 1], "Vz": v[:, 2],
        "AdjX": adj[:, 0], "AdjY": adj[:, 1], "AdjZ": adj[:, 2],
        "SigmaX": sig[:, 0], "SigmaY": sig[:, 1], "SigmaZ": sig[:, 2],
        "CE90": ce, "LE90": le, "NImages": nimg, "Adjusted": meas_v.astype(np.int64),
        "Database": np.full(nv, d.name, dtype=object),
    }
    # ---- per feature
    nf = layer.n_features
    fi = layer.vertex_feature
    npts = np.bincount(fi, minlength=nf)
    nadj = np.bincount(fi, weights=meas_v, minlength=nf).astype(np.int64)
    vz = np.where(meas_v[:, None], v, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        ms = np.stack([np.bincount(fi, weights=vz[:, a] ** 2, minlength=nf) for a in range(3)],
                      axis=1) / nadj[:, None]
    ms[nadj == 0] = np.nan
    rm = np.sqrt(ms)
    # length of the adjusted geometry (horizontal), segments within a part only
    same = np.zeros(nv, bool)
    if nv > 1:
        same[1:] = (fi[1:] == fi[:-1]) & (layer.vertex_part[1:] == layer.vertex_part[:-1])
    seg = np.zeros(nv)
    if nv > 1:
        seg[1:] = np.hypot(*(adj[1:, :2] - adj[:-1, :2]).T)
    length = np.bincount(fi, weights=np.where(same, seg, 0.0), minlength=nf)
    first = np.full(nf, -1, np.int64)
    last = np.full(nf, -1, np.int64)
    if nv:
        first[fi[::-1]] = np.arange(nv)[::-1]
        last[fi] = np.arange(nv)
    has_v = first >= 0

    def at(idx, col):
        out_ = np.full(nf, np.nan)
        out_[has_v] = adj[idx[has_v], col]
        return out_

    # provenance: images that measured a point of the feature, and their dates
    n_img = len(out.image_ids)
    seen = np.zeros((out.problem.n_points, n_img), bool)
    seen[out.problem.obs_point, out.problem.obs_image] = True
    fseen = np.zeros((nf, n_img), np.int64)
    if meas_v.any():
        np.add.at(fseen, fi[meas_v], seen[vp[meas_v]].astype(np.int64))
    fseen = fseen > 0
    dates = {im.id: (im.date or "") for im in out.data.images}
    patterns, inv = np.unique(fseen, axis=0, return_inverse=True)
    inv = np.asarray(inv).reshape(-1)
    img_txt = []
    date_txt = []
    for pat in patterns:
        ids = [out.image_ids[j] for j in np.flatnonzero(pat)]
        img_txt.append(",".join(ids))
        date_txt.append(",".join(sorted({dates[i] for i in ids if dates[i]})))
    problem_txt = np.array([layer.problems.get(i, "") for i in range(nf)], dtype=object)
    d.features = {
        "NPts": npts.astype(np.int64), "NAdj": nadj,
        "RMSE_X": rm[:, 0], "RMSE_Y": rm[:, 1], "RMSE_Z": rm[:, 2],
        "RMSE": np.sqrt(rm[:, 0] ** 2 + rm[:, 1] ** 2), "Length": length,
        "FirstX": at(first, 0), "FirstY": at(first, 1), "LastX": at(last, 0),
        "LastY": at(last, 1),
        "Images": np.array(img_txt, dtype=object)[inv] if nf else np.zeros(0, object),
        "ImgDate": np.array(date_txt, dtype=object)[inv] if nf else np.zeros(0, object),
        "Problem": problem_txt,
    }
    # sigma of the adjusted length, with and without the covariances between points
    from vectoradjust.accuracy.derived import feature_length_sigma

    sd, sd_nc = feature_length_sigma(out, d)
    d.features["LengthSD"] = np.asarray(sd, float)
    d.features["LengthSDnc"] = np.asarray(sd_nc, float)
    # ---- truth comparison (simulations)
    truth = out.data.truth.get(d.name)
    if truth is not None:
        tid, txyz = truth
        ti = lookup(tid, sp.vertex_ids)
        m = meas_v & (ti >= 0)
        if m.any():
            t = txyz[ti[m]]
            resid = v[m]
            dbt = db_xyz[m] - t
            adt = adj[m] - t
            r_res = stats.rmse_summary(resid[:, 0], resid[:, 1], resid[:, 2])
            r_db = stats.rmse_summary(dbt[:, 0], dbt[:, 1], dbt[:, 2])
            r_adj = stats.rmse_summary(adt[:, 0], adt[:, 1], adt[:, 2])
            h_res, h_db, h_adj = (r["rmse_horizontal"] for r in (r_res, r_db, r_adj))
            inside = np.hypot(adt[:, 0], adt[:, 1]) <= ce[m]
            inside_z = np.abs(adt[:, 2]) <= le[m]
            d.truth = {
                "count": int(m.sum()),
                "rmse_residuals_horizontal": float(h_res),
                "rmse_database_truth_horizontal": float(h_db),
                # the dissertation's "recovery": the smaller RMSE over the larger (<= 1)
                "recovery_rate": float(min(h_res, h_db) / max(h_res, h_db)),
                "residual_to_true_ratio": float(stats.recovery_rate(h_res, h_db)),
                "rmse_adjusted_truth_horizontal": float(h_adj),
                "rmse_adjusted_truth_z": float(r_adj["rmse_z"]),
                "improvement": float(stats.improvement(h_adj, h_db)),
                "share_within_ce90": float(inside.mean()),
                "share_within_le90": float(inside_z.mean()),
            }


# --------------------------------------------------------------------------- summary
def _summary(out: AdjustmentRun) -> dict:
    res = out.result
    data = out.data
    chi = stats.chi_square_test(res.vtpv, res.dof, data.settings.alpha) if res.dof > 0 else {
        "statistic": res.vtpv, "lower": None, "upper": None, "alpha": data.settings.alpha,
        "passed": None}
    chi = {k: (bool(v) if k == "passed" and v is not None else
               (_float_or_none(v) if v is not None else None)) for k, v in chi.items()}
    cp = out.control_points
    vv = np.column_stack([cp["Vx"], cp["Vy"], cp["Vz"]])
    chk = (cp["role"] == "check") & (cp["Used"] == 1)
    con = (cp["role"] == "control") & (cp["Used"] == 1)
    shape_rows = [np.column_stack([d.vertices["Vx"], d.vertices["Vy"], d.vertices["Vz"]])
                  [d.vertices["Adjusted"] == 1] for d in out.databases]
    all_v = np.concatenate(shape_rows) if shape_rows else np.zeros((0, 3))
    images = []
    used = {iid: j for j, iid in enumerate(out.image_ids)}
    for im in data.images:
        if im.id in used:
            j = used[im.id]
            sd = np.sqrt(np.diag(res.eo_cov[j]))
            images.append({
                "id": im.id, "position": res.eo[j, :3].tolist(),
                "attitude": _degrees_att(res.eo[j]).tolist(),
                "sigma_position": sd[:3].tolist(), "sigma_attitude": np.degrees(sd[3:]).tolist(),
                "date": im.date, "used": True,
            })
        else:
            images.append({"id": im.id, "position": list(map(float, im.position)),
                           "attitude": list(map(float, im.attitude)), "sigma_position": None,
                           "sigma_attitude": None, "date": im.date, "used": False})
    dbs = []
    for d in out.databases:
        adjm = d.vertices["Adjusted"] == 1
        entry = {
            "name": d.name,
            "vertices": int(len(adjm)),
            "adjusted_vertices": int(adjm.sum()),
            "features": int(d.shape.layer.n_features),
            "unadjustable_features": int(len(d.shape.layer.problems)),
            "sigma_prior": list(map(float, d.sigma_used)),
            "residuals": _rmse_dict(np.column_stack([d.vertices["Vx"], d.vertices["Vy"],
                                                     d.vertices["Vz"]])[adjm]),
            "mean_ce90": _float_or_none(np.mean(d.vertices["CE90"][adjm])) if adjm.any() else None,
            "mean_le90": _float_or_none(np.mean(d.vertices["LE90"][adjm])) if adjm.any() else None,
        }
        if d.truth is not None:
            entry["truth"] = d.truth
        dbs.append(entry)
    allce = np.concatenate([d.vertices["CE90"][d.vertices["Adjusted"] == 1]
                            for d in out.databases]) if out.databases else np.zeros(0)
    allle = np.concatenate([d.vertices["LE90"][d.vertices["Adjusted"] == 1]
                            for d in out.databases]) if out.databases else np.zeros(0)
    kinds = out.point_kind
    return {
        "project": data.source,
        "crs": data.crs,
        "sigma0_squared": _float_or_none(res.sigma0_squared),
        "sigma0": _float_or_none(np.sqrt(res.sigma0_squared)) if res.dof > 0 else None,
        "degrees_of_freedom": int(res.dof),
        "iterations": int(res.iterations),
        "converged": bool(res.converged),
        "chi_square": chi,
        "observations": {
            "image_coordinates": int(2 * len(out.problem.obs_point)),
            "point_priors": int(3 * out.problem.has_prior.sum()),
            "eo_priors": int((out.problem.eo_weight > 0).sum()),
            "total": int(res.n_obs), "unknowns": int(res.n_unknowns),
            "control_points": int((kinds == "control").sum()),
            "shape_points": int((kinds == "shape").sum()),
            "tie_points": int((kinds == "tie").sum()),
        },
        "shape_points": _rmse_dict(all_v),
        "check_points": _rmse_dict(vv[chk]),
        "control_points": _rmse_dict(vv[con]),
        "mean_ce90": _float_or_none(allce.mean()) if allce.size else None,
        "mean_le90": _float_or_none(allle.mean()) if allle.size else None,
        "images": images,
        "databases": dbs,
        "reweight": data.settings.reweight,
        "passes": out.passes,
        "interior_orientation": data.interior or None,
        "warnings": list(out.warnings),
    }
