"""Accuracy control of an adjustment run: the QA verdict (``DESIGN.md`` section 7).

:func:`accuracy_control` judges a finished :class:`~vectoradjust.pipeline.AdjustmentRun`
stage by stage against the tolerances that :mod:`vectoradjust.qa.tolerances` derives from the
product specification (``[qa]``), the camera and the pixel size:

===================== ====================================================================
interior orientation  per image, the largest fiducial residual (from ``data.interior``
                      when fiducial fits were made; else not evaluated)
relative orientation  per stereo pair, the vertical parallax left after the adjustment
                      (mean and max of ``|py|``)
triplets              per three consecutive images, the discrepancies of the points
                      intersected in the two adjacent models (E_xy, E_z, image scale)
block adjustment      control (GCP) and check point residuals, XY and Z
orthophoto            the height tolerance dh_DTM / 3 on the block; dh_DTM reported
DTM heights           with a DEM in the project: the DEM's bilinear height at every
                      control and check point against its surveyed Z (dh_DTM for
                      orthophotos, the check point height rule for maps)
orthomosaic           0.5 / 0.7 mm on GCP and check points; seamlines not measured here
===================== ====================================================================

Choices (documented here because the manual leaves them open)
-------------------------------------------------------------
* **Vertical parallax after the adjustment** is computed from the OBSERVED photo
  coordinates and the ADJUSTED exterior orientation, in the pair's epipolar-normalised
  frame (:func:`vectoradjust.qa.tolerances.vertical_parallax`): it is how far the two observed
  rays of a point miss each other across the base, which is what a relative
  orientation check measures. It needs no object point (so it does not depend on how
  the adjustment shared a point's misclosure between its two, three or more rays), it
  is exact (no linearisation), and it is zero for intersecting rays whatever the
  attitudes. To first order it equals the difference of the two images' y residuals
  in that frame (``py = -(v_y,left - v_y,right)``), which the tests use as an
  independent check.
* **Stereo pairs** are consecutive images of ``[[images]]`` (flight order) with at
  least ``min_pair_points`` common points (6: the standard points of a relative
  orientation); ``pairs="all"`` takes every image pair with that many common points.
* **Triplets** are three consecutive images with at least ``min_triplet_points``
  points on all three. Each such point is intersected (:func:`vectoradjust.adjust.bundle.intersect`,
  adjusted EO held fixed) from its two rays in model (1, 2) and from those in model
  (2, 3); the difference is taken to image scale with ``m = H / f`` (``H`` the height
  of the middle exposure station above the point). The photo base ``b`` of
  ``E_z = (f / b) E_xy`` is the mean of the two models' air bases divided by ``m``.
  Triplet stages are judged on the MEAN discrepancy with every point against twice
  the tolerance (``E_max ~ 2 E_mean``), like the block.
* **Pixel size**: the ``pixel_size`` argument, else ``[qa] pixel_size``, else the
  camera calibration's (``sqrt(sx sy)`` for rectangular pixels). Without one, the
  pixel-based stages are reported with their measured values but not evaluated
  (``n/a``), and the verdict says so.
* **Working-area radius** ``r`` of the orthophoto height tolerance: ``[qa]
  working_radius`` or the largest radial distance of a measured image point from the
  principal point.

A "heart" module: numpy and other vectoradjust heart modules only; no file I/O.
"""

from __future__ import annotations

import html
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Optional

import numpy as np

from vectoradjust.adjust.bundle import intersect
from vectoradjust.adjust.dem import bilinear
from vectoradjust.errors import ProjectError
from vectoradjust.formatting import float_or_none as _num
from vectoradjust.formatting import fmt_number
from vectoradjust.qa import zones as _zones
from vectoradjust.qa.free_model import FREE_MODEL_MAX_IMAGES, free_model, free_model_stages
from vectoradjust.qa.tolerances import (
    PRODUCTS,
    ControlPointQA,
    QASpec,
    QAVerdict,
    StageResult,
    check_stage,
    control_point_qa,
    dtm_height_tolerance,
    interior_orientation_tolerance,
    max_from_mean,
    model_discrepancies,
    orthomosaic_tolerance,
    orthophoto_dtm_tolerance,
    parallax_stages,
    qa_verdict,
    relative_orientation_tolerance,
    triplet_tolerance,
    vertical_parallax,
)

__all__ = [
    "QAReport",
    "spec_from_table",
    "resolve_pixel_size",
    "working_radius_mm",
    "observation_pairs",
    "pair_parallax",
    "triplet_discrepancies",
    "interior_stages",
    "block_view",
    "zone_stages",
    "inter_strip_stages",
    "strips_from_project",
    "accuracy_control",
    "control_qa_field",
    "html_section",
    "production_rows",
]

PAIR_MODES = ("consecutive", "all")


