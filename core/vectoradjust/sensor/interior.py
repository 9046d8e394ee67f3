"""Interior orientation of a whole project's image coordinates (docs/method.md sections 5, 7).

:func:`refine_measurements` turns the image measurements as the user made them
(scanner pixels, comparator millimetres or photo millimetres) into the refined photo
coordinates (mm) that the collinearity equations use, image by image, with the chain
of :mod:`vectoradjust.sensor.refine`:

affine (or pixel size for a digital frame) -> principal point -> lens distortion ->
atmospheric refraction (ARDC 1959) -> earth curvature.

It also fits the 6-parameter fiducial affine of every image that has measured
fiducials, checks the interior orientation (largest fiducial residual <= 1 pixel,
docs/method.md section 7), converts image-coordinate sigmas given in pixels to mm and
returns a JSON-ready report (``summary.json`` ``interior_orientation``).

Heights used by refraction and earth curvature:

* flying height of an image = its approximate ``ZL`` from ``[[images]] position``
  (m above sea level; an error of metres changes the corrections by < 0.1 %);
* terrain height = ``[corrections] terrain_height`` (m above sea level) when given,
  else the mean surveyed Z of the control and check points.

Pure numerics: numpy and other vectoradjust heart modules; vectorised over the points
of an image (the only loop is over images).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple, Optional

import numpy as np

from vectoradjust.errors import CameraError, MeasurementError, ProjectError
from vectoradjust.model import ControlPoints, ImageSpec, Measurements
from vectoradjust.sensor.camera import CameraCalibration
from vectoradjust.sensor.refine import (
    DEFAULT_CORRECTIONS,
    STEPS,
    AffineFit,
    as_calibration,
    fit_fiducial_affine,
    interior_orientation_check,
    refine,
)

__all__ = [
    "FiducialMeasurements",
    "InteriorResult",
    "CORRECTION_SWITCHES",
    "CORRECTION_KEYS",
    "UNITS",
    "normalize_unit",
    "parse_corrections",
    "terrain_height_for",
    "refine_measurements",
    "describe_interior",
]

#: The on/off switches of ``[corrections]``, in the order the corrections are applied.
CORRECTION_SWITCHES: tuple[str, ...] = tuple(DEFAULT_CORRECTIONS)
#: Every key ``[corrections]`` accepts (the switches and ``terrain_height``).
CORRECTION_KEYS: tuple[str, ...] = CORRECTION_SWITCHES + ("terrain_height",)
#: Units of the image measurements (``[measurements] unit``).
UNITS = ("mm", "pixel")

_UNIT_ALIASES = {
    "mm": "mm", "millimetre": "mm", "millimeter": "mm", "millimetres": "mm",
    "millimeters": "mm", "pixel": "pixel", "pixels": "pixel", "px": "pixel",
}
_STEP_LABELS = {
    "affine": "fiducial affine",
    "pixel_to_photo": "pixel size",
    "principal_point": "principal point",
    "distortion": "lens distortion",
    "refraction": "refraction",
    "earth_curvature": "earth curvature",
}


@dataclass
class FiducialMeasurements:
    """Measured fiducial marks, one row per (image, fiducial).

    Attributes
    ----------
    image_id, fiducial_id : numpy.ndarray of str, shape (k,)
        The image and the fiducial id of the calibration report.
    xy : numpy.ndarray, shape (k, 2)
        Measured coordinates in the unit of the image measurements: pixels
        (``x`` = column, ``y`` = row, the row axis pointing down) or comparator mm.
    source : str
        File name, for messages.
    rows : numpy.ndarray of int, shape (k,)
        1-based line numbers in the source (header = line 1).
    """

    image_id: np.ndarray
    fiducial_id: np.ndarray
    xy: np.ndarray
    source: str = "<fiducials>"
    rows: Optional[np.ndarray] = None

    def __post_init__(self) -> None:
        self.image_id = np.asarray(self.image_id, dtype=object).astype(str)
        self.fiducial_id = np.asarray(self.fiducial_id, dtype=object).astype(str)
        self.xy = np.asarray(self.xy, float).reshape(-1, 2)
        if self.rows is None:
            self.rows = np.arange(2, len(self.image_id) + 2)

    def of_image(self, image_id: str) -> dict[str, tuple[float, float]]:
        """``{fiducial id: (x, y)}`` measured on one image (file order)."""
        sel = np.flatnonzero(self.image_id == str(image_id))
        return {str(self.fiducial_id[i]): (float(self.xy[i, 0]), float(self.xy[i, 1]))
                for i in sel}


class InteriorResult(NamedTuple):
    """What :func:`refine_measurements` returns.

    Attributes
    ----------
    measurements : Measurements
        Refined photo coordinates (mm) and sigmas (mm), rows in input order.
    principal_point : tuple of float
        ``(x0, y0)`` the collinearity equations must use with these coordinates:
        ``(0, 0)`` when the principal point was reduced here.
    report : dict
        JSON-ready report (see :func:`refine_measurements`).
    """

    measurements: Measurements
    principal_point: tuple[float, float]
    report: dict


# ============================================================================ settings
def normalize_unit(unit: Any, where: str = "[measurements]") -> str:
    """``"mm"`` or ``"pixel"`` from a user's spelling.

    Raises
    ------
    ProjectError
        For any other unit.
    """
    u = _UNIT_ALIASES.get(str(unit).strip().lower()) if isinstance(unit, str) else None
    if u is None:
        raise ProjectError(
            f"{where}: unit = {unit!r} is not known",
            'Write unit = "mm" (photo or comparator millimetres) or unit = "pixel" '
            "(scanner or sensor pixels: column, row)",
            details={"key": "unit", "value": unit},
        )
    return u


def parse_corrections(
    table: Optional[Mapping[str, Any]], where: str = "[corrections]"
) -> tuple[dict[str, bool], Optional[float]]:
    """Validate a ``[corrections]`` table.

    Parameters
    ----------
    table : mapping or None
        ``affine``, ``principal_point``, ``distortion``, ``refraction``,
        ``earth_curvature`` (true/false) and ``terrain_height`` (m above sea level).
    where : str
        How to name the table in messages.

    Returns
    -------
    switches : dict of str to bool
        Every switch; missing ones take their defaults (affine, principal point and
        distortion on, refraction and earth curvature off).
    terrain_height : float or None

    Raises
    ------
    ProjectError
        An unknown key, a switch that is not true/false, a terrain height that is not
        a finite number.
    """
    switches = dict(DEFAULT_CORRECTIONS)
    if table is None:
        return switches, None
    if not isinstance(table, Mapping):
        raise ProjectError(f"{where} must be a table, not {table!r}",
                           "Write [corrections] with refraction = true and so on")
    terrain = None
    for key, value in table.items():
        if key == "terrain_height":
            if isinstance(value, bool) or not isinstance(value, (int, float, np.integer,
                                                                 np.floating)):
                raise ProjectError(
                    f"{where}: terrain_height must be a number (m above sea level), "
                    f"not {value!r}",
                    "Write terrain_height = 188.0, or omit it to use the mean height of the "
                    "control points", details={"key": key})
            terrain = float(value)
            if not np.isfinite(terrain):
                raise ProjectError(f"{where}: terrain_height is not finite",
                                   "Give the mean terrain height in metres",
                                   details={"key": key})
            continue
        if key not in switches:
            raise ProjectError(
                f"{where}: unknown key {key!r}",
                f"Accepted keys: {', '.join(CORRECTION_KEYS)}", details={"key": key})
        if not isinstance(value, (bool, np.bool_)):
            raise ProjectError(f"{where}: {key} must be true or false, not {value!r}",
                               f"Write {key} = true or {key} = false", details={"key": key})
        switches[key] = bool(value)
    return switches, terrain


def terrain_height_for(
    control: Optional[ControlPoints], terrain_height: Optional[float] = None
) -> tuple[Optional[float], str]:
    """The terrain height used by refraction and earth curvature, and where it came from.

    Parameters
    ----------
    control : ControlPoints or None
        Surveyed control and check points.
    terrain_height : float, optional
        ``[corrections] terrain_height``; wins when given.

    Returns
    -------
    (float or None, str)
        The height (m above sea level) and a description of its source; ``None`` when
        there is neither a value nor a surveyed point.
    """
    if terrain_height is not None:
        return float(terrain_height), "[corrections] terrain_height"
    if control is not None and len(control.point_id):
        z = np.asarray(control.xyz, float)[:, 2]
        z = z[np.isfinite(z)]
        if z.size:
            return float(np.mean(z)), f"mean Z of the {z.size} control and check points"
    return None, "none (no terrain_height and no control points)"


# ============================================================================ the work
def refine_measurements(
    measurements: Measurements,
    images: Sequence[ImageSpec],
    camera: Any,
    corrections: Optional[Mapping[str, Any]] = None,
    *,
    unit: str = "mm",
    fiducials: Optional[FiducialMeasurements] = None,
    control: Optional[ControlPoints] = None,
    terrain_height: Optional[float] = None,
    map_projection: bool = True,
    io_tolerance_px: float = 1.0,
) -> InteriorResult:
    """Refine every image measurement of a project and report what was done.

    Parameters
    ----------
    measurements : Measurements
        As read: coordinates and sigmas in ``unit`` (pixels: column, row).
    images : sequence of ImageSpec
        The ``[[images]]``; the approximate ``ZL`` is each image's flying height.
    camera : CameraCalibration or vectoradjust.model.Camera
        The camera (a ``Camera``'s ``calibration`` is used when it has one).
    corrections : mapping, optional
        The ``[corrections]`` table (switches and optional ``terrain_height``); see
        :func:`parse_corrections`.
    unit : {"mm", "pixel"}
        Unit of the measurements, the sigmas and the fiducials.
    fiducials : FiducialMeasurements, optional
        Measured fiducials. An image that has them gets the 6-parameter affine to the
        calibrated fiducials; a pixel image without them is a digital frame (the camera
        needs ``pixel_size`` and ``image_size``); mm without them are photo
        coordinates already.
    control : ControlPoints, optional
        For the terrain height (mean surveyed Z) when ``terrain_height`` is not given.
    terrain_height : float, optional
        Mean terrain height (m above sea level); overrides ``corrections``' value.
    map_projection : bool
        Whether the ground frame is a map projection; earth curvature is applied only
        then (and only when switched on).
    io_tolerance_px : float
        Interior orientation tolerance: largest fiducial residual (pixels).

    Returns
    -------
    InteriorResult
        ``(measurements, principal_point, report)``. ``report`` holds ``input_unit``,
        ``camera``, ``corrections`` (``requested`` switches, ``applied`` steps in
        order, ``max_um`` = largest size of each step over all images in micrometres),
        ``terrain_height``, ``principal_point``, ``sigma`` (input unit, range in
        the input unit and in mm), ``io_check`` (tolerance, overall pass/fail, failed
        images), ``images`` (per image: flying height, point count, applied steps and
        their sizes, the fiducial fit with residuals per fiducial and its pass/fail)
        and ``notes``.

    Raises
    ------
    CameraError
        Fewer than 3 fiducials on an image, fiducial ids the calibration lacks,
        measured fiducials but no calibrated ones, pixel measurements of an image
        without fiducials when the camera has no pixel size and image size, an image
        whose flying height is not above the terrain.
    MeasurementError
        A measurement or fiducial naming an image that ``images`` does not define.
    ProjectError
        A bad ``[corrections]`` table or unit; refraction or earth curvature without
        a terrain height.
    """
    unit = normalize_unit(unit)
    cal = as_calibration(camera)
    su = _set_up(cal, measurements, images, corrections, fiducials, control, terrain_height,
                 map_projection)
    done = _refine_images(measurements, fiducials, su.image_ids, su.zl, cal, unit, su.switches,
                          su.h if su.need_heights else None, io_tolerance_px)
    meas = measurements
    out = Measurements(meas.point_id.copy(), meas.image_id.copy(), done.xy, done.sigma,
                       source=meas.source, rows=None if meas.rows is None else meas.rows.copy())
    report = _report(su, done, cal, unit, meas.sigma, io_tolerance_px, fiducials)
    return InteriorResult(out, su.pp, report)


def describe_interior(report: Optional[Mapping[str, Any]]) -> list[str]:
    """Short human-readable lines about the interior orientation, for the CLI.

    Parameters
    ----------
    report : mapping or None
        The ``report`` of :func:`refine_measurements` (``summary.json``
        ``interior_orientation``).

    Returns
    -------
    list of str
        One line on the unit and the corrections with their largest sizes, and one on
        the fiducial affine and its accuracy control when fiducials were measured.
        Empty for an empty report.
    """
    if not report:
        return []
    corr = report.get("corrections") or {}
    parts = []
    for step in corr.get("applied", []):
        size = (corr.get("max_um") or {}).get(step)
        label = _STEP_LABELS.get(step, step)
        parts.append(label if size is None else f"{label} {size:.1f} um")
    unit = report.get("input_unit", "mm")
    lines = [
        f"interior orientation: measurements in {unit}; corrections (largest): "
        + (", ".join(parts) if parts else "none")
    ]
    fits = [im for im in report.get("images", []) if im.get("fiducials")]
    if fits:
        rms = max(im["fiducials"]["rms_um"] for im in fits)
        worst = max(fits, key=lambda im: im["fiducials"]["max_um"])
        f = worst["fiducials"]
        chk = report.get("io_check") or {}
        if chk.get("passed") is None:
            verdict = "not checked"
        elif chk["passed"]:
            verdict = "pass"
        else:
            verdict = "FAIL on " + ", ".join(chk.get("failed_images", []))
        px = f.get("max_px")
        px_text = "" if px is None else f" = {px:.2f} px"
        lines.append(
            f"fiducial affine on {len(fits)} image(s): RMS up to {rms:.1f} um, largest "
            f"residual {f['max_um']:.1f} um{px_text} (image {worst['id']}); "
            f"interior orientation check (<= {chk.get('tolerance_px', 1.0):g} px): {verdict}"
        )
    return lines


# ============================================================================ helpers
class _SetUp(NamedTuple):
    """What :func:`_set_up` found for :func:`refine_measurements`."""

    switches: dict  # the [corrections] switches, earth curvature off without a map projection
    notes: list  # notes for the report
    image_ids: list
    zl: dict  # image id -> approximate ZL (flying height, m)
    h: Optional[float]  # terrain height (m) and where it came from
    h_source: str
    need_heights: bool  # refraction or earth curvature switched on
    pp: tuple  # principal point left for the bundle (mm)


def _set_up(cal: CameraCalibration, meas: Measurements, images: Sequence[ImageSpec],
            corrections: Optional[Mapping[str, Any]],
            fiducials: Optional[FiducialMeasurements], control: Optional[ControlPoints],
            terrain_height: Optional[float], map_projection: bool) -> _SetUp:
    """Parse the switches, check the image ids and find the terrain height (if needed)."""
    switches, table_terrain = parse_corrections(corrections)
    notes: list[str] = []
    if switches["earth_curvature"] and not map_projection:
        switches["earth_curvature"] = False
        notes.append("earth curvature switched off: the ground frame is not a map projection")
    image_ids = [str(im.id) for im in images]
    zl = {str(im.id): float(np.asarray(im.position, float)[2]) for im in images}
    _check_images(meas.image_id, meas.rows, meas.source, image_ids)
    if fiducials is not None:
        _check_images(fiducials.image_id, fiducials.rows, fiducials.source, image_ids)

    need_heights = switches["refraction"] or switches["earth_curvature"]
    h, h_source = terrain_height_for(control, table_terrain if terrain_height is None
                                     else terrain_height)
    if need_heights:
        _check_heights(switches, h, h_source, image_ids, zl)
    pp_bundle = (0.0, 0.0) if switches["principal_point"] else tuple(cal.principal_point)
    return _SetUp(switches, notes, image_ids, zl, h, h_source, need_heights,
                  (float(pp_bundle[0]), float(pp_bundle[1])))


def _report(su: _SetUp, done: _ImagesDone, cal: CameraCalibration, unit: str,
            sigma_in: np.ndarray, io_tolerance_px: float,
            fiducials: Optional[FiducialMeasurements]) -> dict[str, Any]:
    """The report of :func:`refine_measurements` (see its Returns)."""
    notes = su.notes
    if unit == "pixel" and len(sigma_in):
        notes.append("sigmas given in pixels were converted to mm through each image's "
                     "fiducial affine (or the pixel size)")
    return {
        "input_unit": unit,
        "camera": _camera_report(cal),
        "corrections": {
            "requested": dict(su.switches),
            "applied": done.applied,
            "max_um": {s: done.step_max.get(s) for s in done.applied},
        },
        "terrain_height": ({"value": su.h, "source": su.h_source} if su.need_heights
                           else None),
        "principal_point": [su.pp[0], su.pp[1]],
        "sigma": _sigma_report(unit, sigma_in, done.sigma),
        "io_check": {
            "tolerance_px": float(io_tolerance_px),
            "images_checked": done.io_checked,
            "passed": None if done.io_checked == 0 else not done.io_failed,
            "failed_images": done.io_failed,
        },
        "images": done.per_image,
        "fiducial_source": fiducials.source if fiducials is not None else None,
        "notes": notes,
    }


class _ImagesDone(NamedTuple):
    """What :func:`_refine_images` hands back to :func:`refine_measurements`."""

    xy: np.ndarray
    sigma: np.ndarray
    per_image: list
    step_max: dict
    applied: list
    io_checked: int
    io_failed: list


def _check_heights(switches: Mapping[str, bool], h: Optional[float], h_source: str,
                   image_ids: list, zl: Mapping[str, float]) -> None:
    """Raise unless there is a terrain height and every image flies above it."""
    wanted = " and ".join(k.replace("_", " ") for k in ("refraction", "earth_curvature")
                          if switches[k])
    if h is None:
        raise ProjectError(
            f"the {wanted} correction needs the mean terrain height, but there are no "
            "control points and [corrections] has no terrain_height",
            "Add terrain_height = <metres above sea level> to [corrections]",
            details={"key": "terrain_height"})
    low = [i for i in image_ids if not zl[i] > h]
    if low:
        raise CameraError(
            f"image {low[0]!r}: flying height ZL = {zl[low[0]]:.1f} m is not above the "
            f"terrain height {h:.1f} m ({h_source}), which the {wanted} correction needs",
            "ZL of [[images]] position and the terrain height are both metres above sea "
            "level: check them, or set [corrections] terrain_height",
            details={"image_id": low[0]})


def _refine_images(meas: Measurements, fiducials: Optional[FiducialMeasurements],
                   image_ids: list, zl: Mapping[str, float], cal: CameraCalibration,
                   unit: str, switches: dict[str, bool], terrain: Optional[float],
                   io_tolerance_px: float) -> _ImagesDone:
    """Refine the measurements image by image (``terrain`` None: no height corrections)."""
    fid_source = fiducials.source if fiducials is not None else None
    xy_out = np.array(meas.xy, float, copy=True)
    sigma_out = np.array(meas.sigma, float, copy=True)
    per_image: list[dict[str, Any]] = []
    step_max: dict[str, Optional[float]] = {}
    applied_any: set = set()
    io_failed: list[str] = []
    io_checked = 0
    for iid in image_ids:
        rows = np.flatnonzero(meas.image_id == iid)
        fit = None
        fid_report = None
        measured = fiducials.of_image(iid) if fiducials is not None else {}
        if measured and switches["affine"]:
            fit = _fit_image_fiducials(measured, cal, unit, iid, fid_source)
            fid_report, passed = _fiducial_report(fit, cal, unit, io_tolerance_px)
            if passed is not None:
                io_checked += 1
                if not passed:
                    io_failed.append(iid)
        entry: dict[str, Any] = {
            "id": iid,
            "flying_height": zl[iid],
            "points": int(rows.size),
            "fiducials": fid_report,
        }
        if rows.size == 0 and fit is None:
            entry.update({"applied": [], "corrections": {}, "sigma_mm": None})
            per_image.append(entry)
            continue
        res = refine(meas.xy[rows], cal, affine=fit, unit=unit,
                     flying_height=zl[iid] if terrain is not None else None,
                     terrain_height=terrain, corrections=switches, image_id=iid)
        xy_out[rows] = res.xy
        jac = _sigma_jacobian(fit, cal, unit, res.summary["applied"])
        sigma_out[rows] = np.sqrt(meas.sigma[rows] ** 2 @ (jac**2).T)
        sizes = _record_steps(res.summary, bool(rows.size), step_max, applied_any)
        if "refraction" in res.summary["applied"]:
            k = res.summary["corrections"]["refraction"].get("K_urad")
            entry["refraction_K_urad"] = None if k is None else float(k)
        entry.update({
            "applied": list(res.summary["applied"]),
            "corrections": sizes,
            "sigma_mm": _mean_pair(sigma_out[rows]) if rows.size else None,
        })
        per_image.append(entry)
    applied = [s for s in STEPS if s in applied_any]
    return _ImagesDone(xy_out, sigma_out, per_image, step_max, applied, io_checked, io_failed)


def _fit_image_fiducials(measured: dict, cal: CameraCalibration, unit: str, iid: str,
                         fid_source: Optional[str]) -> AffineFit:
    """Fiducial affine of one image; errors name the fiducial file."""
    try:
        return fit_fiducial_affine(measured, cal, unit=unit, image_id=iid)
    except CameraError as exc:
        raise CameraError(f"{fid_source}: {exc.what}", exc.mend, path=fid_source,
                          details=exc.details) from exc


def _record_steps(summary: Mapping[str, Any], has_points: bool,
                  step_max: dict[str, Optional[float]], applied_any: set) -> dict:
    """Sizes (um) of the steps applied to one image; updates the project-wide maxima."""
    sizes = {}
    for step in summary["applied"]:
        size = summary["corrections"][step]["max_um"]
        sizes[step] = None if size is None else float(size)
        applied_any.add(step)
        if size is not None and has_points:
            step_max[step] = max(step_max.get(step) or 0.0, float(size))
        else:
            step_max.setdefault(step, None)
    return sizes


def _check_images(ids: np.ndarray, rows, source: str, image_ids: list) -> None:
    known = np.isin(ids, np.asarray(image_ids, dtype=str))
    bad = np.flatnonzero(~known)
    if bad.size:
        i = int(bad[0])
        line = "" if rows is None else f", line {int(rows[i])}"
        raise MeasurementError(
            f"{source}{line}: image {str(ids[i])!r} is not defined in [[images]]",
            f"Add an [[images]] entry with id = {str(ids[i])!r} or correct the image id "
            f"(defined: {', '.join(image_ids)})",
            path=source, details={"image_id": str(ids[i])})


def _fiducial_report(fit: AffineFit, cal: CameraCalibration, unit: str,
                     tolerance_px: float) -> tuple[dict[str, Any], Optional[bool]]:
    rep = fit.to_dict()
    rep["n"] = len(fit.ids)
    if cal.pixel_size is not None:
        ps: Optional[tuple[float, float]] = cal.pixel_size
    elif unit == "pixel":
        ps = fit.scale
    else:
        ps = None
    p = None if ps is None else float(np.sqrt(ps[0] * ps[1]))
    if p is not None:
        rep["rms_px"] = fit.rms_um / 1000.0 / p
        rep["max_px"] = fit.max_um / 1000.0 / p
    lengths = np.hypot(fit.residuals[:, 0], fit.residuals[:, 1]) * 1000.0
    for fid, length in zip(fit.ids, lengths):
        rep["fiducials"][fid]["v_um"] = float(length)
        rep["fiducials"][fid]["v_px"] = None if p is None else float(length / 1000.0 / p)
    rep["pixel_size_mm"] = None if ps is None else [float(ps[0]), float(ps[1])]
    rep["scale_mm"] = [float(s) for s in fit.scale]
    if p is None:
        rep["io_check"] = {"passed": None, "tolerance_px": float(tolerance_px),
                           "note": "no pixel size: the 1-pixel check needs [camera] pixel_size"}
        return rep, None
    chk = interior_orientation_check(fit, pixel_size=ps, tolerance_px=tolerance_px)
    chk.pop("image_id", None)
    rep["io_check"] = chk
    return rep, chk["passed"]


def _sigma_jacobian(fit: Optional[AffineFit], cal: CameraCalibration, unit: str,
                    applied: list) -> np.ndarray:
    """Linear map from the measured unit to photo mm (for the sigmas)."""
    if fit is not None:
        return fit.matrix
    if "pixel_to_photo" in applied and cal.pixel_size is not None:
        sx, sy = cal.pixel_size
        return np.array([[sx, 0.0], [0.0, -sy]])
    return np.eye(2)


def _mean_pair(a: np.ndarray) -> list:
    return [float(v) for v in np.mean(a, axis=0)]


def _sigma_report(unit: str, sigma_in: np.ndarray, sigma_mm: np.ndarray) -> dict[str, Any]:
    if sigma_in.size == 0:
        return {"unit": unit, "input_min": None, "input_max": None, "mm_min": None,
                "mm_max": None}
    return {
        "unit": unit,
        "input_min": float(sigma_in.min()),
        "input_max": float(sigma_in.max()),
        "mm_min": float(sigma_mm.min()),
        "mm_max": float(sigma_mm.max()),
    }


def _camera_report(cal: CameraCalibration) -> dict[str, Any]:
    return {
        "name": cal.name,
        "source": cal.source,
        "focal_length": float(cal.focal_length),
        "principal_point": [float(v) for v in cal.principal_point],
        "distortion_model": cal.distortion_model,
        "distortion_convention": cal.distortion_convention,
        "fiducials": 0 if cal.fiducials is None else len(cal.fiducials),
        "pixel_size": None if cal.pixel_size is None else [float(v) for v in cal.pixel_size],
        "image_size": None if cal.image_size is None else [int(v) for v in cal.image_size],
    }
