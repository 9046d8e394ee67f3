"""The verdict itself: :class:`QAReport` and :func:`accuracy_control`, which judges a
finished run stage by stage, and the control-point QA field.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from vectoradjust.adjust.dem import bilinear
from vectoradjust.formatting import float_or_none as _num
from vectoradjust.qa.tolerances import (
    ControlPointQA,
    QASpec,
    QAVerdict,
    check_stage,
    control_point_qa,
    dtm_height_tolerance,
    interior_orientation_tolerance,
    max_from_mean,
    orthomosaic_tolerance,
    orthophoto_dtm_tolerance,
    parallax_stages,
    qa_verdict,
    relative_orientation_tolerance,
    triplet_tolerance,
)
from vectoradjust.qa.verdict.block_checks import _production_checks
from vectoradjust.qa.verdict.image_checks import (
    _problem,
    interior_stages,
    pair_parallax,
    triplet_discrepancies,
)
from vectoradjust.qa.verdict.spec import _na_stage, _stats_um, resolve_pixel_size, working_radius_mm

__all__ = ["QAReport", "accuracy_control", "control_qa_field"]


@dataclass
class QAReport:
    """The accuracy control of one adjustment run.

    Attributes
    ----------
    verdict : QAVerdict
        Overall verdict; failed stages first, then passed, then not evaluated.
    spec : QASpec
    pixel_size : float or None
        Pixel size used (mm).
    pixel_size_source : str
    tolerances : dict
        Every tolerance in force (block, pixel-based, orthophoto, orthomosaic).
    stereo_pairs : list of dict
        Vertical parallax statistics per stereo pair (micrometres and pixels).
    triplets : list of dict
        Discrepancy statistics per triplet.
    control : ControlPointQA
        Per control / check point judgement (the ``QA`` field).
    control_rows : numpy.ndarray of int
        Row of ``run.control_points`` of each entry of ``control``.
    notes : list of str
    dtm_points : list of dict
        Per control / check point: surveyed Z, the DEM's height there and the
        difference (empty without a DEM).
    production : dict
        ``tie_zones`` (per stereo pair), ``triplet_zones``, ``strips``, ``inter_strip``
        (per pair of adjacent strips) and ``free_model`` (empty for RPC blocks).
    """

    verdict: QAVerdict
    spec: QASpec
    pixel_size: Optional[float]
    pixel_size_source: str
    tolerances: dict
    stereo_pairs: list
    triplets: list
    control: Optional[ControlPointQA]
    control_rows: np.ndarray
    notes: list = field(default_factory=list)
    dtm_points: list = field(default_factory=list)
    production: dict = field(default_factory=dict)

    @property
    def passed(self) -> bool:
        """True when no evaluated stage failed."""
        return self.verdict.passed

    @property
    def stages(self) -> list:
        """Stage results, failed first."""
        return self.verdict.stages

    @property
    def nonconformities(self) -> list:
        """Failed stages with the point ids to re-measure, worst first."""
        return self.verdict.nonconformities

    @property
    def remeasure(self) -> list:
        """Ids of every point to re-measure."""
        return self.verdict.remeasure

    @property
    def not_evaluated(self) -> list:
        """Names of the stages that could not be judged."""
        return [s.name for s in self.stages if s.status == "n/a"]

    def as_dict(self) -> dict:
        """JSON-ready report (the content of ``qa.json``); non-conformities first."""
        v = self.verdict.as_dict()
        ctrl = []
        if self.control is not None:
            c = self.control
            for j, pid in enumerate(c.ids):
                ctrl.append({
                    "id": pid, "role": c.roles[j], "e_xy": _num(c.e_xy[j]),
                    "e_z": _num(c.e_z[j]), "tolerance_xy": _num(c.tol_xy[j]),
                    "tolerance_z": _num(c.tol_z[j]),
                    "qa": "pass" if bool(c.passed[j]) else "fail",
                })
        return {
            "verdict": v["verdict"],
            "passed": v["passed"],
            "nonconformities": v["nonconformities"],
            "remeasure": v["remeasure"],
            "not_evaluated": self.not_evaluated,
            "specification": self.spec.as_dict(),
            "pixel_size_mm": _num(self.pixel_size),
            "pixel_size_source": self.pixel_size_source,
            "tolerances": self.tolerances,
            "stereo_pairs": self.stereo_pairs,
            "triplets": self.triplets,
            "control_points": ctrl,
            "dtm_points": list(self.dtm_points),
            "tie_zones": self.production.get("tie_zones", []),
            "triplet_zones": self.production.get("triplet_zones", []),
            "strips": self.production.get("strips", {}),
            "inter_strip": self.production.get("inter_strip", []),
            "free_model": self.production.get("free_model", {}),
            "stages": v["stages"],
            "notes": list(self.notes),
        }


def _block_inputs(run) -> tuple:
    cp = run.control_points
    used = np.flatnonzero(np.asarray(cp["Used"]) == 1)
    ids = np.asarray(cp["point_id"]).astype(str)[used].tolist()
    res = np.column_stack([cp["Vx"], cp["Vy"], cp["Vz"]])[used]
    roles = np.asarray(cp["role"]).astype(str)[used].tolist()
    return used, ids, res, roles


def _radius(run, spec: QASpec, working_radius: Optional[float]) -> float:
    if working_radius is not None:
        return float(working_radius)
    if spec.working_radius is not None:
        return float(spec.working_radius)
    return working_radius_mm(run)


def _pixel_tolerances(point_rule: str, pixel: Optional[float]) -> tuple:
    """The statistic rule and the pixel-based tolerances, with a note if the pixel is unknown."""
    notes: list = []
    if point_rule == "limit":
        rule = "mean |error|; a single point fails over twice the tolerance (E_max ~ 2 E_mean)"
    else:
        rule = "mean |error|; a single point fails over the tolerance itself"
    tolerances: dict = {"statistic": rule}
    if pixel is None:
        notes.append("pixel size unknown: the interior orientation, relative orientation and "
                     "triplet stages are reported but not evaluated; give [qa] pixel_size (mm) "
                     "or pixel_size in [camera]")
    else:
        tolerances["interior_orientation"] = interior_orientation_tolerance(pixel).as_dict()
        tolerances["relative_orientation"] = relative_orientation_tolerance(pixel).as_dict()
    return tolerances, notes


def _interior_orientation_stages(interior: dict, pixel: Optional[float]) -> tuple:
    """Interior orientation stages and notes (one ``n/a`` stage without fiducial fits)."""
    stages, notes = interior_stages(interior, pixel)
    stages, notes = list(stages), list(notes)
    if not stages:
        stages.append(_na_stage("interior orientation", unit="px"))
        notes.append("interior orientation: no fiducial fits in this project (no measured "
                     "fiducials); not evaluated")
    return stages, notes


def _relative_orientation_stages(run, pairs: str, min_pair_points: int,
                                 pixel: Optional[float]) -> tuple:
    """Vertical parallax stages per stereo pair: ``(stages, notes, pair_stats)``."""
    stages: list = []
    notes: list = []
    found, skipped = pair_parallax(run, pairs, min_pair_points)
    pair_stats = []
    for d in found:
        name = f"{d['left']}-{d['right']}"
        s = _stats_um(d["py_mm"], pixel)
        pair_stats.append({"left": d["left"], "right": d["right"], **s})
        if pixel is not None:
            stages += parallax_stages(name, d["py_mm"], d["point_ids"].tolist(), pixel)
        else:
            for stat in ("mean", "max"):
                stages.append(_na_stage(f"relative orientation {name}: {stat} |py|",
                                        d["py_mm"] * 1e3, d["point_ids"].tolist(), stat, "um"))
    for d in skipped:
        notes.append(f"images {d['left']} and {d['right']} share {d['n']} point(s) "
                     f"(< {min_pair_points}): not a stereo pair, no relative orientation check")
    if not found:
        stages.append(_na_stage("relative orientation", unit="px"))
    return stages, notes, pair_stats


def _triplet_entry(t: dict, e_xy_um: np.ndarray, e_z_um: np.ndarray) -> dict:
    """The ``triplets`` entry of ``qa.json`` for one triplet (without its tolerances)."""
    return {
        "images": t["images"], "n": int(len(t["point_ids"])),
        "base_m": _num(t["base_m"]), "base_mm": _num(t["base_mm"]),
        "photo_scale": _num(np.mean(t["scale"])),
        "mean_e_xy_um": _num(np.mean(e_xy_um)), "max_e_xy_um": _num(np.max(e_xy_um)),
        "mean_e_z_um": _num(np.mean(e_z_um)), "max_e_z_um": _num(np.max(e_z_um)),
        "mean_e_xy_m": _num(np.mean(np.hypot(*(t["xyz_12"] - t["xyz_23"])[:, :2].T))),
        "mean_e_z_m": _num(np.mean(np.abs(t["xyz_12"][:, 2] - t["xyz_23"][:, 2]))),
    }


def _triplet_stages(run, f: float, min_triplet_points: int, pixel: Optional[float]) -> tuple:
    """E_xy and E_z stages per image triplet: ``(stages, notes, trip_stats)``."""
    stages: list = []
    notes: list = []
    trips, tskipped = triplet_discrepancies(run, min_triplet_points)
    trip_stats = []
    for t in trips:
        name = "-".join(t["images"])
        e_xy_um, e_z_um = t["e_xy_mm"] * 1e3, t["e_z_mm"] * 1e3
        entry = _triplet_entry(t, e_xy_um, e_z_um)
        ids = t["point_ids"].tolist()
        if pixel is not None:
            txy, tz = triplet_tolerance(f, t["base_mm"], pixel)
            entry.update({"tolerance_e_xy_um": txy * 1e3, "tolerance_e_z_um": tz * 1e3})
            stages.append(check_stage(f"triplet {name}: E_xy", e_xy_um, ids, txy * 1e3, "mean",
                                      unit="um"))
            stages.append(check_stage(f"triplet {name}: E_z", e_z_um, ids, tz * 1e3, "mean",
                                      unit="um"))
        else:
            stages.append(_na_stage(f"triplet {name}: E_xy", e_xy_um, ids, "mean", "um"))
            stages.append(_na_stage(f"triplet {name}: E_z", e_z_um, ids, "mean", "um"))
        trip_stats.append(entry)
    for t in tskipped:
        notes.append(f"images {'-'.join(t['images'])} share {t['n']} point(s) "
                     f"(< {min_triplet_points}): triplet not checked")
    if not trips:
        stages.append(_na_stage("triplets", unit="um"))
        if len(run.image_ids) < 3:
            notes.append("triplets: fewer than 3 images, not evaluated")
    return stages, notes, trip_stats


def _block_stages(run, spec: QASpec, f: float, r_mm: float, point_rule: str,
                  tolerances: dict) -> tuple:
    """Block, orthophoto and orthomosaic stages ``(cqa, used, stages, notes)``; fills tolerances."""
    stages: list = []
    notes: list = []
    used, ids, res, roles = _block_inputs(run)
    cqa = control_point_qa(ids, res, roles, spec, f, r_mm, point_rule=point_rule)
    stages += cqa.stages
    tolerances["block"] = cqa.tolerances.as_dict()
    tolerances["block"]["unit"] = "m"
    if spec.product != "topographic map" and not np.isfinite(f):
        notes.append("orthophoto: the DTM tolerance 0.3 mm x f x M / r needs a frame camera's "
                     "focal length; with RPC images it is not derived")
    elif spec.product != "topographic map":
        dh, dh3 = orthophoto_dtm_tolerance(f, spec.product_scale, r_mm)
        tolerances["orthophoto"] = {"focal_length_mm": f, "scale": spec.product_scale,
                                    "working_radius_mm": r_mm, "dh_dtm_m": dh,
                                    "block_z_m": dh3}
        if _project_dem(run) is None:
            stages.append(_na_stage("orthophoto: DTM heights", unit="m", tolerance=dh))
            notes.append(f"orthophoto: the DTM must hold dh_DTM = {dh:.3f} m (0.3 mm x f x M "
                         f"/ r, r = {r_mm:.1f} mm); the project has no DEM in its CRS to check")
    if spec.product == "orthomosaic":
        om = orthomosaic_tolerance(spec)
        tolerances["orthomosaic"] = om.as_dict()
        stages.append(_na_stage("orthomosaic: seamlines", unit="m", tolerance=om.seamline_m))
        notes.append(f"orthomosaic: contour mismatch along seamlines must stay within "
                     f"{om.seamline_mm} mm ({om.seamline_m:.2f} m); not measured by vectoradjust")
    for note in cqa.tolerances.notes:
        notes.append(f"block: {note}")
    if not any(r == "check" for r in roles):
        notes.append("block: no check points were intersected; only control points are judged")
    return cqa, used, stages, notes


def _project_dem(run):
    """The first DEM of the project's road databases held in the project CRS, or None."""
    for _spec, layer in getattr(run.data, "vectors", []) or []:
        if getattr(layer, "dem", None) is not None:
            return layer.dem
    return None