# ----------------------------------------------------------------------- helpers
def _na_stage(name: str, values=None, ids: Optional[Sequence] = None, statistic: str = "mean",
              unit: str = "", tolerance: float = float("nan")) -> StageResult:
    """A stage that is reported but not evaluated (tolerance unknown or nothing to judge)."""
    v = np.abs(np.asarray([] if values is None else values, float).ravel())
    ids = list(range(v.size)) if ids is None else list(ids)
    fin = v[np.isfinite(v)]
    if fin.size == 0:
        measured = float("nan")
    elif statistic == "mean":
        measured = float(fin.mean())
    elif statistic == "rms":
        measured = float(np.sqrt(np.mean(fin**2)))
    else:
        measured = float(fin.max())
    rows = [{"id": i, "value": float(x), "tolerance": float("nan"), "passed": None}
            for i, x in zip(ids, v.tolist())]
    return StageResult(name=name, tolerance=float(tolerance), measured=measured,
                       statistic=statistic, point_tolerance=float("nan"), passed=None,
                       unit=unit, rows=rows)


def _stats_um(py_mm: np.ndarray, pixel: Optional[float]) -> dict:
    """Mean |py|, RMS, max in micrometres and (when the pixel is known) pixels."""
    a = np.abs(np.asarray(py_mm, float))
    a = a[np.isfinite(a)]
    if a.size == 0:
        vals = (float("nan"),) * 3
    else:
        vals = (float(a.mean()), float(np.sqrt(np.mean(a * a))), float(a.max()))
    out = {"n": int(a.size)}
    for key, v in zip(("mean", "rms", "max"), vals):
        out[f"{key}_um"] = _num(v * 1e3)
    for key, v in zip(("mean", "rms", "max"), vals):
        out[f"{key}_px"] = _num(v / pixel) if pixel else None
    return out


# --------------------------------------------------------------------- the spec
def spec_from_table(table: Optional[dict], *, product: Optional[str] = None,
                    scale=None, contour_interval: Optional[float] = None,
                    terrain: Optional[str] = None, pixel_size: Optional[float] = None,
                    source: str = "<project>") -> QASpec:
    """The product specification from the ``[qa]`` table and overrides (command line).

    Parameters
    ----------
    table : dict or None
        The project's raw ``[qa]`` table (``ProjectData.qa``).
    product, terrain : str, optional
        Override ``product`` / ``terrain``.
    scale : float or str, optional
        Scale denominator of the product (``2000`` or ``"1:2000"``): sets ``map_scale``
        for a topographic map, ``orthophoto_scale`` for an orthophoto / orthomosaic.
    contour_interval : float, optional
        Override (metres).
    pixel_size : float, optional
        Override (mm).
    source : str
        Project file, for messages.

    Returns
    -------
    QASpec

    Raises
    ------
    ProjectError
        Neither a ``[qa]`` table nor a product given, or an invalid value.
    """
    if table is not None and not isinstance(table, dict):
        raise ProjectError(f"{source}: [qa] is not a table",
                           'Write [qa] with product = "topographic map", map_scale = 2000, '
                           "contour_interval = 1.0")
    d = dict(table or {})
    if not d and product is None:
        raise ProjectError(
            f"{source}: there is no product specification for the accuracy control (no [qa] "
            "table and no --product)",
            'Add to the project [qa] product = "topographic map", map_scale = 2000, '
            "contour_interval = 1.0 (or product = \"orthophoto\", orthophoto_scale = 10000), or "
            "give --product and --scale (and --contour-interval for a map)",
            path=source, details={"key": "qa"},
        )
    if product is not None:
        d["product"] = product
    if terrain is not None:
        d["terrain"] = terrain
    if contour_interval is not None:
        d["contour_interval"] = contour_interval
    if pixel_size is not None:
        d["pixel_size"] = pixel_size
    if scale is not None:
        prod = d.get("product")
        canon = " ".join(str(prod).strip().lower().replace("_", " ").replace("-", " ").split())
        if canon == "topographic map":
            d["map_scale"] = scale
        elif canon in PRODUCTS:
            d["orthophoto_scale"] = scale
        else:
            d["map_scale"] = scale  # QASpec names the bad product
    try:
        return QASpec.from_dict(d)
    except ProjectError as exc:
        raise ProjectError(f"{source}: {exc.what}",
                           f"{exc.mend} (or give it on the command line: --product, --scale, "
                           "--contour-interval, --terrain, --pixel-size)",
                           path=source, details=exc.details) from None


def _pixel_from_value(value) -> Optional[float]:
    if value is None:
        return None
    a = np.asarray(value, float).ravel()
    if a.size == 1:
        p = float(a[0])
    elif a.size == 2:
        p = float(np.sqrt(a[0] * a[1]))
    else:
        return None
    return p if math.isfinite(p) and p > 0 else None