def _dtm_stage(run, spec: QASpec, f: float, r_mm: float, point_rule: str,
               tolerances: dict) -> tuple:
    """DTM heights at the control and check points: ``(stages, notes, rows)``."""
    dem = _project_dem(run)
    if dem is None:
        return [], [], []
    ctrl = run.data.control
    xyz = np.asarray(ctrl.xyz, float).reshape(-1, 3)
    ids = np.asarray(ctrl.point_id).astype(str)
    roles = np.asarray(ctrl.role).astype(str)
    z_dem = bilinear(dem.grid, dem.transform, xyz[:, :2], nodata=dem.nodata)
    ok = np.isfinite(z_dem) & np.isfinite(xyz[:, 2])
    dz = z_dem - xyz[:, 2]
    tol, rule = dtm_height_tolerance(spec, f, r_mm)
    notes = []
    if (~ok).any():
        notes.append(f"DTM heights: {int((~ok).sum())} control/check point(s) outside the DEM "
                     f"or without Z: {', '.join(ids[~ok][:10])}")
    rows = [{"id": str(ids[j]), "role": str(roles[j]), "z": _num(xyz[j, 2]),
             "z_dem": _num(z_dem[j]), "dz": _num(dz[j])} for j in np.flatnonzero(ok)]
    name = "DTM heights"
    if tol is None or not ok.any():
        notes.append(f"DTM heights: not evaluated ({rule if tol is None else 'no point'})")
        return [_na_stage(name, dz[ok], ids[ok].tolist(), unit="m")], notes, rows
    limit = max_from_mean(tol) if point_rule == "limit" else tol
    stage = check_stage(name, dz[ok], ids[ok].tolist(), tol, "mean", point_tolerance=limit,
                        unit="m")
    for r, row in zip(rows, stage.rows):
        r["tolerance"], r["qa"] = limit, "pass" if row["passed"] else "fail"
    tolerances["dtm"] = {"mean_m": tol, "point_m": limit, "rule": rule,
                         "points": int(ok.sum()), "source": "the project's DEM, bilinear"}
    notes.append(f"DTM heights: the DEM's bilinear height at {int(ok.sum())} control/check "
                 f"point(s) against their surveyed Z; mean |dz| tolerance {tol:.3f} m ({rule})")
    return [stage], notes, rows


def accuracy_control(
    run,
    spec: QASpec,
    *,
    pixel_size: Optional[float] = None,
    pairs: str = "consecutive",
    min_pair_points: int = 6,
    min_triplet_points: int = 3,
    point_rule: str = "limit",
    working_radius: Optional[float] = None,
    frame_size: Optional[tuple] = None,
    strips: Optional[Sequence] = None,
    zone_columns: int = 2,
    free_model: Optional[bool] = None,
) -> QAReport:
    """Judge an adjustment run against the production tolerances (``docs/method.md`` section 7).

    Parameters
    ----------
    run : AdjustmentRun
        A finished adjustment (:func:`vectoradjust.pipeline.run`).
    spec : QASpec
        Product specification (:func:`spec_from_table`).
    pixel_size : float, optional
        Pixel size (mm); default ``[qa] pixel_size``, else the camera calibration's.
    pairs : {"consecutive", "all"}
        Which image pairs are stereo pairs (see the module notes).
    min_pair_points, min_triplet_points : int
        Common points needed for a stereo pair / a triplet.
    point_rule : {"limit", "mean"}
        Control and check points: fail over twice the mean tolerance (default,
        ``E_max ~ 2 E_mean``) or over the mean tolerance itself.
    working_radius : float, optional
        ``r`` (mm) of the orthophoto height tolerance; default ``[qa] working_radius``,
        else the largest radial distance of a measured photo point.
    frame_size : (float, float), optional
        Frame width and height (mm) for the overlaps of the tie-point zones; default
        the camera's ``image_size x pixel_size``, its fiducials, else the extent of the
        measurements.
    strips : sequence or dict, optional
        Strip label of every image (in ``run.image_ids`` order, or by image id); default
        the images' ``strip`` attribute when they have one, else found from the flight.
    zone_columns : {2, 3}
        Zone columns along each base (2: the 6 von Gruber zones).
    free_model : bool, optional
        Adjust the free model (a second, unconstrained bundle adjustment); default
        (None) for blocks of at most ``FREE_MODEL_MAX_IMAGES`` images.

    Returns
    -------
    QAReport
        ``.verdict`` (``QAVerdict``), ``.as_dict()`` for ``qa.json``.
    """
    data = run.data
    f = float(_problem(run).focal_length)
    interior = getattr(data, "interior", None) or {}
    pixel, pixel_src = resolve_pixel_size(data.camera, spec, pixel_size, interior)
    tolerances, notes = _pixel_tolerances(point_rule, pixel)
    production: dict = {}
    if _problem(run).is_rpc.any():  # the frame camera's stages do not apply
        stages, pair_stats, trip_stats = [], [], []
        notes.append("RPC images: the interior orientation, relative orientation (vertical "
                     "parallax) and triplet stages are frame camera stages and do not apply; "
                     "the images' bias is in summary.json images[] (estimate, sigma, test)")
    else:
        stages, notes, pair_stats, trip_stats, production = _frame_camera_stages(
            run, f, interior, pixel, notes, pairs=pairs, min_pair_points=min_pair_points,
            min_triplet_points=min_triplet_points, frame=frame_size, strips=strips,
            zone_columns=zone_columns, free_model=free_model)
    r_mm = _radius(run, spec, working_radius)
    cqa, used, bl_stages, bl_notes = _block_stages(run, spec, f, r_mm, point_rule, tolerances)
    stages += bl_stages
    notes += bl_notes
    dtm_stages, dtm_notes, dtm_rows = _dtm_stage(run, spec, f, r_mm, point_rule, tolerances)
    stages += dtm_stages
    notes += dtm_notes
    return QAReport(verdict=qa_verdict(stages), spec=spec, pixel_size=pixel,
                    pixel_size_source=pixel_src, tolerances=tolerances, stereo_pairs=pair_stats,
                    triplets=trip_stats, control=cqa, control_rows=used, notes=notes,
                    dtm_points=dtm_rows, production=production)