def resolve_pixel_size(camera: Any, spec: Optional[QASpec] = None,
                       pixel_size: Optional[float] = None, interior: Any = None) -> tuple:
    """The pixel size (mm) for the pixel-based stages, and where it came from.

    Parameters
    ----------
    camera : vectoradjust.model.Camera or None
        Its ``calibration`` may be a ``CameraCalibration`` (``.pixel_size``), the raw
        ``[camera]`` table (``"pixel_size"`` key) or None.
    spec : QASpec, optional
        ``[qa] pixel_size``.
    pixel_size : float, optional
        Explicit value (wins).
    interior : dict, optional
        ``ProjectData.interior``: last resort, the pixel size of the fiducial fits
        (for scanned film measured in pixels, the scale of the fiducial affine).

    Returns
    -------
    (float or None, str)
        ``sqrt(sx sy)`` for a rectangular pixel; ``(None, "unknown")`` when nothing
        gives one.
    """
    if pixel_size is not None:
        p = _pixel_from_value(pixel_size)
        if p is None:
            raise ValueError(f"pixel size must be a positive number of mm, got {pixel_size!r}")
        return p, "--pixel-size / argument"
    if spec is not None and spec.pixel_size is not None:
        return float(spec.pixel_size), "[qa] pixel_size"
    cal = getattr(camera, "calibration", None)
    if cal is not None:
        value = cal.get("pixel_size") if isinstance(cal, dict) else getattr(cal, "pixel_size",
                                                                             None)
        p = _pixel_from_value(value)
        if p is not None:
            return p, "camera calibration"
    p = _interior_pixel(interior)
    if p is not None:
        return p, "fiducial affine"
    return None, "unknown"


def working_radius_mm(run) -> float:
    """Largest radial distance (mm) of a measured photo point from the principal point.

    The radius ``r`` of the working area in ``dh_DTM = 0.3 mm f M / r``.
    """
    prob = run.result.problem if run.result.problem is not None else run.problem
    d = prob.obs_xy - prob.principal_point[None, :]
    return float(np.hypot(d[:, 0], d[:, 1]).max(initial=0.0))


# ------------------------------------------------------------- observation pairs
def observation_pairs(obs_point, obs_image) -> tuple:
    """Every pair of observations of the same point on two different images.

    Parameters
    ----------
    obs_point, obs_image : array_like of int, shape (k,)

    Returns
    -------
    (first, second) : numpy.ndarray of int
        Observation indices; ``obs_image[first] < obs_image[second]``.
    """
    op = np.asarray(obs_point, np.int64)
    oi = np.asarray(obs_image, np.int64)
    order = np.lexsort((oi, op))
    p, im = op[order], oi[order]
    first, second = [], []
    d = 1
    while d < len(p):
        same = p[d:] == p[:-d]
        if not same.any():
            break  # groups are contiguous: none is larger than d
        i = np.flatnonzero(same & (im[d:] != im[:-d]))
        first.append(order[i])
        second.append(order[i + d])
        d += 1
    if not first:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(first), np.concatenate(second)


def _problem(run):
    return run.result.problem if run.result.problem is not None else run.problem