def _frame_camera_stages(run, f: float, interior: dict, pixel: float, notes: list, *,
                         pairs: str, min_pair_points: int, min_triplet_points: int,
                         frame: Optional[tuple], strips: Optional[Sequence],
                         zone_columns: int, free_model: Optional[bool]) -> tuple:
    """The frame camera's stages of :func:`accuracy_control`: interior orientation,
    relative orientation (vertical parallax), triplets and the production checks.

    Returns
    -------
    tuple
        ``(stages, notes, pair_stats, trip_stats, production)``; ``notes`` is the given
        list extended.
    """
    stages, io_notes = _interior_orientation_stages(interior, pixel)
    notes += io_notes
    ro_stages, ro_notes, pair_stats = _relative_orientation_stages(
        run, pairs, min_pair_points, pixel)
    stages += ro_stages
    notes += ro_notes
    tr_stages, tr_notes, trip_stats = _triplet_stages(run, f, min_triplet_points, pixel)
    stages += tr_stages
    notes += tr_notes
    if strips is None:
        strips = _image_strip_labels(run.data, run.image_ids)
    pc_stages, pc_notes, production = _production_checks(
        run, pixel, frame=frame, strips=strips, zone_columns=zone_columns,
        free_model_mode=free_model)
    stages += pc_stages
    notes += pc_notes
    return stages, notes, pair_stats, trip_stats, production