def pair_parallax(run, pairs: str = "consecutive", min_points: int = 6) -> tuple:
    """Vertical parallax of every stereo pair after the adjustment.

    Parameters
    ----------
    run : AdjustmentRun
    pairs : {"consecutive", "all"}
        Consecutive images (in ``run.image_ids`` order) or every image pair.
    min_points : int
        Common points needed to call two images a stereo pair.

    Returns
    -------
    (pairs, skipped) : (list of dict, list of dict)
        Per stereo pair: ``left``, ``right`` (image ids), ``point_ids`` (numpy array of
        str), ``py_mm`` (numpy array, observed photo coordinates and adjusted EO,
        epipolar-normalised frame); ``skipped`` lists the candidate pairs with too few
        common points (``left``, ``right``, ``n``).
    """
    if pairs not in PAIR_MODES:
        raise ValueError(f"pairs must be one of {PAIR_MODES}, got {pairs!r}")
    prob = _problem(run)
    eo = run.result.eo
    a, b = observation_pairs(prob.obs_point, prob.obs_image)
    ia, ib = prob.obs_image[a], prob.obs_image[b]
    n_img = eo.shape[0]
    if pairs == "consecutive":
        keep = ib - ia == 1
        a, b, ia, ib = a[keep], b[keep], ia[keep], ib[keep]
    py = vertical_parallax(prob.obs_xy[a], prob.obs_xy[b], eo[ia], eo[ib],
                           prob.focal_length, tuple(prob.principal_point))
    key = ia * n_img + ib
    keys, inv, counts = np.unique(key, return_inverse=True, return_counts=True)
    inv = np.asarray(inv).reshape(-1)
    order = np.argsort(inv, kind="stable")
    bounds = np.concatenate([[0], np.cumsum(counts)])
    ids = np.asarray(run.point_ids).astype(str)
    found, skipped = [], []
    for g, k in enumerate(keys.tolist()):
        sel = order[bounds[g]:bounds[g + 1]]
        left, right = run.image_ids[k // n_img], run.image_ids[k % n_img]
        if counts[g] < min_points:
            skipped.append({"left": left, "right": right, "n": int(counts[g])})
            continue
        pts = prob.obs_point[a[sel]]
        srt = np.argsort(pts, kind="stable")
        found.append({"left": left, "right": right, "point_ids": ids[pts[srt]],
                      "py_mm": py[sel][srt]})
    if pairs == "consecutive":
        have = {(d["left"], d["right"]) for d in found} | {(d["left"], d["right"])
                                                           for d in skipped}
        for j in range(n_img - 1):
            pair = (run.image_ids[j], run.image_ids[j + 1])
            if pair not in have:
                skipped.append({"left": pair[0], "right": pair[1], "n": 0})
    return found, skipped


# ----------------------------------------------------------------------- triplets
def triplet_discrepancies(run, min_points: int = 3) -> tuple:
    """Discrepancies of points between the adjacent models of every triplet.

    A triplet is three consecutive images ``(1, 2, 3)`` of ``run.image_ids``. Each point
    measured on all three is intersected from its rays in model (1, 2) and in model
    (2, 3) with the adjusted exterior orientation held fixed.

    Parameters
    ----------
    run : AdjustmentRun
    min_points : int
        Points on all three images needed to judge a triplet.

    Returns
    -------
    (triplets, skipped) : (list of dict, list of dict)
        Per triplet: ``images`` (3 ids), ``point_ids``, ``xyz_12``, ``xyz_23`` (m),
        ``scale`` (photo-scale denominator ``m = H / f`` per point), ``e_xy_mm``,
        ``e_z_mm`` (image scale), ``base_m`` (mean air base of the two models),
        ``base_mm`` (photo base at the mean image scale). ``skipped``: triplets with
        too few common points (``images``, ``n``).
    """
    prob = _problem(run)
    eo = run.result.eo
    n_img = eo.shape[0]
    if n_img < 3:
        return [], []
    op, oi = prob.obs_point, prob.obs_image
    order = np.lexsort((oi, op))
    p, im = op[order], oi[order]
    if len(p) >= 3:
        hit = ((p[2:] == p[:-2]) & (p[1:-1] == p[:-2])
               & (im[1:-1] == im[:-2] + 1) & (im[2:] == im[:-2] + 2))
        i = np.flatnonzero(hit)
    else:
        i = np.zeros(0, np.int64)
    o1, o2, o3 = order[i], order[i + 1], order[i + 2]
    first = oi[o1]
    f = float(prob.focal_length)
    pp = tuple(prob.principal_point)
    n = len(i)
    rows = np.arange(n)
    # every (point, triplet) row is one "point" of each intersection
    xyz12, _ = intersect(eo, np.concatenate([rows, rows]), np.concatenate([oi[o1], oi[o2]]),
                         np.concatenate([prob.obs_xy[o1], prob.obs_xy[o2]]),
                         np.concatenate([prob.obs_sigma[o1], prob.obs_sigma[o2]]), n, f, pp)
    xyz23, _ = intersect(eo, np.concatenate([rows, rows]), np.concatenate([oi[o2], oi[o3]]),
                         np.concatenate([prob.obs_xy[o2], prob.obs_xy[o3]]),
                         np.concatenate([prob.obs_sigma[o2], prob.obs_sigma[o3]]), n, f, pp)
    mid = eo[first + 1]
    height = mid[:, 2] - 0.5 * (xyz12[:, 2] + xyz23[:, 2])
    scale = height * 1e3 / f
    e_xy, e_z = model_discrepancies(xyz12, xyz23, scale)
    ids = np.asarray(run.point_ids).astype(str)
    found, skipped = [], []
    for j in range(n_img - 2):
        sel = np.flatnonzero(first == j)
        names = [run.image_ids[j], run.image_ids[j + 1], run.image_ids[j + 2]]
        if len(sel) < min_points:
            skipped.append({"images": names, "n": int(len(sel))})
            continue
        base = 0.5 * (np.linalg.norm(eo[j + 1, :3] - eo[j, :3])
                      + np.linalg.norm(eo[j + 2, :3] - eo[j + 1, :3]))
        m_mean = float(np.mean(scale[sel]))
        found.append({
            "images": names, "point_ids": ids[op[o1[sel]]], "xyz_12": xyz12[sel],
            "xyz_23": xyz23[sel], "scale": scale[sel], "e_xy_mm": e_xy[sel],
            "e_z_mm": e_z[sel], "base_m": float(base), "base_mm": float(base / m_mean * 1e3),
        })
    return found, skipped


# ----------------------------------------------------------- interior orientation
def _interior_entries(interior: Any) -> list:
    """``(image_id, entry dict)`` from ``data.interior`` (a list or a mapping by id)."""
    if not isinstance(interior, dict):
        return []
    images = interior.get("images", {})
    if isinstance(images, dict):
        return [(str(k), v) for k, v in images.items() if isinstance(v, dict)]
    if isinstance(images, list):
        return [(str(v.get("id", v.get("image_id", j))), v) for j, v in enumerate(images)
                if isinstance(v, dict)]
    return []


def _fit_report(entry: dict) -> Optional[dict]:
    """The fiducial affine report of one image entry, or None when no fit was made.

    Accepts the layout of :func:`vectoradjust.sensor.interior.refine_measurements` (the
    report under ``entry["fiducials"]``, itself with per-fiducial ``"fiducials"``) and a
    flat ``AffineFit.to_dict()``.
    """
    fit = entry.get("fiducials")
    if isinstance(fit, dict) and isinstance(fit.get("fiducials"), dict):
        return fit
    if isinstance(fit, dict) and fit and all(isinstance(v, dict) for v in fit.values()):
        return entry
    if entry.get("max_um") is not None or entry.get("max_residual_um") is not None:
        return entry
    return None


def _first(entry: dict, *keys):
    for k in keys:
        if entry.get(k) is not None:
            return entry[k]
    return None


def _fit_pixel(fit: dict) -> Optional[float]:
    """Pixel size (mm) a fiducial report was judged with, if it says."""
    p = _pixel_from_value(fit.get("pixel_size_mm"))
    if p is None:
        mx_um = _first(fit, "max_um", "max_residual_um")
        mx_px = _first(fit, "max_px", "max_residual_px")
        if mx_um and mx_px:
            p = float(mx_um) / 1e3 / float(mx_px)
    return p


def interior_stages(interior: Any, pixel: Optional[float]) -> tuple:
    """Interior orientation stages (max fiducial residual <= 1 pixel) per image.

    Parameters
    ----------
    interior : dict
        ``ProjectData.interior`` (:func:`vectoradjust.sensor.interior.refine_measurements`
        report): per image under ``"images"`` the fiducial affine report with the
        residual of every fiducial (``v_um`` or ``vx_um, vy_um``), ``max_um``,
        ``redundancy`` (0: an exact fit checks nothing) and the pixel size it used.
    pixel : float or None
        Pixel size (mm) when the report does not give one.

    Returns
    -------
    (stages, notes) : (list of StageResult, list of str)
        One stage per image with a fiducial fit, per-fiducial rows ``"<image>:<id>"``.
    """
    stages, notes, without = [], [], []
    for img, e in _interior_entries(interior):
        fit = _fit_report(e)
        if fit is None:
            without.append(img)
            continue
        name = f"interior orientation {img}: max fiducial residual"
        fid = fit.get("fiducials")
        if isinstance(fid, dict) and fid and all(isinstance(v, dict) for v in fid.values()):
            ids = [f"{img}:{k}" for k in fid]
            um = np.array([float(v["v_um"]) if v.get("v_um") is not None else
                           math.hypot(float(v.get("vx_um") or 0.0), float(v.get("vy_um") or 0.0))
                           for v in fid.values()])
        else:
            ids, um = [img], np.array([float(_first(fit, "max_um", "max_residual_um"))])
        p = _fit_pixel(fit) or pixel
        if fit.get("redundancy") == 0:
            notes.append(f"interior orientation of {img}: 3 fiducials leave no redundancy; "
                         "nothing is checked")
            stages.append(_na_stage(name, um / 1e3 / p if p else um, ids, "max",
                                    "px" if p else "um"))
        elif p is None:
            stages.append(_na_stage(name, um, ids, "max", "um"))
        else:
            tol = interior_orientation_tolerance(p)
            stages.append(check_stage(name, um / 1e3 / p, ids, tol.max_px, "max", unit="px"))
    if stages and without:
        notes.append(f"interior orientation: no fiducial fit for image(s) {', '.join(without)}")
    return stages, notes


def _interior_pixel(interior: Any) -> Optional[float]:
    """Mean pixel size of the fiducial fits (e.g. the affine scale of scanned film)."""
    ps = [p for p in (_fit_pixel(f) for f in (_fit_report(e) for _, e in
                                               _interior_entries(interior)) if f is not None)
          if p is not None]
    return float(np.mean(ps)) if ps else None


# ------------------------------------------------------- zones, strips, free model
def block_view(run, frame: Optional[tuple] = None) -> _zones.BlockView:
    """The adjusted block of a run as a :class:`vectoradjust.qa.zones.BlockView`.

    Parameters
    ----------
    run : AdjustmentRun
    frame : (float, float), optional
        Frame width and height (mm); default from the camera
        (:func:`vectoradjust.qa.zones.frame_size`).
    """
    prob = _problem(run)
    w, h, _src = _zones.frame_size(run.data.camera, prob.obs_xy, prob.principal_point, frame)
    return _zones.BlockView(
        image_ids=list(run.image_ids), eo=np.asarray(run.result.eo, float),
        xyz=np.asarray(run.result.xyz, float),
        point_ids=np.asarray(run.point_ids).astype(str),
        point_kind=np.asarray(run.point_kind).astype(str), obs_point=prob.obs_point,
        obs_image=prob.obs_image, obs_xy=prob.obs_xy, focal_length=float(prob.focal_length),
        principal_point=np.asarray(prob.principal_point, float), frame=(w, h))


def _count_stage(name: str, counts: dict, action: str) -> StageResult:
    """A coverage stage: every zone (or image) needs 2 points, 3 for a clean pass."""
    ids = list(counts)
    vals = [float(counts[i]) for i in ids]
    rows = [{"id": i, "value": v, "tolerance": float(_zones.ZONE_WARN),
             "passed": bool(v >= _zones.ZONE_WARN)} for i, v in zip(ids, vals)]
    warn = [i for i, v in zip(ids, vals) if _zones.ZONE_WARN <= v < _zones.ZONE_PASS]
    measured = min(vals) if vals else float("nan")
    return StageResult(name=name, tolerance=float(_zones.ZONE_PASS), measured=measured,
                       statistic="min", point_tolerance=float(_zones.ZONE_WARN),
                       passed=(bool(measured >= _zones.ZONE_WARN) if vals else None),
                       unit="points", rows=rows, warnings=warn, action=action)


def _zone_json(entry: dict) -> dict:
    """A zone entry for ``qa.json`` (floats rounded to what is meaningful)."""
    out = dict(entry)
    out["overlap_mm"] = [[round(x, 3), round(y, 3)] for x, y in entry["overlap_mm"]]
    if "zone_corners_mm" in entry:
        out["zone_corners_mm"] = [[[round(v, 3) for v in c] for c in z]
                                  for z in entry["zone_corners_mm"]]
    out["reference_height_m"] = _num(entry["reference_height_m"])
    if "overlap_area_mm2" in entry:
        out["overlap_area_mm2"] = _num(entry["overlap_area_mm2"])
    return out


def zone_stages(view: _zones.BlockView, strips, columns: int = 2) -> tuple:
    """Tie-point zone stages of every stereo pair and triplet of consecutive images.

    Parameters
    ----------
    view : vectoradjust.qa.zones.BlockView
    strips : array_like of int, shape (n,)
        Strip of every image: pairs and triplets never cross a strip change.
    columns : {2, 3}
        Zone columns along the base (2: the 6 von Gruber zones).

    Returns
    -------
    (stages, notes, pairs, triplets)
        ``pairs`` / ``triplets``: the zone entries
        (:func:`vectoradjust.qa.zones.pair_zones`) for ``qa.json``.
    """
    strips = np.asarray(strips, np.int64)
    counted, label = _zones.counted_kinds(view.point_kind)
    stages, pairs, trips = [], [], []
    n = len(view.image_ids)
    for j in range(n - 1):
        if strips[j + 1] != strips[j]:
            continue
        e = _zones.pair_zones(view, j, j + 1, columns, counted)
        name = "-".join(e["images"])
        stages.append(_count_stage(f"tie-point zones {name}",
                                   {f"{name}:{z['zone']}": z["count"] for z in e["zones"]}
                                   or {f"{name}:overlap": 0}, "add tie points"))
        pairs.append(_zone_json(e))
        if j + 2 < n and strips[j + 2] == strips[j]:
            t = _zones.triplet_zones(view, j, counted)
            tname = "-".join(t["images"])
            stages.append(_count_stage(f"triplet zones {tname}",
                                       {f"{tname}:{z['zone']}": z["count"] for z in t["zones"]}
                                       or {f"{tname}:overlap": 0}, "add tie points"))
            trips.append(_zone_json(t))
    notes = [f"tie-point zones: {label} counted per zone of each overlap (3 rows x {columns} "
             f"columns, frame {view.frame[0]:.1f} x {view.frame[1]:.1f} mm); at least "
             f"{_zones.ZONE_PASS} per zone pass, {_zones.ZONE_WARN} is a warning"]
    warned = [w for s in stages for w in s.warnings]
    if warned:
        notes.append(f"tie-point zones with only {_zones.ZONE_WARN} points (warning): "
                     + ", ".join(warned[:20]) + (" ..." if len(warned) > 20 else ""))
    if not pairs:
        stages.append(_na_stage("tie-point zones", unit="points"))
    return stages, notes, pairs, trips


def _strip_names(strips: np.ndarray, labels: Optional[Sequence]) -> list:
    """Display name of every strip number: the given label, else its number from 1."""
    if labels is None:
        return [str(k + 1) for k in range(int(strips.max(initial=-1)) + 1)]
    names: dict = {}
    for k, lab in zip(strips.tolist(), labels):
        names.setdefault(k, str(lab))
    return [names[k] for k in sorted(names)]


def inter_strip_stages(view: _zones.BlockView, strips, pixel: Optional[float],
                       labels: Optional[Sequence] = None) -> tuple:
    """Inter-strip tie counts and vertical parallax per pair of adjacent strips.

    Parameters
    ----------
    view : vectoradjust.qa.zones.BlockView
    strips : array_like of int, shape (n,)
    pixel : float or None
        Pixel size (mm): the parallax is judged with the relative orientation tolerance.
    labels : sequence, optional
        Given strip labels per image (for names).

    Returns
    -------
    (stages, notes, entries)
        With one strip: one ``n/a`` stage ("n/a: one strip"), never a pass.
    """
    strips = np.asarray(strips, np.int64)
    names = _strip_names(strips, labels)
    if len(names) < 2:
        return ([_na_stage("inter-strip ties", unit="points")],
                ["inter-strip ties: n/a: one strip"], [])
    stages, entries = [], []
    for t in _zones.inter_strip_ties(view, strips):
        a, b = (names[k] for k in t["strips"])
        name = f"inter-strip {a}-{b}"
        stages.append(_count_stage(f"{name}: tie points per image", t["per_image"],
                                   "add tie points between the strips"))
        rp = t["ray_pairs"]
        py = np.asarray(rp["py_mm"], float)
        if pixel is not None and py.size:
            tol = relative_orientation_tolerance(pixel)
            stages.append(check_stage(f"{name}: mean |py|", py / pixel, rp["point_ids"],
                                      tol.mean_px, "mean", point_tolerance=tol.max_px, unit="px"))
            stages.append(check_stage(f"{name}: max |py|", py / pixel, rp["point_ids"],
                                      tol.max_px, "max", unit="px"))
        else:
            stages.append(_na_stage(f"{name}: mean |py|", py * 1e3, rp["point_ids"], "mean",
                                    "um"))
        entries.append({"strips": [a, b], "images": t["images"], "n_points": t["n_points"],
                        "n_counted": t["n_counted"], "per_image": t["per_image"],
                        "min_per_image": t["min_per_image"], "ray_pairs": int(py.size),
                        "parallax": _stats_um(py, pixel), "point_ids": t["point_ids"]})
    return stages, [], entries


def _strips_of(run, view: _zones.BlockView, strips: Optional[Sequence]) -> tuple:
    """Strip numbers, their labels (or None) and where they came from."""
    if strips is not None:
        if isinstance(strips, dict):
            labels = [strips.get(i) for i in view.image_ids]
        else:
            labels = list(strips)
        if len(labels) != len(view.image_ids) or any(x is None for x in labels):
            raise ProjectError(
                f"{getattr(run.data, 'source', '<project>')}: strip labels are given for "
                f"{sum(x is not None for x in labels)} of {len(view.image_ids)} images",
                "Give strip = ... in every [[images]] entry, or in none (the strips are then "
                "found from the flight)")
        return _zones.image_strips(view.eo, labels), labels, "[[images]] strip"
    return _zones.image_strips(view.eo), None, "flight (positions and heading)"


def strips_from_project(raw: dict) -> Optional[dict]:
    """``{image id: strip}`` from the project's ``[[images]] strip`` keys, or None.

    Parameters
    ----------
    raw : dict
        The parsed project file (``ProjectSpec.raw``).

    Returns
    -------
    dict or None
        None when no image gives a strip (the strips are then found from the flight).
    """
    images = raw.get("images") or []
    found = {str(im.get("id")): im["strip"] for im in images
             if isinstance(im, dict) and im.get("strip") is not None}
    return found or None


def _free_model_part(run, pixel: Optional[float], mode) -> tuple:
    """``(stages, entry, notes)`` of the free model, or a note why it was left out."""
    n_img = len(run.image_ids)
    if mode is None or mode == "auto":
        mode = n_img <= FREE_MODEL_MAX_IMAGES
        if not mode:
            return [], {"skipped": f"{n_img} images > {FREE_MODEL_MAX_IMAGES}"}, [
                f"free model: not run for {n_img} images (more than {FREE_MODEL_MAX_IMAGES}; "
                "ask for it with --free-model)"]
    if not mode:
        return [], {"skipped": "--no-free-model"}, ["free model: not run (--no-free-model)"]
    fm = free_model(_problem(run), run.result.eo, run.result.xyz)
    return free_model_stages(fm, run.point_ids, pixel)


def _production_checks(run, pixel: Optional[float], *, frame, strips, zone_columns,
                       free_model_mode) -> tuple:
    """Zones, inter-strip ties and the free model: ``(stages, notes, parts)``."""
    view = block_view(run, frame)
    numbers, labels, source = _strips_of(run, view, strips)
    stages, notes, pairs, trips = zone_stages(view, numbers, zone_columns)
    is_stages, is_notes, inter = inter_strip_stages(view, numbers, pixel, labels)
    fm_stages, fm_entry, fm_notes = _free_model_part(run, pixel, free_model_mode)
    names = _strip_names(numbers, labels)
    parts = {
        "tie_zones": pairs, "triplet_zones": trips, "inter_strip": inter,
        "strips": {"source": source, "frame_mm": list(view.frame),
                   "strips": [{"strip": names[k], "images": [view.image_ids[i] for i in
                                                             np.flatnonzero(numbers == k)]}
                              for k in range(len(names))]},
        "free_model": fm_entry,
    }
    return stages + is_stages + fm_stages, notes + is_notes + fm_notes, parts


# ------------------------------------------------------------------- the report
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
    """Judge an adjustment run against the production tolerances (``DESIGN.md`` 7).

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
            strips = _image_strip_labels(data, run.image_ids)
        pc_stages, pc_notes, production = _production_checks(
            run, pixel, frame=frame_size, strips=strips, zone_columns=zone_columns,
            free_model_mode=free_model)
        stages += pc_stages
        notes += pc_notes
    r_mm = _radius(run, spec, working_radius)
    cqa, used, bl_stages, bl_notes = _block_stages(run, spec, f, r_mm, point_rule, tolerances)
    stages += bl_stages
    notes += bl_notes
    dtm_stages, dtm_notes, dtm_rows = _dtm_stage(run, spec, f, r_mm, point_rule, tolerances)
    stages += dtm_stages
    notes += dtm_notes

    verdict = qa_verdict(stages)
    return QAReport(verdict=verdict, spec=spec, pixel_size=pixel, pixel_size_source=pixel_src,
                    tolerances=tolerances, stereo_pairs=pair_stats, triplets=trip_stats,
                    control=cqa, control_rows=used, notes=notes, dtm_points=dtm_rows,
                    production=production)


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


# --------------------------------------------------------------------- rendering
def html_section(report: dict) -> str:
    """An HTML fragment (``<section>``) of a QA report for ``report.html``.

    Parameters
    ----------
    report : dict
        :meth:`QAReport.as_dict`.

    Returns
    -------
    str
    """
    e = html.escape
    spec = report["specification"]
    verdict = report["verdict"].upper()
    if spec["product"] == "topographic map":
        scale = spec.get("map_scale")
    else:
        scale = spec.get("orthophoto_scale") or spec.get("map_scale")
    head = f"product {spec['product']}, scale 1:{fmt_number(scale, 0)}"
    if spec.get("contour_interval"):
        head += f", contour interval {fmt_number(spec['contour_interval'], 2)} m"
    head += f", pixel size {fmt_number(report.get('pixel_size_mm'), 4)} mm"
    out = ['<section id="accuracy-control">', "<h2>Accuracy control</h2>",
           f"<p><strong>Verdict: {e(verdict)}</strong> &mdash; {e(head)}</p>"]
    if report["nonconformities"]:
        out.append("<h3>Non-conformities</h3><ul>")
        for n in report["nonconformities"]:
            ids = ", ".join(e(str(i)) for i in n["ids"]) or "(the statistic)"
            out.append(f"<li>{e(n['stage'])}: {e(n['statistic'])} {fmt_number(n['measured'])} "
                       f"{e(n['unit'])} &gt; {fmt_number(n['tolerance'])}; re-measure: {ids}</li>")
        out.append("</ul>")
    out.append("<table><thead><tr><th>stage</th><th>statistic</th><th>measured</th>"
               "<th>tolerance</th><th>point limit</th><th>unit</th><th>status</th>"
               "</tr></thead><tbody>")
    for s in report["stages"]:
        out.append(f"<tr><td>{e(s['name'])}</td><td>{e(s['statistic'])}</td>"
                   f"<td>{fmt_number(s['measured'])}</td><td>{fmt_number(s['tolerance'])}</td>"
                   f"<td>{fmt_number(s['point_tolerance'])}</td><td>{e(s['unit'])}</td>"
                   f"<td>{e(s['status'])}</td></tr>")
    out.append("</tbody></table>")
    for title, rows in production_rows(report):
        out.append(f"<h3>{e(title)}</h3><table><thead><tr>"
                   + "".join(f"<th>{e(k)}</th>" for k in rows[0]) + "</tr></thead><tbody>")
        out += ["<tr>" + "".join(f"<td>{e(str(v))}</td>" for v in r.values()) + "</tr>"
                for r in rows]
        out.append("</tbody></table>")
    if report["notes"]:
        out.append("<ul>" + "".join(f"<li>{e(n)}</li>" for n in report["notes"]) + "</ul>")
    out.append("</section>")
    return "\n".join(out)


def _zone_rows_flat(entries: list) -> list:
    rows = []
    for t in entries:
        row = {"overlap": "-".join(t["images"]), "points": t["points"]}
        for z in t["zones"]:
            row[z["zone"]] = f"{z['count']} ({z['status']})"
        row["road vertices"] = sum(z["road"] for z in t["zones"])
        row["status"] = t["status"]
        rows.append(row)
    return rows


def production_rows(report: dict) -> list:
    """The production checks as flat tables for HTML: ``[(title, rows), ...]``.

    Parameters
    ----------
    report : dict
        :meth:`QAReport.as_dict` (missing keys are skipped).

    Returns
    -------
    list of (str, list of dict)
        Tie-point zones per stereo pair, triplet zones, inter-strip ties, free model;
        only the non-empty ones.
    """
    out = []
    for key, title in (("tie_zones", "Tie-point zones per stereo pair (counted points)"),
                       ("triplet_zones", "Triplet zones (triple overlap)")):
        rows = _zone_rows_flat(report.get(key) or [])
        if rows:
            out.append((title, rows))
    inter = [{"strips": "-".join(t["strips"]), "points": t["n_points"],
              "counted": t["n_counted"], "min per image": t["min_per_image"],
              "ray pairs": t["ray_pairs"], "mean |py| px": fmt_number(
                  t["parallax"].get("mean_px"), 2),
              "max |py| px": fmt_number(t["parallax"].get("max_px"), 2)}
             for t in report.get("inter_strip") or []]
    if inter:
        out.append(("Inter-strip ties", inter))
    fm = report.get("free_model") or {}
    if fm.get("sigma0") is not None:
        out.append(("Free model (before control)", [{
            "sigma0": fmt_number(fm["sigma0"], 3), "limit": fmt_number(fm["sigma0_bound"], 3),
            "dof": fm["dof"], "RMS x um": fmt_number(fm["rms_x_um"], 2),
            "RMS y um": fmt_number(fm["rms_y_um"], 2),
            "RMS px": fmt_number(fm.get("rms_px"), 2)}]))
    return out