def _image_strip_labels(data, image_ids: Sequence) -> Optional[list]:
    """The ``strip`` of every image when the project gives one to each, else None."""
    by_id = {str(getattr(im, "id", "")): getattr(im, "strip", None)
             for im in getattr(data, "images", []) or []}
    labels = [by_id.get(str(i)) for i in image_ids]
    return labels if labels and all(x is not None for x in labels) else None


def control_qa_field(run, spec: QASpec, *, point_rule: str = "limit",
                     working_radius: Optional[float] = None) -> np.ndarray:
    """The ``QA`` field of the ``control_points`` layer.

    Parameters
    ----------
    run : AdjustmentRun
    spec : QASpec
    point_rule : {"limit", "mean"}
        See :func:`accuracy_control`.
    working_radius : float, optional
        ``r`` (mm) for orthophoto heights.

    Returns
    -------
    numpy.ndarray of str (object), shape (n,)
        ``"pass"`` / ``"fail"`` per row of ``run.control_points`` (XY and Z within
        their limits), ``""`` for points not used (not measured, or a check point on
        one image only).
    """
    used, ids, res, roles = _block_inputs(run)
    out = np.full(len(run.control_points["point_id"]), "", dtype=object)
    if len(used):
        cqa = control_point_qa(ids, res, roles, spec, float(_problem(run).focal_length),
                               _radius(run, spec, working_radius), point_rule=point_rule)
        out[used] = np.where(cqa.passed, "pass", "fail")
    return out

